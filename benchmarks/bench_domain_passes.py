#!/usr/bin/env python
"""The working-domain choice's coarse pass against its fine pass (issue 27), per input and probe.

For each input folder, with the plain probe (``--k 150``: 150 vectors on 2,048 fitting texels)
and the budget probe (``--max-bytes``: 300 of 500 vectors on 4,096): every candidate's score
(log(encoded %) + log(linear %), :func:`usdbtf.compress.domain_choice.score_domains`) from the
fine pass (:data:`~usdbtf.compress.domain_choice.FINE`) and the coarse pass
(:data:`~usdbtf.compress.domain_choice.COARSE`) on the same loaded data, the gaps to each
pass's best, what each pass alone and the two passes as compress runs them
(:func:`~usdbtf.compress.domain_choice.choose_by_scores`) choose, and the CPU seconds of each
pass (this process, all threads).  Nothing is written.

    .venv/bin/python benchmarks/bench_domain_passes.py FOLDER [FOLDER ...]

Inputs as in RESULTS: ``usdbtf synth PRESET --sampling paper --size 128 -o FOLDER``.
"""
from __future__ import annotations

import sys
import time

from common import format_machine, machine_info
from usdbtf.compress import domain_choice as dc
from usdbtf.compress.options import CompressOptions
from usdbtf.compress.parallel import one_blas_thread
from usdbtf.compress.select_source import load_source
from usdbtf.compress.texels import sample_texels
from usdbtf.io import open_btf

PROBES = {"k": dict(k=150), "budget": dict(max_bytes=10**6)}


def scored(source, texels, k, opts, strides) -> tuple[dict, float]:
    """({name: score}, CPU seconds) of one pass."""
    c = time.process_time()
    scores, _ = dc.score_domains(source, texels, k, opts, strides=strides)
    return {n: v["score"] for n, v in scores.items()}, time.process_time() - c


def main(argv=None) -> int:
    folders = sys.argv[1:] if argv is None else argv
    print(format_machine(machine_info()))
    print(f"\nfine {dc.FINE}, coarse {dc.COARSE}, tie margin {dc.TIE_MARGIN}; gaps fine / coarse\n")
    print("| input | probe | fine alone | coarse alone | two passes | gaps (fine / coarse) | CPU s coarse / fine |")
    print("|---|---|---|---|---|---|---|")
    for folder in folders:
        btf = open_btf(folder)
        for probe, kw in PROBES.items():
            opts = CompressOptions(**kw)
            texels = sample_texels(btf, opts)
            k = opts.fit_k(btf.n_samples, btf.n_pixels)
            with one_blas_thread(), load_source(btf, texels, opts) as source:
                fine, fine_s = scored(source, texels, k, opts, dc.FINE)
                coarse, coarse_s = scored(source, texels, k, opts, dc.COARSE)
                both = dc.choose_by_scores(source, texels, k, opts)[0].name
            fb, cb = min(fine, key=fine.get), min(coarse, key=coarse.get)
            gaps = ", ".join(f"{n} {fine[n] - fine[fb]:+.3f} / {coarse[n] - coarse[cb]:+.3f}" for n in fine)
            print(f"| {folder} | {probe} | {fb} | {cb} | {both} | {gaps} | {coarse_s:.2f} / {fine_s:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
