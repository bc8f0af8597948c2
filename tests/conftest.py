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


@pytest.fixture(scope="session")
def synth_capture(tmp_path_factory):
    """``usdbtf synth PRESET --sampling S --size N [--seed K]`` made once per session.

    Several modules start from the same synthetic capture (satin_weave on the 6,561-sample
    ``ubo81`` sampling at 16^2, ~11 s of CPU to render; pebbles, ridged_fabric and fuzzy_moss
    on ``small`` at 32^2).  A synth folder does not depend on where it is written (the same
    bytes at any path), so a copy is what a fresh ``synth`` there would write.

    Returns ``get(preset, sampling, size, seed=None, out=None)``: the cached folder itself
    (``out`` None: read it, never write into it), or a copy of it at ``out``.
    """
    import shutil

    from usdbtf.cli import main

    made: dict = {}

    def get(preset: str, sampling: str, size: int, seed: int | None = None, out: Path | None = None) -> Path:
        key = (preset, sampling, int(size), seed)
        if key not in made:
            folder = tmp_path_factory.mktemp("synth_cache") / f"{preset}-{sampling}-{size}-{seed}"
            argv = ["synth", preset, "-o", str(folder), "--sampling", sampling, "--size", str(size), "-q"]
            assert main(argv + ([] if seed is None else ["--seed", str(seed)])) == 0
            made[key] = folder
        if out is None:
            return made[key]
        shutil.copytree(made[key], out)
        return Path(out)

    return get
