"""``usdbtf package``: a compressed BTF as a USD asset (swatch or mesh, LOD variants, usdz)."""
from __future__ import annotations

from pathlib import Path

from ..argtypes import float_in

ORDER = 60


def add_parser(sub) -> None:
    from ..usd.asset.formats import PAYLOAD_FORMATS, TEXTURE_FORMATS

    p = sub.add_parser("package", help="a compressed BTF as a USD asset (.usda/.usdc, optional .usdz)")
    p.add_argument("input", type=Path, help="compressed BTF folder")
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="root layer to write, e.g. out/pebbles.usda or out/pebbles.usdc")
    p.add_argument("--mesh", type=Path, help="mesh with texture coordinates (OBJ/PLY/STL/GLB/USD); "
                   "default a swatch quad at the tile's physical size")
    p.add_argument("--usdz", action="store_true", help="also write the asset as a .usdz package beside it "
                   "(variants and payload kept)")
    p.add_argument("--usdz-ar", action="store_true", help="also write <stem>_ar.usdz for AR viewers: one usdc "
                   "layer, PNG textures, the fitted UsdPreviewSurface only")
    p.add_argument("--lod", help="basis counts of the lod variants besides 'full', e.g. 64,16 "
                   "(default: halvings of k down to 4)")
    p.add_argument("--physical-size", type=float_in(0, 1e4, lo_open=True), nargs=2, metavar=("W", "H"),
                   help="tile size in metres (default: the source's physical_size_m)")
    p.add_argument("--payload-format", choices=PAYLOAD_FORMATS, default="usdc",
                   help="file format of the heavy payload layer (default usdc)")
    p.add_argument("--texture-format", choices=TEXTURE_FORMATS, default="png",
                   help="png (default: what every USD consumer and usdz reads), tx (tiled mip-mapped TIFF "
                        "through maketx) or exr (tiled mip-mapped OpenEXR)")
    p.add_argument("--asset-name", help="assetInfo name (default: the output's file stem)")
    p.add_argument("--asset-version", help="assetInfo version (default: none)")
    p.add_argument("--creator", help="who made the asset: assetInfo and layer metadata (default: none)")
    p.add_argument("--no-thumbnail", action="store_true", help="do not render a thumbnail")
    p.add_argument("--rendering-space", default=None, metavar="SPACE",
                   help="scene-linear space the BTF shaders return, an OCIO name or a USD token (default: "
                        "lin_rec709_scene, linear Rec.709: what UsdPreviewSurface colours and Storm's and "
                        "Blender's frames mean); the BTF data stay in the working space")
    p.add_argument("--no-validate", action="store_true", help="skip the UsdValidation check before publishing")
    p.add_argument("--json", action="store_true", help="print a JSON summary of what was written on stdout")
    p.set_defaults(func=run)


def outputs(args):
    from ..usd.asset.package import asset_pieces
    pieces = asset_pieces(args.output, usdz=args.usdz, usdz_ar=args.usdz_ar, payload_format=args.payload_format)
    return [(args.output.parent / name, kind) for name, _, kind in pieces]


def run(args) -> int:
    from ..errors import UsageError
    from ..usd.asset.package import PackageOptions, check_root_layer, package, write_package

    lods = None
    if args.lod is not None:
        try:
            lods = [int(x) for x in args.lod.split(",") if x.strip()]
        except ValueError:
            raise UsageError(f"--lod {args.lod!r}: expected comma-separated integers") from None
    options = PackageOptions(mesh=args.mesh, usdz=args.usdz, usdz_ar=args.usdz_ar, lods=lods,
                             physical_size=tuple(args.physical_size) if args.physical_size else None,
                             payload_format=args.payload_format, texture_format=args.texture_format,
                             asset_name=args.asset_name, asset_version=args.asset_version, creator=args.creator,
                             thumbnail=not args.no_thumbnail, validate=not args.no_validate,
                             **({} if args.rendering_space is None else {"rendering_space": args.rendering_space}))
    options.check()                  # every option and the output's name checked before anything is read
    check_root_layer(args.output)
    summary = write_package(package(args.input, options), args.output)
    if args.json:
        from . import print_json

        print_json(summary)
    return 0
