"""``usdbtf quilt``: image quilting in coefficient space -> a larger compressed BTF (or an atlas)."""
from __future__ import annotations

import logging
from pathlib import Path

from ..argtypes import MAX_TEXTURE_SIDE, SEED, float_in, int_in

log = logging.getLogger(__name__)
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
                   help="block side in texels (default: a quarter of the sample, 6..64)")
    p.add_argument("--overlap", type=int_in(0, MAX_TEXTURE_SIDE), help="block overlap in texels (default: block / 4, at least 3)")
    p.add_argument("--tolerance", type=float_in(0, 100), default=0.1,
                   help="pick among blocks within (1 + T) x the best overlap error (default 0.1)")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--no-ghosts", action="store_true",
                   help="atlas: do not match chart borders against neighbouring charts (for comparison)")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import COMPRESSED
    return [(args.output, COMPRESSED)]


def run(args) -> int:
    import time

    from ..errors import UsageError
    from ..quilt import QuiltOptions, quilt, write_quilt
    from ..resources import require_memory

    t0 = time.perf_counter()
    if args.size is not None:
        # Position map, matching features of the m leading textures, one gathered texture.
        m = args.m or 4
        require_memory(args.size[0] * args.size[1] * (16.0 * m + 64), f"quilt --size {args.size[0]} {args.size[1]}",
                       error=UsageError)
    if args.atlas is None and args.no_ghosts:
        raise UsageError("--no-ghosts applies to --atlas only")
    opts = QuiltOptions(block=args.block, overlap=args.overlap, m=args.m, tolerance=args.tolerance, seed=args.seed,
                        tileable=args.tileable, size=tuple(args.size) if args.size is not None else None,
                        ghosts=not args.no_ghosts)
    q = quilt(args.input, opts, atlas=args.atlas)
    synth_s = time.perf_counter() - t0
    cbtf = q.source
    log.info(f"quilted {q.width}x{q.height} from {cbtf.width}x{cbtf.height} ({q.record['blocks']} blocks of "
             f"{q.options.block}, overlap {q.options.overlap}, m = {q.options.m}) in {synth_s:.2f} s; "
             f"seam error {q.record['seam_error']['all_samples_mean']:.4g}")
    sizes = write_quilt(q, args.output)
    log.info(f"wrote {cbtf.k} coefficient textures ({sizes['payload']} bytes) to {args.output} "
             f"in {time.perf_counter() - t0 - synth_s:.2f} s")
    return 0
