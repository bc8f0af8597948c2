#!/usr/bin/env python
"""Issue 43's real-time check on any packaged asset: real Storm (USD 25.02 and 25.08, the
``.venv-storm-*`` environments) draws the asset's 5 cm swatch seen from the pole (a pinhole
camera 1 m above it, a 3.4 degree field of view: nearly orthographic, about one pixel a texel at
128²) under one ``UsdLux.DistantLight`` from each of ``--lights`` measured light directions
(theta 15..65 degrees, at the capture light's irradiance pi W), and ``usdbtf render`` (the
shader's CPU twin: the same interpolation of measured directions, the same photometric
convention) draws the same stage.  No gain between them: mean |difference| in 8-bit sRGB steps
and PSNR (sRGB) where both have full coverage (as tests/test_storm.py compares them on a curved
mesh: PSNR >= 35 dB).  The test suite checks assets it makes small; this one the assets a
benchmark packaged at paper scale (e.g. ``bench_issue16.py``'s at the paper's bytes), whose
sampling need not have a pole view.

Usage (repository root)::

    .venv/bin/python benchmarks/probes/storm_swatch_check.py ASSET.usda [ASSET.usda ...] [--lights 3]
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform; registers the schema)
import numpy as np  # noqa: E402

from common import print_header, print_table  # noqa: E402

SIZE = 160          # pixels a side
DISTANCE_M = 1.0    # camera above the swatch
FOV_DEG = 2.0 * math.degrees(math.atan(0.03 / DISTANCE_M))     # 6 cm across: the 5 cm swatch and a margin


def measured_lights(cbtf, count: int) -> list[tuple[float, float]]:
    """``count`` measured light directions (theta, phi degrees), theta 15..65, spread over the list."""
    lights = np.unique(np.asarray(cbtf.sampling.light, np.float64), axis=0)
    cand = [light for light in lights if 15.0 <= light[0] <= 65.0]
    return [tuple(float(a) for a in cand[i]) for i in np.linspace(0, len(cand) - 1, count).round().astype(int)]


def cpu_frame(scene: Path, camera: str) -> np.ndarray:
    """(H, W, 4) float64 ``usdbtf render SCENE --camera CAMERA`` (no shadows, bilinear), as the
    suite's Storm tests render it (tests/storm_helpers.against_cpu_render)."""
    from usdbtf.cli import main as cli
    from usdbtf.usd.asset.storm import read_rgba

    out = scene.with_name(scene.stem + "_cpu.exr")
    if cli(["render", str(scene), "--camera", camera, "--size", str(SIZE), str(SIZE), "--no-shadows",
            "--filter", "bilinear", "-o", str(out), "--no-png", "-q"]) != 0:
        raise SystemExit(f"usdbtf render failed on {scene}")
    return np.asarray(read_rgba(out), np.float64)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("assets", nargs="+", type=Path)
    ap.add_argument("--lights", type=int, default=3)
    args = ap.parse_args(argv)

    from usdbtf.camera import Camera
    from usdbtf.gpu.headless import psnr
    from usdbtf.photometry import capture_irradiance, white_level_of
    from usdbtf.render.output import srgb_encoded
    from usdbtf.render.scene import Light
    from usdbtf.usd.asset.storm import to_rendering_space
    from usdbtf.usd.preview import hydra
    from usdbtf.usd.read import load_btf
    from usdbtf.usd.scenes.scene import write_scene

    print_header("# Storm swatch check: Storm against usdbtf render of the same stage, pole camera, no gain")
    pythons = hydra.storm_pythons()
    if not pythons:
        print("no Storm environment (scripts/bootstrap.sh installs them)")
        return 1
    camera = Camera(np.array([0.0, 0.0, DISTANCE_M]), np.zeros(3), np.array([0.0, 1.0, 0.0]), FOV_DEG, SIZE, SIZE)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n, asset in enumerate(args.assets):
            cbtf = load_btf(asset)
            irradiance = capture_irradiance(white_level_of(cbtf.info))
            frames, scenes, cpu = [], [], []
            for i, (theta, phi) in enumerate(measured_lights(cbtf, args.lights)):
                t, f = math.radians(theta), math.radians(phi)
                light = Light("directional", np.array([math.sin(t) * math.cos(f), math.sin(t) * math.sin(f),
                                                       math.cos(t)]), irradiance)
                scene = Path(tmp) / f"a{n}_l{i}.usda"
                prim = write_scene(asset, scene, camera, [light])
                frames.append((scene, scene.with_suffix(".exr")))
                scenes.append(scene)
                cpu.append(cpu_frame(scene, prim))
            for version, python in sorted(pythons.items()):
                t0 = time.perf_counter()
                result = hydra.render_frames(python, frames, prim, (SIZE, SIZE))
                seconds = time.perf_counter() - t0
                steps, psnrs, covered, means, controls = [], [], [], [], []
                for image, scene, ref in zip(result.images, scenes, cpu):
                    storm = to_rendering_space(scene, image, back=True).astype(np.float64)
                    both = (storm[..., 3] > 0.999) & (ref[..., 3] > 0.999)
                    a, b = srgb_encoded(storm[..., :3]), srgb_encoded(ref[..., :3])
                    steps.append(float(np.abs(a - b)[both].mean() * 255.0))
                    psnrs.append(psnr(a, b, both))
                    covered.append(int(both.sum()))
                    means.append(float(b[both].mean() * 255.0))
                    # the control: the CPU frame at half the exposure must not agree
                    controls.append(float(np.abs(a - srgb_encoded(ref[..., :3] * 0.5))[both].mean() * 255.0))
                row = (f"| {asset} | {cbtf.k} | USD {version} | {min(means):.1f}-{max(means):.1f} | {max(steps):.3f} | "
                       f"{min(psnrs):.2f} | {min(controls):.1f} | {min(covered)} | {len(result.problems)} | {seconds:.0f} |")
                print(row, flush=True)
                rows.append(row)
    print_table(["asset", "k", "Storm", "mean sRGB value (8-bit)", "max mean abs diff (8-bit steps)", "min PSNR dB",
                 "control: against half exposure, min mean abs diff", "pixels compared", "problems", "Storm s"], rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
