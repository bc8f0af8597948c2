#!/usr/bin/env python
"""Issue 43: the asset's own fallback as the first term of the BTF, a global basis for what it
misses (a probe of "model + residual" before anyone builds it).

The packaged asset already ships a per-texel analytic model of the BTF: the UsdPreviewSurface
fallback's maps (diffuse, specular, roughness, a normal per texel), 0.04-0.10 of the paper's
bytes that count against every budget.  A renderer could evaluate that model and add a global
basis's reconstruction of the residual, in the working domain f:

    I(v, l, t) = f^-1( f(M(v, l, t)) + U[v, l] . c(t) )           (M: the fallback's value)

so the maps would carry part of the BTF instead of being pure overhead, and a texel's
per-direction highlight (a normal, a roughness), which a global basis needs many vectors for,
would cost three numbers.  This probe measures, unquantised, how many basis vectors the
residual needs against the BTF itself to reach the same error:

- the data: the bench's paper-scale dataset (``rlib.load``: 8-bit sRGB codes, decoded by OCIO's
  table), every sample and texel;
- M: ``fallback_count.fit_fallbacks`` of the compressed folder (the fits an asset ships), its
  maps encoded and decoded as shipped (``fallback.encode_maps`` / ``decode_maps``: 8-bit),
  ``svbrdf.evaluate`` at every sample, converted to linear Rec.709;
- f: a power curve x^(1/g) (``--gamma``, the product's ``--domain auto`` choices are 1.6, 2.2,
  3 and sRGB; default 2.2 for every preset: the same f for both arms);
- both arms: one basis over samples shared by the three channels (columns = texel x channel),
  randomized SVD (``compress.linalg.randomized_basis``, one power iteration, K0 vectors), each
  column projected; "plain" on f(X), "model" on f(X) - f(M);
- errors at k = ``--ks`` over every ``--stride``-th sample, all texels and channels, on the 8-bit
  sRGB file values and in scene-linear ACEScg (``rlib.evaluate``, the paper's metric), beside the
  paper's errors when given (``--paper-errors ENC,LIN``), and the fallback alone (k = 0).

Usage (repository root; the compressed folder from ``usdbtf compress DATA -o FOLDER --k 64``)::

    .venv/bin/python benchmarks/probes/probe_issue43_model_residual.py PRESET FOLDER [--gamma 2.2]
        [--ks 8,16,32,64,96,128,192,256] [--stride 12] [--paper-errors 11.396,21.46]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "research"))

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform)
import numpy as np  # noqa: E402

from common import print_header, print_table  # noqa: E402
from rlib import domain, evaluate, load  # noqa: E402


def model_values(folder: Path, view, light):
    """(S, P, 3) float32 linear Rec.709: the shipped UsdPreviewSurface fallback of the compressed
    folder evaluated at every sample (maps through their 8-bit files, as a renderer reads them)."""
    from usdbtf import color, svbrdf
    from usdbtf.compress.format import read_compressed
    from usdbtf.photometry import white_level_of
    from usdbtf.usd.asset import fallback as ups
    from usdbtf.usd.asset.fallback_count import fit_fallbacks

    cbtf = read_compressed(folder)
    white = white_level_of(cbtf.info)
    fitted, _, _ = fit_fallbacks(cbtf, white)
    maps = ups.decode_maps(ups.encode_maps(fitted, cbtf.ocio_config), cbtf.working_space,
                           ocio_config=cbtf.ocio_config, white_level=white)
    to_709 = color.processor(cbtf.working_space, color.RENDERING_SPACE, cbtf.ocio_config)
    out = np.empty((len(view), cbtf.width * cbtf.height, 3), np.float32)
    for a in range(0, len(view), 256):
        b = min(a + 256, len(view))
        out[a:b] = to_709.apply(np.ascontiguousarray(svbrdf.evaluate(maps, view[a:b], light[a:b])))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("preset")
    ap.add_argument("folder", type=Path, help="a compressed folder of the preset's paper-scale data")
    ap.add_argument("--gamma", type=float, default=2.2)
    ap.add_argument("--ks", default="8,16,32,64,96,128,192,256")
    ap.add_argument("--stride", type=int, default=12)
    ap.add_argument("--sampling", default="paper")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--paper-errors", default=None, help="ENC,LIN: the paper's errors, for the ratios")
    args = ap.parse_args(argv)
    ks = [int(x) for x in args.ks.split(",")]
    k0 = max(ks)

    from usdbtf.compress.linalg import randomized_basis

    print_header(f"# issue 43: fallback model + residual basis against the basis alone ({args.preset})")
    data = load(args.preset, args.sampling, args.size)
    f = domain(f"gamma{args.gamma:g}")
    S, P = data.S, data.P
    t0 = time.perf_counter()
    x = np.empty((S, P * 3), np.float32)                         # f(X), then reused
    for a in range(0, S, 512):
        x[a:a + 512] = f.forward(data.lut[np.asarray(data.codes[a:a + 512])]).reshape(-1, P * 3)
    view, light = data.sampling.view, data.sampling.light
    model = model_values(args.folder, view, light)
    fm = np.empty_like(x)
    for a in range(0, S, 512):
        fm[a:a + 512] = f.forward(model[a:a + 512]).reshape(-1, P * 3)
    print(f"- data and model in {time.perf_counter() - t0:.1f} s; S {S}, texels {P}, K0 {k0}, f = x^(1/{args.gamma:g})")
    rows = np.arange(0, S, args.stride)
    paper = [float(v) for v in args.paper_errors.split(",")] if args.paper_errors else None

    def report(name, k, errs):
        ratio = "" if paper is None else f"  ({errs.encoded / paper[0]:.3f} / {errs.linear / paper[1]:.3f} of the paper's)"
        print(f"| {name} | {k} | {errs.encoded:.3f} | {errs.linear:.3f} |{ratio}", flush=True)

    report("fallback alone", 0, evaluate(data, lambda sel: model[sel].reshape(len(sel), P, 3), rows))
    del model
    results = {}
    for name, offset in (("plain", None), ("model", fm)):
        t0 = time.perf_counter()
        if offset is not None:
            x -= offset                                        # the residual f(X) - f(M), in place
        u, sv, coeff = randomized_basis(x, k0, return_coefficients=True)
        energy = sum(float(np.einsum("ij,ij->", x[a:a + 512], x[a:a + 512], dtype=np.float64))
                     for a in range(0, S, 512))
        print(f"- {name}: fit {time.perf_counter() - t0:.1f} s; energy {energy:.4g}, captured by {k0}: "
              f"{float(np.square(sv).sum()) / energy:.5f}")
        for k in ks:
            def recon(sel, k=k):
                d = u[sel, :k] @ coeff[:k]
                if offset is not None:
                    d += offset[sel]
                return f.inverse(d).reshape(len(sel), P, 3)
            errs = evaluate(data, recon, rows)
            results[(name, k)] = errs
            report(name, k, errs)
        del u, coeff
    table = []
    for k in ks:
        p, m = results[("plain", k)], results[("model", k)]
        table.append(f"| {k} | {p.encoded:.3f} / {p.linear:.3f} | {m.encoded:.3f} / {m.linear:.3f} |")
    print_table(["k", "plain enc / lin", "model + residual enc / lin"], table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
