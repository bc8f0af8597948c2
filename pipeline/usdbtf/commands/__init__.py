"""One module per ``usdbtf <stage>`` command.

Each module defines ``ORDER`` (its place in ``usdbtf --help``), ``add_parser(sub)``
(registers its argparse sub-command, with ``func`` set to its ``run(args) -> int``)
and keeps heavy imports inside ``run`` so ``usdbtf --help`` stays fast.  Messages go to
``logging.getLogger(__name__)`` (the CLI adds -q/-v/--progress to every command and sets the
level).  A new stage is a new module here; :func:`usdbtf.cli.build_parser` finds it.
"""
from __future__ import annotations

import importlib
import pkgutil


def command_modules() -> list:
    """Every command module in this package, in ``ORDER``."""
    mods = [importlib.import_module(f"{__name__}.{info.name}") for info in pkgutil.iter_modules(__path__)
            if not info.name.startswith("_")]
    return sorted(mods, key=lambda m: (getattr(m, "ORDER", 1000), m.__name__))


def json_ready(value):
    """``value`` with paths as strings and numpy scalars/arrays as Python numbers/lists."""
    from pathlib import PurePath

    import numpy as np

    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None                       # strict JSON has no NaN/Infinity
    return value


def print_json(value) -> None:
    """The ``--json`` summary of a command: one JSON document on stdout (messages go to stderr)."""
    import json

    print(json.dumps(json_ready(value), indent=1, sort_keys=True))
