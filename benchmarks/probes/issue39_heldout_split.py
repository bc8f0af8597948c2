"""Issue 39 probe: where compress's held-out error estimate departs from the exact error.

For a compressed folder of INPUT, the exact paper metric on the 8-bit file values
(100 sum|x - x'| / sum x, the reconstruction encoded as a file holds it) summed per texel
over all samples, then reported over: all texels; the fitting texels (in-sample); the
texels not fitted; compress's held-out (evaluation) texels.  The texel sets are recomputed
from the folder's recorded options (``usdbtf.compress.texels.sample_texels``).

    .venv/bin/python benchmarks/probes/issue39_heldout_split.py INPUT FOLDER [FOLDER ...]
"""
from __future__ import annotations

import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "pipeline"))


def main() -> None:
    from usdbtf import color
    from usdbtf.compress.format import read_compressed, reconstruct
    from usdbtf.compress.options import CompressOptions
    from usdbtf.compress.texels import sample_texels
    from usdbtf.io import open_btf
    from usdbtf.manifest import encode_for_file

    src, folders = sys.argv[1], sys.argv[2:]
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, load {os.getloadavg()[0]:.2f}")
    orig = open_btf(src)
    print(f"input: {src} ({orig.width}x{orig.height}, {orig.n_samples} samples, {orig.bit_depth})")
    to_file = color.processor(orig.working_space, orig.color_space, orig.ocio_config)
    for folder in folders:
        meta = json.loads((Path(folder) / "btf-compressed.json").read_text())
        o = meta["provenance"]["options"]
        opts = CompressOptions(solver=o["solver"], target_error=o.get("target_error"), max_bytes=o.get("max_bytes"),
                               k=o.get("k"), seed=o["seed"], fit_texels=o.get("fit_texels"), region=o.get("region"),
                               eval_texels=o["eval_texels"])
        tex = sample_texels(orig, opts)
        cbtf = read_compressed(folder)
        P = orig.n_pixels
        err, tot = np.zeros(P), np.zeros(P)
        for a in range(0, orig.n_samples, 256):
            sel = np.arange(a, min(a + 256, orig.n_samples))
            stored = orig.read_encoded(sel).reshape(len(sel), P, 3).astype(np.float64)
            rec = encode_for_file(reconstruct(cbtf, sel), to_file, orig.bit_depth).reshape(len(sel), P, 3)
            err += np.abs(stored - rec).sum(axis=(0, 2))
            tot += stored.sum(axis=(0, 2))
        pct = lambda m: 100.0 * err[m].sum() / tot[m].sum() if np.any(m) else float("nan")
        fit = np.zeros(P, bool)
        fit[tex.fit] = True
        ev = np.zeros(P, bool)
        ev[tex.evaluation] = True
        est = meta["estimated_error"]["encoded"]["percent"]
        # The stratified estimate: the held-out texels stand for the unfitted ones, the fit's for itself.
        w = (~fit).sum() / ev.sum() if tex.held_out else 0.0
        strat = 100.0 * (err[fit].sum() + err[ev].sum() * w) / (tot[fit].sum() + tot[ev].sum() * w)
        print(f"{folder}: k {cbtf.k}, fit {fit.sum()} texels, eval {ev.sum()} (held out {tex.held_out}); "
              f"compress's estimate {est:.4f} %")
        print(f"  exact enc %: all {pct(slice(None)):.4f}, fit {pct(fit):.4f}, not fit {pct(~fit):.4f}, "
              f"eval {pct(ev):.4f}; stratified (fit + eval) {strat:.4f}")
        if tex.held_out:
            # How far a held-out sample of n random runs of RUN texels strays from the unfitted
            # texels' error: 400 draws (seeded) per n, the 5/50/95 % points of estimate / truth.
            from usdbtf.compress.texels import RUN
            runs = np.setdiff1d(np.arange(P // RUN), np.unique(tex.fit // RUN))
            e_run = err[:P // RUN * RUN].reshape(-1, RUN).sum(1)[runs]
            t_run = tot[:P // RUN * RUN].reshape(-1, RUN).sum(1)[runs]
            truth = e_run.sum() / t_run.sum()
            rng = np.random.default_rng(0)
            for n in (16, 32, 64, 128):
                if n > len(runs):
                    continue
                r = [e_run[d].sum() / t_run[d].sum() / truth for d in
                     (rng.choice(len(runs), n, replace=False) for _ in range(400))]
                q = np.percentile(r, [5, 50, 95])
                print(f"  held-out sample of {n} runs ({n * RUN} texels): estimate / unfitted error "
                      f"5 % {q[0]:.3f}, median {q[1]:.3f}, 95 % {q[2]:.3f}")


if __name__ == "__main__":
    main()
