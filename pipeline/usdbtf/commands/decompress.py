"""``usdbtf decompress``: write the reconstruction as a manifest folder."""
from __future__ import annotations

from pathlib import Path

from . import log
from ..argtypes import int_in

ORDER = 30


def add_parser(sub) -> None:
    p = sub.add_parser("decompress", help="write the reconstruction as a manifest folder")
    p.add_argument("input", type=Path, help="compressed BTF folder or packaged USD asset (.usda/.usdz)")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.add_argument("--samples", help="indices to write, e.g. 0-99,200 (default all)")
    p.add_argument("--k", type=int_in(1), help="use only the first k basis vectors")
    p.add_argument("--material", help="USD assets: prim path of the BTF material (when there are several)")
    p.add_argument("--lod", help="USD assets: lod variant to read, e.g. k16")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import MANIFEST
    return [(args.output, MANIFEST)]


def run(args) -> int:
    from ..compress.decompress import decompress_to_folder, parse_samples
    from ..errors import UsageError
    from ..io import open_compressed
    from ..resources import require_memory

    cbtf = open_compressed(args.input, material=args.material, lod=args.lod)
    idx = parse_samples(args.samples, cbtf.n_samples)
    if args.k is not None and not (1 <= args.k <= cbtf.k):
        raise UsageError(f"--k must be in 1..{cbtf.k} for {args.input}")
    k = args.k or cbtf.k
    # The k working-space coefficient textures, and a chunk of 128 reconstructions.
    require_memory(cbtf.width * cbtf.height * 3 * 4 * (k + min(128, len(idx))), f"decompressing {args.input}")
    decompress_to_folder(cbtf, args.output, samples=idx, k=args.k)
    log(args.quiet)(f"wrote {len(idx)} reconstructed samples (k = {args.k or cbtf.k}) to {args.output}")
    return 0
