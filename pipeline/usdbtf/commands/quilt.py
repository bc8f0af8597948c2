"""``usdbtf quilt``: image quilting in coefficient space -> a larger compressed BTF (or an atlas)."""
from __future__ import annotations

from pathlib import Path

from . import log
from ..argtypes import MAX_TEXTURE_SIDE, SEED, float_in, int_in

ORDER = 56


def add_parser(sub) -> None:
    p = sub.add_parser("quilt", help="synthesise larger coefficient textures by image quilting (or fill an atlas)")
    p.add_argument("input", type=Path, help="compressed BTF folder")
    p.add_argument("-o", "--output", required=True, type=Path, help="output compressed BTF folder")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--size", type=int_in(1, MAX_TEXTURE_SIDE), nargs=2, metavar=("W", "H"),
                       help=f"output size in texels (1..{MAX_TEXTURE_SIDE} each)")
    where.add_argument("--atlas", type=Path, metavar="MESH_USDA",
                       help="quilt into the atlas of this `usdbtf unwrap` layer (charts.png beside it)")
    p.add_argument("--tileable", action="store_true", help="the output wraps around seamlessly")
    p.add_argument("--m", type=int_in(1), help="leading coefficient textures compared in block matching (default 4)")
    p.add_argument("--block", type=int_in(1, MAX_TEXTURE_SIDE),
                   help="block side in texels (default: a quarter of the sample, 8..64)")
    p.add_argument("--overlap", type=int_in(0, MAX_TEXTURE_SIDE), help="block overlap in texels (default: block / 6)")
    p.add_argument("--tolerance", type=float_in(0, 100), default=0.1,
                   help="pick among blocks within (1 + T) x the best overlap error (default 0.1)")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--no-ghosts", action="store_true",
                   help="atlas: do not match chart borders against neighbouring charts (for comparison)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import COMPRESSED
    return [(args.output, COMPRESSED)]


def run(args) -> int:
    import time

    from ..compress import read_compressed
    from ..errors import UsageError
    from ..quilt import QuiltOptions, quilt, write_quilted
    from ..resources import require_memory

    say = log(args.quiet)
    t0 = time.perf_counter()
    cbtf = read_compressed(args.input)
    if args.size is not None:
        # Position map, matching features of the m leading textures, one gathered texture.
        m = args.m or 4
        require_memory(args.size[0] * args.size[1] * (16.0 * m + 64), f"quilt --size {args.size[0]} {args.size[1]}",
                       error=UsageError)
    opts = QuiltOptions(block=args.block, overlap=args.overlap, m=args.m, tolerance=args.tolerance, seed=args.seed,
                        tileable=args.tileable)
    if args.atlas is not None:
        from ..quilt.atlas import quilt_atlas
        from ..unwrap import read_unwrap

        q = quilt_atlas(cbtf, read_unwrap(args.atlas), opts, ghosts=not args.no_ghosts, log=say)
        q.record["atlas"]["layer"] = str(args.atlas)
    else:
        if args.no_ghosts:
            raise UsageError("--no-ghosts applies to --atlas only")
        q = quilt(cbtf, args.size[0], args.size[1], opts)
    synth_s = time.perf_counter() - t0
    say(f"quilted {q.width}x{q.height} from {cbtf.width}x{cbtf.height} ({q.record['blocks']} blocks of "
        f"{q.options.block}, overlap {q.options.overlap}, m = {q.options.m}) in {synth_s:.2f} s; "
        f"seam error {q.record['seam_error']['all_samples_mean']:.4g}")
    sizes = write_quilted(cbtf, q, args.output, source_folder=args.input, log=say)
    say(f"wrote {cbtf.k} coefficient textures ({sizes['payload']} bytes) to {args.output} "
        f"in {time.perf_counter() - t0 - synth_s:.2f} s")
    return 0
