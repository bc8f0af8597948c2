"""``usdbtf synth``: write a synthetic BTF (manifest folder) from a procedural material."""
from __future__ import annotations

import logging
import time
from pathlib import Path

from ..argtypes import SEED, float_in, int_in

log = logging.getLogger(__name__)

#: Largest synthetic sample side (texels); memory grows with its square.
MAX_SIZE = 4096

ORDER = 10


def add_parser(sub) -> None:
    from ..sampling import PRESETS as SAMPLINGS
    p = sub.add_parser("synth", help="write a synthetic BTF (manifest folder) from a procedural material")
    p.add_argument("preset", help="material: pebbles, ridged_fabric, fuzzy_moss, crevice_stones, metal_flakes, "
                                  "velvet or satin_weave")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.add_argument("--sampling", default="small", choices=sorted(SAMPLINGS), help="direction set (default small)")
    p.add_argument("--size", type=int_in(8, MAX_SIZE), default=128, help=f"texels per side, 8..{MAX_SIZE} "
                   "(default 128)")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--format", default="png", choices=["png", "exr", "tif", "jpg"], help="image file type")
    p.add_argument("--bit-depth", default="uint8", choices=["uint8", "uint16", "half", "float"])
    p.add_argument("--color-space", help="OCIO space of the files (default sRGB for integers, linear Rec.709 for floats)")
    p.add_argument("--physical-size", type=float_in(0, 100, lo_open=True), default=0.05,
                   help="edge length of the tile in metres (default 0.05)")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import MANIFEST
    return [(args.output, MANIFEST)]


def run(args) -> int:
    from .. import synth
    from ..errors import UsageError
    from ..resources import require_memory
    from ..synth import SynthOptions, write_synth

    t0 = time.perf_counter()
    if args.preset not in synth.PRESETS:
        raise UsageError(f"unknown material preset {args.preset!r}; choose from {', '.join(synth.PRESETS)}")
    # Height field, per-view hit maps and shading temporaries: about 256 bytes a texel.
    require_memory(256.0 * args.size ** 2, f"synth --size {args.size}", error=UsageError)
    options = SynthOptions(size=args.size, seed=args.seed, sampling=args.sampling, physical_size=args.physical_size,
                           ext=args.format, bit_depth=args.bit_depth, color_space=args.color_space)
    result = synth.synth(args.preset, options)
    write_synth(result, args.output)
    log.info(f"wrote {len(result.sampling)} samples of {args.preset} ({args.size}x{args.size}, {args.bit_depth} "
             f"{options.file_space}) to {args.output} in {time.perf_counter() - t0:.1f} s")
    return 0
