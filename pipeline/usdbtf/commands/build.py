"""``usdbtf build``: build the BTF materials a scene binds (and nothing else), incrementally."""
from __future__ import annotations

from pathlib import Path

from . import log
from ..cluster import ADDRESS_HELP, parse_address

ORDER = 67


def add_parser(sub) -> None:
    p = sub.add_parser("build", help="compress and package only the BTF materials bound in a scene (SCons, "
                       "content signatures)")
    p.add_argument("scene", type=Path, help="scene .usda whose bound BtfMaterialAPI materials carry btf:build:* recipes")
    p.add_argument("--dry-run", action="store_true", help="list what the scene needs without building")
    p.add_argument("--dask", type=parse_address, metavar="ADDRESS", help=ADDRESS_HELP + "; the material builds "
                   "run as tasks there, with the same outputs")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def outputs(args):
    """None declared here: the scene names them, and :func:`usdbtf.usd.build.build` checks them
    (``--force`` is still offered: it lets a build replace outputs it did not write before)."""
    return []


def run(args) -> int:
    from ..usd.build import build, plan

    if args.dry_run:
        recipes, report = plan(args.scene)
        for r in recipes:
            print(f"{r.material}: {r.source} -> {r.asset}" + (f" ({' '.join(r.options)})" if r.options else ""))
        for path in report["without_recipe"]:
            print(f"{path}: bound, no recipe")
        return 0
    build(args.scene, force=args.force, log=log(args.quiet), dask=args.dask)
    return 0
