"""``usdbtf error``: percent error, RMSE, PSNR of a reconstruction against the original."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import BTFError

from ..argtypes import add_outside_paths_flag

ORDER = 40


def add_parser(sub) -> None:
    p = sub.add_parser("error", help="percent error, RMSE, PSNR of a reconstruction against the original")
    p.add_argument("original", type=Path)
    p.add_argument("reconstruction", type=Path)
    p.add_argument("--samples", help="restrict to these original sample indices")
    add_outside_paths_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from ..compress.decompress import compare, parse_samples
    from ..io import open_btf
    from ..resources import require_memory

    orig = open_btf(args.original)
    other = open_btf(args.reconstruction)
    if (other.width, other.height) != (orig.width, orig.height):
        raise BTFError(f"{args.reconstruction}: size {other.width}x{other.height} differs from "
                       f"{args.original}'s {orig.width}x{orig.height}")
    # Match samples by direction, so a partial reconstruction (--samples) compares correctly.
    key = {tuple(np.round(np.r_[v, l], 6)): i for i, (v, l) in enumerate(zip(orig.sampling.view, orig.sampling.light))}
    pos = []
    for v, l in zip(other.sampling.view, other.sampling.light):
        i = key.get(tuple(np.round(np.r_[v, l], 6)))
        if i is None:
            raise BTFError(f"{args.reconstruction}: sample view {v.tolist()} light {l.tolist()} is not in {args.original}")
        pos.append(i)
    pos = np.asarray(pos)
    order = {int(o): n for n, o in enumerate(pos)}
    wanted = parse_samples(args.samples, orig.n_samples) if args.samples else np.sort(pos)
    missing = [int(w) for w in wanted if int(w) not in order]
    if missing:
        raise BTFError(f"{args.reconstruction}: has no reconstruction of original sample {missing[0]} "
                       f"({orig.names[missing[0]]})")
    # Per sample: stored, decoded and reconstructed images plus the encoded copy (float32).
    per_sample = orig.width * orig.height * 3 * 4 * 5
    require_memory(per_sample, f"comparing {orig.width}x{orig.height} images")
    chunk = int(max(1, min(256, 1e9 // per_sample)))
    report = compare(orig, lambda sel: other.read_samples([order[int(s)] for s in sel]), wanted, chunk=chunk)
    print(json.dumps(report, indent=1))
    return 0
