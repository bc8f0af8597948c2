"""``usdbtf decompress``: write the reconstruction as a manifest folder."""
from __future__ import annotations

import logging
from pathlib import Path

from ..argtypes import int_in

log = logging.getLogger(__name__)

ORDER = 30


def add_parser(sub) -> None:
    p = sub.add_parser("decompress", help="write the reconstruction as a manifest folder")
    p.add_argument("input", type=Path, help="compressed BTF folder or packaged USD asset (.usda/.usdz)")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.add_argument("--samples", help="indices to write, e.g. 0-99,200 (default all)")
    p.add_argument("--k", type=int_in(1), help="use only the first k basis vectors")
    p.add_argument("--material", help="USD assets: prim path of the BTF material (when there are several)")
    p.add_argument("--lod", help="USD assets: lod variant to read, e.g. k16")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import MANIFEST
    return [(args.output, MANIFEST)]


def run(args) -> int:
    from ..decompress import DecompressOptions, decompress, write_decompress
    from ..io import open_compressed

    cbtf = open_compressed(args.input, material=args.material, lod=args.lod)
    result = decompress(cbtf, DecompressOptions(samples=args.samples, k=args.k))
    write_decompress(result, args.output)
    log.info(f"wrote {len(result.indices)} reconstructed samples (k = {args.k or cbtf.k}) to {args.output}")
    return 0
