"""The UsdPreviewSurface fit reconstructs each texel block once per distinct set of samples
(issue 42): on the paper sampling its photometric-stereo samples are its pole samples, and
reusing their values must give the maps of reconstructing them twice, bit for bit."""
from __future__ import annotations

import dataclasses

import numpy as np


def test_paper_sampling_pole_values_serve_the_normals_with_the_same_bits(synth_capture, monkeypatch):
    from usdbtf import svbrdf
    from usdbtf.compress import CompressOptions, compress
    from usdbtf.io import open_btf

    cbtf = compress(open_btf(synth_capture("metal_flakes", "paper", 8)), CompressOptions(k=12))
    assert np.array_equal(svbrdf.normal_samples(cbtf), svbrdf.pole_samples(cbtf))
    calls = []
    block_values = svbrdf._block_values

    def counted(c, texels):
        values = block_values(c, texels)
        return lambda rows: calls.append(len(rows)) or values(rows)

    monkeypatch.setattr(svbrdf, "_block_values", counted)
    shared = svbrdf.fit_svbrdf(cbtf, brightness=False)
    pole = len(svbrdf.pole_samples(cbtf))
    assert calls.count(pole) == 1          # one block: the pole samples reconstructed once
    monkeypatch.setattr(svbrdf, "_same_samples", lambda a, b: False)
    calls.clear()
    twice = svbrdf.fit_svbrdf(cbtf, brightness=False)
    assert calls.count(pole) == 2
    for field in dataclasses.fields(shared):
        a, b = getattr(shared, field.name), getattr(twice, field.name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a.view(np.uint8), b.view(np.uint8)), field.name
    # A real fit: tilted normals on the flakes, F0 and roughness inside their ranges.
    assert 0 < np.mean(shared.normal[..., 2] < 0.999) < 1
    assert np.all((shared.specular >= 0) & (shared.specular <= 1)) and np.ptp(shared.roughness) > 0
