"""``usdbtf inspect``: what a packaged BTF asset holds (k, bytes, directions, error, LODs)."""
from __future__ import annotations

ORDER = 65


def add_parser(sub) -> None:
    p = sub.add_parser("inspect", help="summarise the BTF materials of a USD asset")
    # A string, not a Path: the asset resolver may understand names a file path would mangle.
    p.add_argument("asset", help=".usda/.usdc/.usdz asset (or any stage referencing one), as the asset "
                   "resolver finds it")
    p.add_argument("--validate", action="store_true", help="also run every UsdValidation validator on every lod "
                   "selection (exit status 65 when any reports an error)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON (keys in the README)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import EXIT_DATA
    from ..usd.inspect import describe, summary
    from ..usd.validate import validation_by_lod

    info = summary(args.asset)
    status = 0
    if args.validate:
        errors = validation_by_lod(args.asset)
        warnings = validation_by_lod(args.asset, severities=("Warn",))
        flat = lambda report: [f"{f'lod={lod}: ' if lod else ''}{line}"  # noqa: E731
                               for lod, lines in report.items() for line in lines]
        info["validation"] = {"errors": flat(errors), "warnings": flat(warnings),
                              "selections": [lod or "(as authored)" for lod in errors]}
        status = EXIT_DATA if info["validation"]["errors"] else 0
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
    return status
