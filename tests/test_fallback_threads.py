"""The fallback fits run their texel blocks on several threads (issue 42: they ran on one core,
86 of a paper-scale ``--max-bytes`` compress's 152 s).  The blocks are cut by ``chunk_bytes``
alone and each runs on one BLAS thread, so the maps are the same bits on one thread or two,
with every block's rows where they belong."""
from __future__ import annotations

import dataclasses
import threading

import numpy as np


def _same(a, b) -> None:
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x.view(np.uint8), y.view(np.uint8)), field.name


def test_fallback_fits_are_the_same_bits_on_one_thread_or_two(synth_capture, monkeypatch):
    from usdbtf import openpbr, svbrdf
    from usdbtf.compress import CompressOptions, compress
    from usdbtf.compress import parallel
    from usdbtf.io import open_btf

    cbtf = compress(open_btf(synth_capture("metal_flakes", "paper", 32)), CompressOptions(k=12))
    chunk = 1.0          # the smallest blocks, 256 texels: four a fit at 32^2
    calls = []           # the threads each fit_blocks call ran its blocks on
    fit_blocks = svbrdf.fit_blocks

    def watched(fit_block, texels, step, label, logger):
        seen = set()
        calls.append(seen)

        def one(block):
            seen.add(threading.get_ident())
            return fit_block(block)
        return fit_blocks(one, texels, step, label, logger)

    monkeypatch.setattr(svbrdf, "fit_blocks", watched)
    monkeypatch.setattr(openpbr, "fit_blocks", watched)
    monkeypatch.setattr(parallel, "cpu_count", lambda: 2)
    monkeypatch.setattr(svbrdf, "FIT_THREADS", 2)
    ups2 = svbrdf.fit_svbrdf(cbtf, chunk_bytes=chunk)
    pbr2 = openpbr.fit_openpbr(cbtf, svbrdf=ups2, chunk_bytes=chunk)
    # The blocks did run on two threads, and never on more.  Per call: each call has a pool of
    # its own, whose threads need not reuse an earlier pool's identifiers.
    assert max(len(seen) for seen in calls) == 2, [len(seen) for seen in calls]
    monkeypatch.setattr(svbrdf, "FIT_THREADS", 1)
    ups1 = svbrdf.fit_svbrdf(cbtf, chunk_bytes=chunk)
    pbr1 = openpbr.fit_openpbr(cbtf, svbrdf=ups1, chunk_bytes=chunk)
    _same(ups1, ups2)
    _same(pbr1, pbr2)
    # A real fit, every block's texels written: tilted normals on some flakes, no texel left at
    # the maps' initial zeros.
    assert 0 < np.mean(ups1.normal[..., 2] < 0.999) < 1
    assert np.all(np.linalg.norm(ups1.normal, axis=-1) > 0.5)
    assert np.all(np.linalg.norm(pbr1.normal, axis=-1) > 0.5)
