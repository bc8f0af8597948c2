"""Shared pytest setup: import path, a fixed OCIO environment, and the ``slow`` marker."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PIPELINE = ROOT / "pipeline"

# Make `import usdbtf` work from a plain checkout when the package isn't installed.
try:
    import usdbtf  # noqa: F401
except ImportError:
    sys.path.insert(0, str(PIPELINE))

# Tests use the built-in default OCIO config, whatever the developer's shell says.
os.environ["OCIO"] = "ocio://default"


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="also run tests marked slow")


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long-running test; run with --runslow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip_slow = pytest.mark.skip(reason="slow; use --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip_slow)
