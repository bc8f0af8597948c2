"""One module per ``usdbtf <stage>`` command.

Each module defines ``ORDER`` (its place in ``usdbtf --help``), ``add_parser(sub)``
(registers its argparse sub-command, with ``func`` set to its ``run(args) -> int``)
and keeps heavy imports inside ``run`` so ``usdbtf --help`` stays fast.  A new
stage is a new module here; :func:`usdbtf.cli.build_parser` finds it.
"""
from __future__ import annotations

import importlib
import pkgutil
import sys


def log(quiet: bool):
    """A progress printer to stderr, or a no-op when ``quiet``."""
    return (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))


def command_modules() -> list:
    """Every command module in this package, in ``ORDER``."""
    mods = [importlib.import_module(f"{__name__}.{info.name}") for info in pkgutil.iter_modules(__path__)
            if not info.name.startswith("_")]
    return sorted(mods, key=lambda m: (getattr(m, "ORDER", 1000), m.__name__))
