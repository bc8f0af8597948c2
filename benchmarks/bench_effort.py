#!/usr/bin/env python
"""JPEG XL effort against bytes and time for compress's stored textures (issue 27, item 3).

Reads the coefficient textures and the basis image of a ``usdbtf compress`` output folder
(their stored integers), encodes them again in memory at each effort with the output's codec
settings otherwise (planar files for ``jxlp``), one texture at a time on one thread, and prints
per effort: total bytes, relative to effort 7 (the budget modes' effort), and encode seconds
(the median of ``--repeats`` passes).  Every encode is decoded back and checked to give the
same integers (a lossless effort that does not round-trip is marked).  An effort written
``EsT`` (e.g. ``7s1``) also sets JPEG XL's decoding-speed tier T (``jpegxl:speed``, 0-4:
higher tiers restrict the encoder's modelling for faster decoding, and also encode faster).

    .venv/bin/python benchmarks/bench_effort.py OUT_FOLDER [--efforts 2,3,4,5,7,7s1,7s2] [--repeats 1]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import format_machine, machine_info, median


def main(argv=None) -> int:
    from usdbtf.compress import read_compressed
    from usdbtf.compress.codecs import Codec, Stored, get_codec
    from usdbtf.compress.format import basis_layout, basis_to_image

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder")
    ap.add_argument("--efforts", default="2,3,4,5,7")
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args(argv)
    print(f"command: {' '.join([sys.executable, *sys.argv])}")
    print(format_machine(machine_info()))
    cbtf = read_compressed(args.folder)
    base = get_codec(cbtf.codec)
    print(f"input: {args.folder}: codec {cbtf.codec}, k = {cbtf.k}, {cbtf.width}x{cbtf.height} texels; "
          f"load {os.getloadavg()[0]:.1f}")
    rows = []
    for setting in args.efforts.split(","):
        effort, _, tier = setting.strip().partition("s")
        extra = {"jpegxl:effort": int(effort), **({"jpegxl:speed": int(tier)} if tier else {})}
        attrs = dict(base.attributes, **extra)
        battrs = dict(base.basis_attributes, **extra)
        codec = replace(base, attributes=attrs, basis_attributes=battrs)
        times, coeff_bytes, ok = [], 0, True
        for _ in range(args.repeats):
            t = time.perf_counter()
            data = [codec.encode(st, "data") for st in cbtf.coefficients]
            times.append(time.perf_counter() - t)
            coeff_bytes = sum(len(d) for d in data)
        for d, st in zip(data[:8], cbtf.coefficients[:8]):
            back = codec.texture(Codec.decode(d), st.pixels.shape[:2])
            ok = ok and np.array_equal(back.reshape(st.pixels.shape), st.pixels)
        t = time.perf_counter()
        layout = basis_layout(cbtf.sampling, cbtf.k, cbtf.codec)
        image = Stored(basis_to_image(cbtf.basis.pixels, layout), cbtf.basis.scale, cbtf.basis.bias)
        basis = len(codec.encode(image, "data", basis=True))
        basis_s = time.perf_counter() - t
        rows.append((setting.strip(), coeff_bytes, median(times), basis, basis_s, ok))
        print(f"  effort {setting.strip()}: coefficients {coeff_bytes} bytes in {median(times):.2f} s"
              f"; basis {basis} bytes in {basis_s:.2f} s{'' if ok else ' (NOT lossless)'}",
              flush=True)
    ref = {e: b for e, b, *_ in rows}.get("7", rows[-1][1])
    print("\n| effort | coefficient bytes | vs effort 7 | encode s (one thread) | basis bytes | basis s | round trip |"
          "\n|---|---|---|---|---|---|---|")
    for e, b, s, bb, bs, ok in rows:
        print(f"| {e} | {b} | {b / ref:.3f} | {s:.2f} | {bb} | {bs:.2f} | {'exact' if ok else 'FAILED'} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
