"""``usdbtf build``: build the BTF materials a scene binds (and nothing else), incrementally,
shaped by what the scene's cameras, lights and visibility need of each (``--full``: all of it)."""
from __future__ import annotations

import logging
from pathlib import Path

from ..argtypes import float_in, int_in
from ..cluster import ADDRESS_HELP, parse_address

log = logging.getLogger(__name__)
ORDER = 67


def add_parser(sub) -> None:
    p = sub.add_parser("build", help="compress and package only the BTF materials bound in a scene, only what its "
                       "cameras, lights and visibility need of them (SCons, content signatures)")
    p.add_argument("scene", type=Path, help="scene .usda whose bound BtfMaterialAPI materials carry btf:build:* recipes")
    p.add_argument("--dry-run", action="store_true", help="list what the scene needs without building")
    p.add_argument("--full", action="store_true", help="build every bound material in full (every direction, the "
                   "measured resolution, the recipe's k), whatever the scene shows of it")
    p.add_argument("--target-error", type=float_in(0, 100, lo_open=True), metavar="PCT",
                   help="screen-space percent error each material must meet (default: its btf:build:targetError, "
                        "else the recipe's k); scaled to a per-texel target by its size on screen")
    p.add_argument("--dask", type=parse_address, metavar="ADDRESS", help=ADDRESS_HELP + "; the material builds "
                   "run as tasks there, with the same outputs")
    p.add_argument("-o", "--output", type=Path, metavar="PATH",
                   help="the built stage to write and open: the scene with every bound mesh quilted at its "
                        "material's measured scale (default: SCENE.built.usda beside the scene; .usda, .usdc or "
                        ".usd); its path is printed last")
    p.add_argument("--jobs", "-j", type=int_in(1, 4096), metavar="N",
                   help="steps SCons runs at once (independent material and mesh chains; default: the CPU "
                        "count); the outputs are the same bytes whatever N is")
    p.add_argument("--json", action="store_true", help="print the build's report as JSON on stdout "
                   "(bound materials, what the scene needs of each, recipes, steps run, bytes and time)")
    p.set_defaults(func=run)


def outputs(args):
    """None declared here: the scene names them, and :func:`usdbtf.usd.scenes.build.build` checks them
    (``--force`` is still offered: it lets a build replace outputs it did not write before)."""
    return []


def source_facts(path: Path):
    """:class:`usdbtf.usd.scenes.plan.MaterialFacts` of a recipe's source (a compressed folder or any
    BTF input :func:`usdbtf.io.open_btf` reads)."""
    from ..compress.format import METADATA, read_compressed
    from ..io import open_btf
    from ..usd.scenes.plan import MaterialFacts

    if (Path(path) / METADATA).is_file():
        return MaterialFacts.of(read_compressed(path), compressed=True)
    return MaterialFacts.of(open_btf(path))


def run(args) -> int:
    from ..usd.scenes.build import build, plan

    shape = {} if args.full else {"source_facts": source_facts, "target_error": args.target_error}
    if args.dry_run:
        recipes, report = plan(args.scene, **shape)
        _log_table(report, None)
        if args.json:
            return _print_report(args.scene, recipes, report, dry_run=True)
        for r in recipes:
            print(f"{r.material}: {r.source} -> {r.asset}" + (f" ({' '.join(r.options + r.shape)})"
                                                               if r.options or r.shape else ""))
        for path in report["without_recipe"]:
            print(f"{path}: bound, no recipe")
        for path in report.get("skipped", []):
            print(f"{path}: not built: {report['needs'][path].why_not}")
        for path in report.get("stand_ins", []):
            print(f"{path}: a stand-in only (one view, one light, k 1): {report['needs'][path].why_not}")
        return 0
    report = build(args.scene, force=args.force, dask=args.dask, output=args.output, jobs=args.jobs, **shape)
    _log_table(report, report.get("costs"))
    if args.json:
        return _print_report(args.scene, report["recipes"], report, dry_run=False)
    if report.get("built_scene") is not None:
        print(report["built_scene"])        # last: the stage to open
    return 0


def _mb(n) -> str:
    return "-" if n is None else f"{n / 1e6:.2f}"


def _log_table(report: dict, costs: dict | None) -> None:
    """The per-material table on stderr: what the scene needs, and (builds) bytes and time
    against the last ``--full`` build."""
    needs = report.get("needs") or {}
    if not needs and not costs:
        return
    rows = [("material", "needed", "views", "lights", "max texels", "target %", "MB", "s", "full MB", "full s")]
    for material in sorted(set(needs) | set(costs or {})):
        need, cost = needs.get(material), (costs or {}).get(material, {})
        if need is not None and need.needed and need.full is not None:
            cells = (f"yes, whole: {need.full}", "all", "all", "full", "-")
        elif need is not None and need.stand_in:
            cells = (f"no, stand-in (k 1): {need.why_not}", f"1/{len(need.facts.views)}", f"1/{len(need.facts.lights)}",
                     str(need.max_texels or "full"), "-")
        elif need is not None:
            cells = ("yes" if need.needed else f"no: {need.why_not}", f"{len(need.views)}/{len(need.facts.views)}",
                     f"{len(need.lights)}/{len(need.facts.lights)}", str(need.max_texels or "full"),
                     "-" if need.target_error is None else f"{need.target_error:.3g}")
        else:
            cells = ("yes (--full)", "all", "all", "full", "-")
        secs = cost.get("seconds")
        rows.append((material, *cells, _mb(cost.get("bytes")), "-" if secs is None else f"{secs:.1f}",
                     _mb(cost.get("full_bytes")),
                     "-" if cost.get("full_seconds") is None else f"{cost['full_seconds']:.1f}"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for row in rows:
        log.info("  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip())


def _print_report(scene, recipes, report: dict, *, dry_run: bool) -> int:
    """``--json``: {"scene", "dry_run", "shaped", "recipes": [{material, source, options, shape,
    asset, compressed}], "bound": {material: [prims]}, "without_recipe": [materials],
    "needs": {material: what the scene needs of it (:meth:`usdbtf.usd.scenes.plan.Need.report`)},
    "skipped": [materials not built], "stand_ins": [materials the scene never shows, built as
    one-direction stand-ins so that its references resolve], "bindings": [{material, prims, asset}] (the bound
    meshes' unwrap/quilt/package chains), "ran": [commands], "costs": {material: {bytes,
    seconds, full_bytes, full_seconds}} and "built_scene" (builds only)}."""
    from . import print_json

    out = {"scene": str(scene), "dry_run": dry_run, "shaped": bool(report.get("shaped")),
           "recipes": [{"material": r.material, "source": r.source, "options": list(r.options),
                        "shape": list(r.shape), "asset": r.asset, "compressed": r.compressed} for r in recipes],
           "bound": report["bound"], "without_recipe": report["without_recipe"],
           "needs": {m: n.report() for m, n in (report.get("needs") or {}).items()},
           "skipped": report.get("skipped", []), "stand_ins": report.get("stand_ins", []),
           "bindings": [{"material": c.material, "prims": c.prims, "asset": c.asset} for c in report["bindings"]]}
    if not dry_run:
        out["ran"] = report["ran"]
        out["built_scene"] = None if report.get("built_scene") is None else str(report["built_scene"])
        out["costs"] = report.get("costs", {})
    print_json(out)
    return 0
