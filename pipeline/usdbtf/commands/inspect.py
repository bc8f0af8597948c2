"""``usdbtf inspect``: what a packaged BTF asset holds (k, bytes, directions, error, LODs)."""
from __future__ import annotations

from pathlib import Path

ORDER = 65


def add_parser(sub) -> None:
    p = sub.add_parser("inspect", help="summarise the BTF materials of a USD asset")
    p.add_argument("asset", type=Path, help=".usda/.usdc/.usdz asset (or any stage referencing one)")
    p.add_argument("--validate", action="store_true",
                   help="also run every UsdValidation validator and check every layer for NaN or Inf "
                        "(exit status 65 when there is an error)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import BTFError
    from ..usd.finite import non_finite_in_stage
    from ..usd.inspect import describe
    from ..usd.validate import validation_issues

    print(describe(args.asset))
    if args.validate:
        # Besides USD's validators: no NaN or infinite number in any layer (none of them checks).
        errors = validation_issues(args.asset) + [f"[usdbtf:NonFiniteValue] {where}: NaN or infinite value"
                                                  for where in non_finite_in_stage(args.asset)]
        warnings = validation_issues(args.asset, severities=("Warn",))
        print(f"validation: {len(errors)} error(s), {len(warnings)} warning(s)"
              + "".join(f"\n  {line}" for line in errors + warnings), flush=True)
        if errors:       # a bad asset is bad data (status 65); the report above lists every error
            raise BTFError(f"{args.asset}: fails validation ({len(errors)} error(s)); first: {errors[0]}")
    return 0
