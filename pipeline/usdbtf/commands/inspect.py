"""``usdbtf inspect``: what a packaged BTF asset holds (k, bytes, directions, error, LODs)."""
from __future__ import annotations

ORDER = 65


def add_parser(sub) -> None:
    p = sub.add_parser("inspect", help="summarise the BTF materials of a USD asset")
    # A string, not a Path: the asset resolver may understand names a file path would mangle.
    p.add_argument("asset", help=".usda/.usdc/.usdz asset (or any stage referencing one), as the asset "
                   "resolver finds it")
    p.add_argument("--validate", action="store_true",
                   help="also run every UsdValidation validator on every lod selection, check every layer "
                        "for NaN or Inf and every bound mesh's texel density against its material's (within 2 "
                        "%%) (exit status 65 when there is an error); warn where a camera or light of the stage "
                        "asks a partial asset for a view or light direction it does not keep, and, on a scene `usdbtf build` "
                        "has built, name the built stage that supersedes it")
    p.add_argument("--json", action="store_true", help="print the summary as JSON (keys in docs/unattended-runs-errors-outputs.md)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import BTFError
    from ..usd.scenes.build import superseding_stage
    from ..usd.density import density_problems
    from ..usd.asset.finite import non_finite_in_stage
    from ..usd.asset.inspect import describe, summary
    from ..usd.scenes.reach import coverage_warnings
    from ..usd.read import open_stage
    from ..usd.asset.validate import validation_by_lod

    info = summary(args.asset)
    errors = []
    if args.validate:
        flat = lambda report: [f"{f'lod={lod}: ' if lod else ''}{line}"  # noqa: E731
                               for lod, lines in report.items() for line in lines]
        by_lod = validation_by_lod(args.asset)
        # Besides USD's validators: no NaN or infinite number in any layer (none of them checks).
        # ... and every bound mesh carries its material at the material's physical scale.
        errors = flat(by_lod) + [f"[usdbtf:NonFiniteValue] {where}: NaN or infinite value"
                                 for where in non_finite_in_stage(args.asset)] + density_problems(info["bindings"])
        # ... and warnings where the stage's cameras and lights ask a partial asset for more.
        warnings = flat(validation_by_lod(args.asset, severities=("Warn",))) + coverage_warnings(open_stage(args.asset))
        # ... and, on a scene ``usdbtf build`` has built, the built stage to open instead.
        built = superseding_stage(args.asset)
        if built is not None:
            warnings.insert(0, f"[usdbtf:BuiltStage] {args.asset}: superseded by the built stage {built} "
                               "(usdbtf build: its bound meshes quilted at measured scale); open that one")
        info["validation"] = {"errors": errors, "warnings": warnings,
                              "selections": [lod or "(as authored)" for lod in by_lod]}
    if args.json:
        from . import print_json

        print_json(info)
    else:
        print(describe(args.asset, info))
        if args.validate:
            v = info["validation"]
            print(f"validation: {len(v['errors'])} error(s), {len(v['warnings'])} warning(s) on "
                  f"{len(v['selections'])} lod selection(s)" + "".join(f"\n  {line}" for line in v["errors"]
                                                                     + v["warnings"]))
    if errors:       # a bad asset is bad data (status 65); the report above lists every error
        import sys

        sys.stdout.flush()
        raise BTFError(f"{args.asset}: fails validation ({len(errors)} error(s)); first: {errors[0]}")
    return 0
