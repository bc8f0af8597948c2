"""``usdbtf unwrap``: a mesh -> USD geometry layer with an xatlas atlas at the sample's texel density."""
from __future__ import annotations

from pathlib import Path

from ..argtypes import MAX_TEXTURE_SIDE, float_in, int_in

ORDER = 54
#: Densest texel spacing unwrap accepts: 1e6 texels per metre (1 micrometre texels).
MAX_DENSITY = 1e6


def add_parser(sub) -> None:
    p = sub.add_parser("unwrap", help="mesh -> USD geometry layer with an atlas at the sample's texel density")
    p.add_argument("mesh", type=Path, help="OBJ/PLY/STL/GLB/glTF/OFF or USD mesh")
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="output folder (mesh.usda, charts.png, unwrap.json)")
    density = p.add_mutually_exclusive_group(required=True)
    density.add_argument("--btf", type=Path, metavar="COMPRESSED",
                         help="compressed BTF whose physical_size_m sets the texel density")
    density.add_argument("--texels-per-metre", type=float_in(0, MAX_DENSITY, lo_open=True), metavar="D",
                         help=f"texel density directly (0 < D <= {MAX_DENSITY:g})")
    p.add_argument("--keep-uvs", action="store_true",
                   help="keep the mesh's texture coordinates when they are usable (else unwrap)")
    p.add_argument("--no-orient-charts", dest="orient_charts", action="store_false",
                   help="leave every chart as xatlas or the mesh's UVs oriented it (default: turn charts by "
                        "quarter turns so the texture's axes continue across chart borders, and pack them again)")
    p.add_argument("--max-resolution", type=int_in(16, MAX_TEXTURE_SIDE), default=4096,
                   help=f"atlas side cap in texels, 16..{MAX_TEXTURE_SIDE} (default 4096)")
    p.add_argument("--padding", type=int_in(1, 64), default=4, help="gutter texels between charts, 1..64 (default 4)")
    p.add_argument("--meters-per-unit", type=float_in(0, 1e6, lo_open=True),
                   help="scale of the mesh's units (default: the file's, else 1)")
    p.add_argument("--up-axis", choices=["Y", "Z"], help="up axis to declare (default: the file's, else Y)")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import UNWRAP
    return [(args.output, UNWRAP)]


def run(args) -> int:
    from ..mesh import load_mesh
    from ..unwrap import UnwrapOptions, texel_density, unwrap, write_unwrap

    if args.btf is not None:
        from ..compress import read_compressed
        from ..errors import BTFError

        density = texel_density(read_compressed(args.btf), str(args.btf))
        if not 0 < density <= MAX_DENSITY:
            raise BTFError(f"{args.btf}: its physical size gives {density:g} texels per metre, outside "
                           f"(0, {MAX_DENSITY:g}]")
    else:
        density = args.texels_per_metre
    opts = UnwrapOptions(texels_per_metre=density, keep_uvs=args.keep_uvs, max_resolution=args.max_resolution,
                         padding=args.padding, orient_charts=args.orient_charts)
    opts.validate()                     # every number checked before the mesh is read
    mesh = load_mesh(args.mesh, meters_per_unit=args.meters_per_unit, up_axis=args.up_axis)
    write_unwrap(unwrap(mesh, opts), args.output)
    return 0
