"""Issue 39 probe: does the budget modes' basis, fitted on a sample of the texels, generalise?

For one paper-scale input, in one working domain: the rsvd basis is fitted exactly as a
budgeted compress fits it (``usdbtf.compress.fit.fit_basis`` on ``source.columns`` of the
texels ``usdbtf.compress.texels.sample_texels`` picks, 500 vectors: ``BUDGET_K``) from N
fitting texels; then every texel is projected on the first k vectors (all three channels
on the same k, no colour rotation, no quantisation) and the error is reported over the
fitting texels, the other texels and the whole image:

* ``l2``: sqrt(sum ||x - U_k U_k^T x||^2 / sum ||x||^2), in percent, in the working domain;
* ``l1``: 100 sum |x - U_k U_k^T x| / sum |x|, in the working domain (for the sRGB/power
  curves the budget modes choose, a proxy of the encoded-value metric bench_issue16 reports).

It also prints the fit's CPU seconds (process time of the fit alone) and the process's peak
RSS (``ru_maxrss``; run one fit size per process for a clean figure).

    .venv/bin/python benchmarks/probes/issue39_fit_texels.py INPUT --domain srgb --fit-texels 4096 \
        [--ks 150,288] [--max-bytes B] [--seed 0] [--streamed]

``--streamed`` fits with ``usdbtf.compress.fit.streamed_fit`` where this tree has it (the
fit that never holds all fitting columns at once), else the flag is refused.
"""
from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "pipeline"))

import usdbtf  # noqa: E402,F401  (before numpy: pins the numeric platform)
import numpy as np  # noqa: E402

#: Texels per projection chunk of the error pass.
CHUNK = 1024


def main() -> None:
    from usdbtf.compress.domain import parse_domain
    from usdbtf.compress.fit import fit_basis
    from usdbtf.compress.options import CompressOptions
    from usdbtf.compress.parallel import one_blas_thread, rows_gemm
    from usdbtf.compress.source import InMemorySource
    from usdbtf.compress.texels import sample_texels
    from usdbtf.io import open_btf

    ap = argparse.ArgumentParser()
    ap.add_argument("input")
    ap.add_argument("--domain", required=True)
    ap.add_argument("--fit-texels", type=int, required=True)
    ap.add_argument("--ks", default="150,288")
    ap.add_argument("--max-bytes", type=int, default=3_000_000, help="any budget: only makes the options budgeted")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--streamed", action="store_true")
    ap.add_argument("--power-iterations", type=int, default=1, help="the rsvd's power iterations (compress's default 1)")
    a = ap.parse_args()
    ks = [int(k) for k in a.ks.split(",")]

    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, load {os.getloadavg()[0]:.2f}")
    btf = open_btf(a.input)
    print(f"input: {a.input} ({btf.width}x{btf.height}, {btf.n_samples} samples), domain {a.domain}")
    opts = CompressOptions(max_bytes=a.max_bytes, fit_texels=a.fit_texels, seed=a.seed,
                           power_iterations=a.power_iterations)
    texels = sample_texels(btf, opts)
    k_fit = opts.fit_k(btf.n_samples, btf.n_pixels)
    with one_blas_thread():
        source = InMemorySource(btf)
        source.set_domain(parse_domain(a.domain))
        c0 = time.process_time()
        w0 = time.perf_counter()
        if a.streamed:
            from usdbtf.compress.fit import streamed_fit
            fit = streamed_fit(source, texels.fit, k_fit, opts)
        else:
            x = source.columns(texels.fit)
            fit = fit_basis(x, k_fit, opts)
            del x
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        rss_fit = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
        print(f"fit: {len(texels.fit)} texels, {fit.k} vectors, {cpu:.1f} CPU s ({wall:.1f} s wall), "
              f"peak RSS so far {rss_fit:.2f} GB")
        u = fit.basis
        P = btf.n_pixels
        in_fit = np.zeros(P, bool)
        in_fit[texels.fit] = True
        # per texel: total energy, residual energy at each k, total |x|, residual |x - x_k|
        tot2, tot1 = np.zeros(P), np.zeros(P)
        res2, res1 = np.zeros((len(ks), P)), np.zeros((len(ks), P))
        for t0 in range(0, P, CHUNK):
            tex = np.arange(t0, min(P, t0 + CHUNK))
            xc = source.columns(tex)                       # (S, 3 m)
            c = rows_gemm(u.T, xc)                         # (k, 3 m)
            tot2[tex] = np.einsum("st,st->t", xc, xc, dtype=np.float64).reshape(-1, 3).sum(1)
            tot1[tex] = np.abs(xc).sum(0, dtype=np.float64).reshape(-1, 3).sum(1)
            for i, k in enumerate(ks):
                r = xc - rows_gemm(u[:, :k], c[:k])
                res2[i, tex] = np.einsum("st,st->t", r, r, dtype=np.float64).reshape(-1, 3).sum(1)
                res1[i, tex] = np.abs(r).sum(0, dtype=np.float64).reshape(-1, 3).sum(1)
    for i, k in enumerate(ks):
        def pct(m):
            return (100 * np.sqrt(res2[i, m].sum() / tot2[m].sum()), 100 * res1[i, m].sum() / tot1[m].sum())
        parts = {"fit": in_fit, "not fit": ~in_fit, "all": np.ones(P, bool)}
        text = ", ".join(f"{name} l2 {pct(m)[0]:.4f} l1 {pct(m)[1]:.4f}" for name, m in parts.items()
                         if m.any())
        print(f"k {k}: {text}")
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20:.2f} GB")


if __name__ == "__main__":
    main()
