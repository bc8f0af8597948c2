"""``usdbtf package``: a compressed BTF as a USD asset (swatch or mesh, LOD variants, usdz)."""
from __future__ import annotations

from pathlib import Path

from . import log
from ..argtypes import float_in

ORDER = 60


def add_parser(sub) -> None:
    p = sub.add_parser("package", help="a compressed BTF as a USD asset (.usda, optional .usdz)")
    p.add_argument("input", type=Path, help="compressed BTF folder")
    p.add_argument("-o", "--output", required=True, type=Path, help="root layer to write, e.g. out/pebbles.usda")
    p.add_argument("--mesh", type=Path, help="mesh with texture coordinates (OBJ/PLY/STL/GLB/USD); "
                   "default a swatch quad at the tile's physical size")
    p.add_argument("--usdz", action="store_true", help="also write the asset as a .usdz package beside it "
                   "(AR viewers read only PNG/JPEG textures: compress with --codec png or jpeg for those)")
    p.add_argument("--lod", help="basis counts of the lod variants besides 'full', e.g. 64,16 "
                   "(default: halvings of k down to 4)")
    p.add_argument("--physical-size", type=float_in(0, 1e4, lo_open=True), nargs=2, metavar=("W", "H"),
                   help="tile size in metres (default: the source's physical_size_m)")
    p.add_argument("--no-validate", action="store_true", help="skip the UsdValidation check before publishing")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def outputs(args):
    from ..usd.package import asset_pieces
    return [(args.output.parent / name, kind) for name, _, kind in asset_pieces(args.output, usdz=args.usdz)]


def run(args) -> int:
    from ..errors import UsageError
    from ..usd.package import package

    lods = None
    if args.lod is not None:
        try:
            lods = [int(x) for x in args.lod.split(",") if x.strip()]
        except ValueError:
            raise UsageError(f"--lod {args.lod!r}: expected comma-separated integers") from None
    package(args.input, args.output, mesh=args.mesh, usdz=args.usdz, lods=lods,
            physical_size=tuple(args.physical_size) if args.physical_size else None,
            validate=not args.no_validate, log=log(args.quiet))
    return 0
