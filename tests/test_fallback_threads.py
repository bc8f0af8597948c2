"""The fallback fits run their texel blocks on threads (issue 42: ``compress --max-bytes``
packages a near choice to count the asset's bytes, and the two fits were most of its time):
the maps must have the bits of the blocks fitted one after the other."""
from __future__ import annotations

import dataclasses

import numpy as np


def test_fallback_fits_on_threads_give_the_bits_of_one_block_after_another(synth_capture, monkeypatch):
    from usdbtf import openpbr, svbrdf
    from usdbtf.compress import CompressOptions, compress
    from usdbtf.io import open_btf

    cbtf = compress(open_btf(synth_capture("pebbles", "small", 32)), CompressOptions(k=12))
    # Small blocks: 1,024 texels in several blocks of each fit and of the pole sums.
    chunk = 4e6
    assert -(-1024 // svbrdf._chunk_texels(1536, chunk)) >= 3 and -(-1024 // openpbr._chunk_texels(768, chunk)) >= 3
    maps = {}
    for threads in (1, 2):
        monkeypatch.setattr(svbrdf, "FIT_THREADS", threads)
        preview = svbrdf.fit_svbrdf(cbtf, chunk_bytes=chunk)
        maps[threads] = (preview, openpbr.fit_openpbr(cbtf, svbrdf=preview, chunk_bytes=chunk))
    for one, two in zip(maps[1], maps[2]):
        for field in dataclasses.fields(one):
            a, b = getattr(one, field.name), getattr(two, field.name)
            if isinstance(a, np.ndarray):
                assert a.dtype == b.dtype and np.array_equal(a.view(np.uint8), b.view(np.uint8)), field.name
    preview = maps[2][0]
    # A real fit, not zeros: the albedo spans the pebbles' colours and some texels have a normal.
    assert np.all(np.isfinite(preview.diffuse)) and np.ptp(preview.diffuse) > 0.05
    assert 0 < np.mean(preview.normal[..., 2] < 0.999) < 1
