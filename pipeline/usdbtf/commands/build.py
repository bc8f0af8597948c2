"""``usdbtf build``: build the BTF materials a scene binds (and nothing else), incrementally."""
from __future__ import annotations

from pathlib import Path

from ..cluster import ADDRESS_HELP, parse_address

ORDER = 67


def add_parser(sub) -> None:
    p = sub.add_parser("build", help="compress and package only the BTF materials bound in a scene (SCons, "
                       "content signatures)")
    p.add_argument("scene", type=Path, help="scene .usda whose bound BtfMaterialAPI materials carry btf:build:* recipes")
    p.add_argument("--dry-run", action="store_true", help="list what the scene needs without building")
    p.add_argument("--dask", type=parse_address, metavar="ADDRESS", help=ADDRESS_HELP + "; the material builds "
                   "run as tasks there, with the same outputs")
    p.add_argument("--json", action="store_true", help="print the build's report as JSON on stdout "
                   "(bound materials, recipes, steps run)")
    p.set_defaults(func=run)


def outputs(args):
    """None declared here: the scene names them, and :func:`usdbtf.usd.build.build` checks them
    (``--force`` is still offered: it lets a build replace outputs it did not write before)."""
    return []


def run(args) -> int:
    from ..usd.build import build, plan

    if args.dry_run:
        recipes, report = plan(args.scene)
        if args.json:
            return _print_report(args.scene, recipes, report, dry_run=True)
        for r in recipes:
            print(f"{r.material}: {r.source} -> {r.asset}" + (f" ({' '.join(r.options)})" if r.options else ""))
        for path in report["without_recipe"]:
            print(f"{path}: bound, no recipe")
        return 0
    report = build(args.scene, force=args.force, dask=args.dask)
    if args.json:
        return _print_report(args.scene, report["recipes"], report, dry_run=False)
    return 0


def _print_report(scene, recipes, report: dict, *, dry_run: bool) -> int:
    """``--json``: {"scene", "dry_run", "recipes": [{material, source, options, asset, compressed}],
    "bound": {material: [prims]}, "without_recipe": [materials], "bindings": [{material, prims, asset}]
    (the bound meshes' unwrap/quilt/package chains), "ran": [commands] and "built_scene" (builds only)}."""
    from . import print_json

    out = {"scene": str(scene), "dry_run": dry_run,
           "recipes": [{"material": r.material, "source": r.source, "options": list(r.options), "asset": r.asset,
                        "compressed": r.compressed} for r in recipes],
           "bound": report["bound"], "without_recipe": report["without_recipe"],
           "bindings": [{"material": c.material, "prims": c.prims, "asset": c.asset} for c in report["bindings"]]}
    if not dry_run:
        out["ran"] = report["ran"]
        out["built_scene"] = report.get("built_scene")
    print_json(out)
    return 0
