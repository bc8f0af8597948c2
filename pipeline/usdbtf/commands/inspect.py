"""``usdbtf inspect``: what a packaged BTF asset holds (k, bytes, directions, error, LODs)."""
from __future__ import annotations

from pathlib import Path

ORDER = 65


def add_parser(sub) -> None:
    p = sub.add_parser("inspect", help="summarise the BTF materials of a USD asset")
    p.add_argument("asset", type=Path, help=".usda/.usdc/.usdz asset (or any stage referencing one)")
    p.add_argument("--validate", action="store_true", help="also run every UsdValidation validator")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..usd.inspect import describe
    from ..usd.validate import validation_issues

    print(describe(args.asset))
    if args.validate:
        errors = validation_issues(args.asset)
        warnings = validation_issues(args.asset, severities=("Warn",))
        print(f"validation: {len(errors)} error(s), {len(warnings)} warning(s)"
              + "".join(f"\n  {line}" for line in errors + warnings))
        return 1 if errors else 0
    return 0
