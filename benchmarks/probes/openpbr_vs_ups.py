#!/usr/bin/env python
"""Issue 40 probe: OpenPBR fit vs UsdPreviewSurface fit against the compressed BTF's reconstruction
(linear, % of the paper's metric over every measured sample), both without their brightness step,
per-texel counts of where OpenPBR is worse.  Tuning presets only.

The OpenPBR fit's CPU time (median of --repeats) and peak traced memory (tracemalloc, one more
fit).  Before/after in one session: run it twice, once with ``PYTHONPATH=<base tree>/pipeline``.

Usage: .venv/bin/python benchmarks/probes/openpbr_vs_ups.py --presets satin_weave,metal_flakes --size 32
"""
from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import usdbtf  # noqa: F401,E402
import numpy as np  # noqa: E402
from common import OUT, cli_command, format_machine, machine_info  # noqa: E402


def per_texel_l1(cbtf, evaluate, maps, chunk=256):
    from usdbtf.compress.format import reconstruct, working_coefficients
    coeff = working_coefficients(cbtf)
    err = np.zeros(cbtf.width * cbtf.height)
    tot = np.zeros_like(err)
    enc = np.zeros(2)
    for a in range(0, cbtf.n_samples, chunk):
        idx = np.arange(a, min(a + chunk, cbtf.n_samples))
        recon = reconstruct(cbtf, idx, coefficients=coeff).reshape(len(idx), -1, 3)
        pred = evaluate(maps, cbtf.sampling.view[idx], cbtf.sampling.light[idx]).reshape(len(idx), -1, 3)
        err += np.abs(recon - pred).sum(axis=(0, 2))
        tot += recon.sum(axis=(0, 2))
        srgb = lambda x: np.round(255 * np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.abs(x) ** (1 / 2.4) - 0.055).clip(0, 1))  # noqa: E731
        er = srgb(np.clip(recon, 0, 1))
        enc += (np.abs(er - srgb(np.clip(pred, 0, 1))).sum(), er.sum())
    per_texel_l1.encoded = 100 * enc[0] / enc[1]
    return err, tot


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--presets", default="satin_weave,metal_flakes,fuzzy_moss,pebbles")
    ap.add_argument("--size", type=int, default=16)
    ap.add_argument("--sampling", default="paper")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--kw", default="{}", help="fit_openpbr keyword arguments (JSON)")
    a = ap.parse_args()
    import json
    kw = json.loads(a.kw)
    from usdbtf import openpbr, svbrdf
    from usdbtf.bench.datasets import compressed, ensure_dataset, preset_split
    print(format_machine(machine_info()))
    print(f"- command: {' '.join(sys.argv)}")
    for preset in a.presets.split(","):
        assert preset_split(preset) == "tuning", preset
        data = ensure_dataset(OUT / "data", preset, a.sampling, a.size, 0, say=lambda m: None)
        folder = OUT / "fallback" / f"{preset}-{a.sampling}-{a.size}-seed0-k64"
        cbtf = compressed(cli_command(), Path(data["folder"]), folder, 64)
        ups = svbrdf.fit_svbrdf(cbtf, brightness=False)
        cpu = []
        for _ in range(a.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            op = openpbr.fit_openpbr(cbtf, svbrdf=ups, brightness=False, **kw)
            t1, c1 = time.perf_counter(), time.process_time()
            cpu.append(c1 - c0)
        tracemalloc.start()
        openpbr.fit_openpbr(cbtf, svbrdf=ups, brightness=False, **kw)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        print(f"  OpenPBR fit CPU seconds (median of {a.repeats}) {np.median(cpu):.2f}, peak traced memory "
              f"{peak / 2**20:.1f} MiB")
        eu, tot = per_texel_l1(cbtf, svbrdf.evaluate, ups)
        eu_enc = per_texel_l1.encoded
        eo, _ = per_texel_l1(cbtf, openpbr.evaluate, op)
        eo_enc = per_texel_l1.encoded
        from usdbtf.usd.asset import openpbr as usd_openpbr
        shipped = usd_openpbr.decode_maps(usd_openpbr.encode_maps(op, cbtf.ocio_config), cbtf.working_space,
                                          ocio_config=cbtf.ocio_config)
        es, _ = per_texel_l1(cbtf, openpbr.evaluate, shipped)
        print(f"  encoded (sRGB 8-bit of both): UPS {eu_enc:.2f} %  OpenPBR {eo_enc:.2f} %  ratio {eo_enc / eu_enc:.3f}; "
              f"OpenPBR as shipped (8-bit maps) lin {100 * es.sum() / tot.sum():.2f} % enc {per_texel_l1.encoded:.2f} %")
        worse = np.mean(eo > eu * 1.001)
        print(f"{preset}: UPS {100 * eu.sum() / tot.sum():.2f} %  OpenPBR {100 * eo.sum() / tot.sum():.2f} %  "
              f"ratio {eo.sum() / eu.sum():.3f}  texels worse {100 * worse:.0f} %  "
              f"aniso>0 {100 * np.mean(op.specular_anisotropy > 0):.0f} %  fuzz>0 {100 * np.mean(op.fuzz_weight > 0):.0f} %  "
              f"sigma>0 {100 * np.mean(op.base_diffuse_roughness > 0):.0f} %  ",
              flush=True)


if __name__ == "__main__":
    main()
