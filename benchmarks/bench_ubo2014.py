"""How long expanding a UBO2014-sized DFMF file's images takes (issue 18).

A synthetic file of UBO2014's shape -- 151 views x 151 lights = 22,801 samples, 400 x 400
texels, colour model 11, half-float factors with k = 150 / 50 / 50 components (Y, U/Y, V/Y)
-- is written with the test writer (tests/bonn_btf_writer.py, not usdbtf), then opened with
:func:`usdbtf.ubo2014.read_ubo2014` and expanded in compress's access pattern (chunks of
256 whole samples, ``read_encoded``: the product, the colour model, the clamp).

Printed, all measured in this run:
* open: header, direction table and the NaN scan of every factor;
* one sample; one 256-sample chunk; ``--chunks`` chunks -> seconds per image and the
  projected time for all 22,801 images (a full pass is ~89 chunks: not run by default);
* baselines: reading 64 pre-expanded 400 x 400 half-float EXR images through OpenImageIO
  (what a UBO2003-style input costs per image), and the float32 GEMM of one chunk's
  Y channel alone (the floor of the product).

Run: ``.venv/bin/python benchmarks/bench_ubo2014.py [--chunks 4] [--k 150 50 50]``
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import REPO, format_machine, machine_info, median, time_call

sys.path.insert(0, str(REPO / "tests"))
import bonn_btf_writer as writer  # noqa: E402

N_VIEWS = N_LIGHTS = 151
SIZE = 400
CHUNK = 256


def synthetic_dfmf(path: Path, ks, seed: int = 0, *, model: int = 11, offsets=(-2.0, 0.0, 0.0)) -> Path:
    """Random factors with UBO2014's shapes; channel values stay in a plausible range
    (by default colour model 11 with log Y around -2, chroma ratios around 0, so the colour
    model does real work; ``offsets`` are the channels' means)."""
    rng = np.random.default_rng(seed)
    S, T = N_VIEWS * N_LIGHTS, SIZE * SIZE
    theta = np.radians(np.linspace(0, 75, N_VIEWS))
    dirs = np.stack([theta, np.radians(np.arange(N_VIEWS) * 137.5 % 360)], axis=1)
    chans = []
    for c, k in enumerate(ks):
        u = (rng.standard_normal((S, k)) / np.sqrt(k)).astype(np.float32)
        sxv = (0.3 * rng.standard_normal((T, k)) * (0.9 ** np.arange(k))).astype(np.float32)
        u[:, 0], sxv[:, 0] = 1.0, offsets[c]
        chans.append((np.ones(k), u, sxv))
    return writer.dfmf_file(path, chans, views_rad=dirs, lights_rad=dirs, width=SIZE, height=SIZE, model=model)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--chunks", type=int, default=4, help="256-sample chunks to expand (default 4)")
    ap.add_argument("--k", type=int, nargs=3, default=[150, 50, 50], help="components per channel")
    args = ap.parse_args()

    from usdbtf.imageio import read_image, write_image
    from usdbtf.ubo2014 import read_ubo2014

    print("machine (shared with other sessions: read medians and ratios):")
    print(format_machine(machine_info()))
    with tempfile.TemporaryDirectory(prefix="bench-ubo2014-") as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        path = synthetic_dfmf(tmp / "synthetic.btf", args.k)
        print(f"\ninput: {path.stat().st_size / 1e6:.1f} MB DFMF, {N_VIEWS} x {N_LIGHTS} samples, {SIZE}^2, "
              f"k = {args.k} (written in {time.perf_counter() - t:.1f} s)")

        opened = time_call(lambda: read_ubo2014(path), repeats=3, warmup=0)
        btf = read_ubo2014(path)
        one = time_call(lambda: btf.read_encoded([1234]), repeats=5)
        chunk_times = []
        for j in range(args.chunks):
            a = j * CHUNK * 20 % btf.n_samples
            t = time.perf_counter()
            block = btf.read_encoded(slice(a, a + CHUNK))
            chunk_times.append(time.perf_counter() - t)
        assert np.isfinite(block).all()
        per_image = median(chunk_times) / CHUNK
        print(f"open (header + NaN scan of the factors): median {opened['median_s']:.2f} s")
        print(f"one sample:                              median {one['median_s'] * 1e3:.1f} ms")
        print(f"256-sample chunks ({args.chunks}):                  median {median(chunk_times):.2f} s "
              f"= {per_image * 1e3:.2f} ms/image; all {btf.n_samples} images projected "
              f"{per_image * btf.n_samples / 60:.1f} min")

        # Baselines in the same run.
        f = btf.factors
        a32, b32 = f.float32(0, "samples")[:CHUNK], f.float32(0, "texels")
        gemm = time_call(lambda: a32 @ b32.T, repeats=3)
        imgs = tmp / "exr"
        imgs.mkdir()
        for i in range(64):
            write_image(imgs / f"{i:03d}.exr", block[i].astype(np.float16), color_space="Linear Rec.709 (sRGB)",
                        attributes={"compression": "zip"})
        files = sorted(imgs.iterdir())
        exr = time_call(lambda: [read_image(p) for p in files], repeats=3)
        print(f"baseline: float32 GEMM of one chunk's Y channel ({CHUNK} x {args.k[0]} x {SIZE * SIZE}): "
              f"median {gemm['median_s']:.2f} s = {gemm['median_s'] / CHUNK * 1e3:.2f} ms/image")
        print(f"baseline: OIIO read of 64 pre-expanded half EXR (zip) images: median {exr['median_s']:.2f} s "
              f"= {exr['median_s'] / 64 * 1e3:.2f} ms/image")
        print(f"ratio expand / EXR read: {per_image / (exr['median_s'] / 64):.2f}; "
              f"expand / Y-channel GEMM: {per_image / (gemm['median_s'] / CHUNK):.2f}")


if __name__ == "__main__":
    main()
