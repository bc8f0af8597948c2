"""Where the rectification error of clipping materials lives (issue 28): an analysis, not a goal.

For frames of the rectification benchmark (the same materials, plan picks, camera, seeds and
sensor noise as ``bench_rectify.py``, rendered in memory without the TIFF round trip), each
rectified with the simulator's exact homography, it prints per frame

* the texture's peak radiance, in units of the sensor's clip level (1);
* the share of the window's texels that are *not recorded*: within one pixel of a clipped
  sensor pixel (:func:`usdbtf.rectify.clipped_texels`);
* the PSNR over all texels against the truth clipped at 1 (the old measure), and the share
  of its squared error that sits on the texels not recorded;
* the PSNR over the recorded texels (the benchmark's measure since issue 28);
* the PSNR over all texels if the sensor did not clip (same noise, values above 1 kept), the
  rectified texels clipped at 1 like the truth: what a rectifier would get from an HDR merge.

    .venv/bin/python benchmarks/probes/rectify_clipping.py                      # metal_flakes, satin_weave, 60 frames
    .venv/bin/python benchmarks/probes/rectify_clipping.py --materials metal_flakes --frames 12
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py and the benchmarks a probe reuses

import argparse
import sys
import tempfile
import zlib

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np
from bench_rectify import LIN709, psnr
from common import format_machine, machine_info, median

from usdbtf import color, synth
from usdbtf.camera import Camera
from usdbtf.fiducials import make_board
from usdbtf.rectify import clipped_texels, warp_window, window_homography
from usdbtf.rig.plan import make_plan
from usdbtf.rig.scene import add_sensor_noise, frame_homography, vignetting
from usdbtf.rig.sim import SceneRenderer
from usdbtf.sampling import preset


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60, help="frames per material (default 60, the benchmark's)")
    ap.add_argument("--materials", default="metal_flakes,satin_weave")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    print(format_machine(machine_info()))
    print(f"\ncommand: benchmarks/probes/rectify_clipping.py {' '.join(sys.argv[1:] if argv is None else argv)}")
    board = make_board()
    camera = Camera.framing(board, 1600, 1200)
    plan = make_plan(preset("paper"))
    picks = plan.order[np.linspace(0, len(plan.order) - 1, args.frames).round().astype(int)]
    to_working = color.processor(LIN709, color.WORKING_SPACE)
    to709 = color.processor(color.WORKING_SPACE, LIN709)
    vignette = vignetting(camera)[..., None]
    size = 128
    for name in args.materials.split(","):
        material = synth.make_material(name, size, args.seed)
        # The renderer's radiance only (no frames are written): its folder is a scratch one.
        scratch = tempfile.TemporaryDirectory(prefix="rectify-clipping-")
        renderer = SceneRenderer(material, board, camera, scratch.name, seed=args.seed)
        rows = []
        print(f"\n## {name}\n")
        print("| plan sample | view | light | peak radiance (× clip) | not recorded | PSNR all texels | "
              "error share on not recorded | PSNR recorded | PSNR all texels, sensor that does not clip |")
        print("|---|---|---|---|---|---|---|---|---|")
        for i in picks:
            view, light = plan.sampling.view[i], plan.sampling.light[i]
            texture = synth.render_sample(material, view, light)
            truth = np.clip(texture, 0.0, 1.0)
            signal = renderer.radiance(tuple(plan.head[i]), tuple(plan.arm[i]), False) * vignette
            h_tex = window_homography(frame_homography(board, plan.head[i], camera), board, size)
            result = {}
            for clip in (True, False):
                # The renderer's noise stream for this frame's tag, so both sensors see the same noise.
                rng = np.random.default_rng([args.seed, zlib.crc32(f"s{i:05d}".encode())])
                frame = add_sensor_noise(signal, camera, rng, clip=clip)
                rectified = to709.apply(warp_window(to_working.apply(frame / vignette), h_tex, size))
                result[clip] = (frame, rectified)
            frame, rectified = result[True]
            lost = clipped_texels(frame.max(axis=2) >= 1.0, h_tex, size)
            err = ((rectified.astype(np.float64) - truth) ** 2).sum(axis=2)
            row = {"peak": float(texture.max()), "lost": 100 * float(lost.mean()), "all": psnr(rectified, truth),
                   "share": float(err[lost].sum() / err.sum()) if err.sum() > 0 else 0.0,
                   "recorded": psnr(rectified[~lost], truth[~lost]) if not lost.all() else float("nan"),
                   "unclipped": psnr(np.clip(result[False][1], 0.0, 1.0), truth)}
            rows.append(row)
            print(f"| {i} | {view.tolist()} | {light.tolist()} | {row['peak']:.2f} | {row['lost']:.1f} % | "
                  f"{row['all']:.2f} | {100 * row['share']:.0f} % | {row['recorded']:.2f} | {row['unclipped']:.2f} |",
                  flush=True)
        scratch.cleanup()
        print_summary(name, rows)
    return 0


def print_summary(name: str, rows: list) -> None:
    """One material's minima, peak radiance and where its worst frames' error sits."""
    clipping = [r for r in rows if r["lost"] > 0]
    print(f"\n{name}: PSNR all texels min {min(r['all'] for r in rows):.2f} dB, recorded min "
          f"{np.nanmin([r['recorded'] for r in rows]):.2f} dB, sensor that does not clip min "
          f"{min(r['unclipped'] for r in rows):.2f} dB; peak radiance max {max(r['peak'] for r in rows):.1f}x "
          f"the clip level; {len(clipping)} of {len(rows)} frames clip under the window")
    if clipping:
        worst = sorted(clipping, key=lambda r: r["all"])[:10]
        print(f"the 10 worst frames over all texels: error share on texels not recorded min / median / max "
              f"{100 * min(r['share'] for r in worst):.0f} / {100 * median([r['share'] for r in worst]):.0f} / "
              f"{100 * max(r['share'] for r in worst):.0f} %")


if __name__ == "__main__":
    sys.exit(main())
