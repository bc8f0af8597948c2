"""Rectification accuracy on simulated captures with known homographies.

For frames of the simulated rig (``usdbtf rig-sim``'s renderer: a synthetic BTF sample in
the standard fiducial board, seen in perspective, with vignetting, sensor noise and 16-bit
sRGB quantisation, written to and read back from TIFF through OIIO), the script rectifies
every frame with :func:`usdbtf.rectify.rectify_frame` after flat-fielding it with a gain
map made from simulated flat-field frames (the same :func:`usdbtf.rig.capture.flat_gain`
capture uses), and measures

* **corner reprojection error**: |H_est(c) - H_true(c)| in frame pixels over every board
  corner c (the 256 marker corners and the 4 sample-window corners), H_true being the
  simulator's exact board -> frame homography; per frame the mean, then the mean/median/
  max over frames;
* **fit residual**: the mean distance of the inlier detected corners from H_est (what a
  real capture can measure without ground truth);
* **PSNR over the recorded texels** (the goal's measure since issue 28): the rectified N x N
  sample against the ground-truth texture (the BTF image the simulator put in the window),
  in linear Rec.709 with peak 1.0, ground truth clipped at 1, over the texels the sensor
  recorded: those with no clipped frame pixel (top code in the TIFF) within one pixel of their
  footprint under the simulator's exact homography (:func:`usdbtf.rectify.clipped_texels`).
  A clipped pixel holds the clip level, not the radiance it integrated; metal flakes sparkle
  at up to ~200 times the clip level, and a pixel that holds a sparkle and a dark neighbour
  reads 1 where the neighbour's truth is 0.05.  What such a texel was is not in the frame, so
  no rectifier can be asked for it; the rectifier flags these texels itself and reports their
  share per sample (``rectify.saturated``), and the benchmark checks that its flags cover every
  texel whose footprint holds a clipped pixel;
* **PSNR over the texels holding no clipped pixel**: the same with no reach around the clipped
  pixels, to show what the one-pixel reach (the pixels that undoing the sensor's box blur reads)
  adds;
* **PSNR over all texels** (the measure before issue 28's part 5, kept for comparison): the
  same against the clipped truth over every texel, clipped pixels included;
* **texels not recorded**: per frame the share of texels the benchmark leaves out, and the
  share of those the rectifier flagged (from its own homography);
* **time** per frame of the full rectify_frame (detection, refinement, RANSAC, warp).

Baselines measured in the same run on the same frames: (a) ArUco's own sub-pixel corners
without the edge-fit refinement, (b) bilinear resampling without the pixel pre-filter, (c) the
resampling before issue 28: bicubic without the pixel pre-filter (``warp_window(...,
interpolation="cubic", deblur=0)``).

Materials: the three the rectifier was developed on (pebbles, ridged_fabric, fuzzy_moss) and
the four held out from that work (crevice_stones, metal_flakes, velvet, satin_weave).

Frames are spread over the paper's capture plan (90 views x 120 lights, obstructed
samples excluded): every k-th sample of the shooting order, so all five view rings
(10..70 deg) appear.

    .venv/bin/python benchmarks/bench_rectify.py                 # 60 frames of 1600x1200, N = 128, 7 materials
    .venv/bin/python benchmarks/bench_rectify.py --frames 12 --materials pebbles   # a quick check

Before the frames it also prints what the capture order saves on the paper plan: arm
travel (great-circle degrees the LED sweeps) and head travel (sum of max(|d tilt|, |d pan|))
of ``--order travel`` against the sampling's own view-major order, same samples.

Targets: mean corner reprojection error <= 0.5 px and PSNR >= 30 dB at 128^2 (issue 4), >= 31 dB
over the recorded texels of every frame (issue 28), the rectifier flagging every texel that
holds a clipped pixel, every frame rectified.  The exit status is 1 when one fails.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np
from common import OUT, format_machine, machine_info, median, timestamp, write_json

from usdbtf import color, synth
from usdbtf.camera import Camera
from usdbtf.fiducials import apply_homography, detect_markers, fit_homography, make_board
from usdbtf.imageio import read_image
from usdbtf.rectify import (CLIP_REACH_PX, clipped_pixels, clipped_texels, luminance, rectify_frame, warp_window,
                            window_homography)
from usdbtf.rig.capture import decode_frame, flat_gain
from usdbtf.rig.plan import make_plan
from usdbtf.rig.scene import frame_homography
from usdbtf.rig.sim import CAMERA_SPACE, SceneRenderer
from usdbtf.sampling import preset

LIN709 = "Linear Rec.709 (sRGB)"


def psnr(a, b) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def board_points(board) -> np.ndarray:
    x0, y0, x1, y1 = board.sample_rect
    window = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float64)
    return np.concatenate([board.corners.reshape(-1, 2), window])


def corner_error(h_est, h_true, pts) -> float:
    return float(np.linalg.norm(apply_homography(h_est, pts) - apply_homography(h_true, pts), axis=1).mean())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60, help="frames per material (default 60)")
    ap.add_argument("--materials", default="pebbles,ridged_fabric,fuzzy_moss,crevice_stones,metal_flakes,velvet,"
                    "satin_weave")
    ap.add_argument("--size", type=int, default=128, help="rectified texels per side (default 128)")
    ap.add_argument("--frame-size", default="1600x1200", help="camera frame, WxH (default 1600x1200, the sim's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workdir", type=Path, default=OUT / "rectify", help="scratch frames go below this folder")
    args = ap.parse_args(argv)
    width, height = (int(v) for v in args.frame_size.split("x"))

    info = machine_info()
    print(format_machine(info))
    board = make_board()
    camera = Camera.framing(board, width, height)
    plan = make_plan(preset("paper"))
    picks = plan.order[np.linspace(0, len(plan.order) - 1, args.frames).round().astype(int)]
    to709 = color.processor(color.WORKING_SPACE, LIN709)
    pts = board_points(board)
    print("\n## inputs")
    print(f"- board: {len(board.ids)} ArUco markers ({board.dictionary}), {board.image_size[0]} px, "
          f"window {board.window_size_m[0] * 100:.2f} cm; camera {width}x{height}, f = {camera.focal_px:.0f} px, "
          f"vignetting a = {camera.vignetting}, read noise {camera.read_noise}, shot noise {camera.shot_noise}; "
          f"16-bit sRGB TIFF frames, 4 flat-field frames")
    print(f"- {args.frames} frames per material from the paper plan ({len(plan.order)} unobstructed samples), "
          f"view theta {sorted(set(plan.sampling.view[picks, 0].tolist()))}; rectified to {args.size}^2")

    naive = make_plan(preset("paper"), ordering="sampling")
    travel = {"arm_travel_deg": plan.arm_travel_deg(), "arm_travel_sampling_order_deg": naive.arm_travel_deg(),
              "head_travel_deg": plan.head_travel_deg(), "head_travel_sampling_order_deg": naive.head_travel_deg(),
              "obstructed": int(plan.obstructed.sum()), "samples": len(plan.sampling)}
    print(f"\n## capture plan (paper)\n- obstructed: {travel['obstructed']} of {travel['samples']} "
          f"({100 * travel['obstructed'] / travel['samples']:.1f}%)\n- arm travel: travel order "
          f"{travel['arm_travel_deg']:.0f} deg vs sampling order {travel['arm_travel_sampling_order_deg']:.0f} deg "
          f"(ratio {travel['arm_travel_deg'] / travel['arm_travel_sampling_order_deg']:.3f})\n- head travel: "
          f"{travel['head_travel_deg']:.0f} deg vs {travel['head_travel_sampling_order_deg']:.0f} deg (ratio "
          f"{travel['head_travel_deg'] / travel['head_travel_sampling_order_deg']:.3f})")

    rows, runs = [], []
    for name in args.materials.split(","):
        material = synth.make_material(name, args.size, args.seed)
        # Frames are ~11 MB each at 1600x1200: a scratch folder, removed after the material.
        args.workdir.mkdir(parents=True, exist_ok=True)
        scratch = tempfile.TemporaryDirectory(prefix=f"{name}-", dir=args.workdir)
        folder = Path(scratch.name)
        renderer = SceneRenderer(material, board, camera, folder, seed=args.seed)
        t0 = time.perf_counter()
        for k in range(4):
            renderer(f"flat{k:02d}", (0.0, 0.0), (0.0, 0.0), True)
        gain = flat_gain(decode_frame(read_image(folder / f"flat{k:02d}.tif")[0], CAMERA_SPACE) for k in range(4))
        for i in picks:
            renderer(f"s{i:05d}", tuple(plan.head[i]), tuple(plan.arm[i]), False)
        render_s = time.perf_counter() - t0
        frames = []
        for i in picks:
            pixels, finfo = read_image(folder / f"s{i:05d}.tif")
            view, light = plan.sampling.view[i], plan.sampling.light[i]
            truth = np.clip(synth.render_sample(material, view, light), 0.0, 1.0)
            linear = decode_frame(pixels, finfo.color_space) / gain[..., None]
            clipped = clipped_pixels(pixels)
            h_true = frame_homography(board, plan.head[i], camera)
            t = time.perf_counter()
            res = rectify_frame(linear, board, args.size, clipped=clipped)
            dt = time.perf_counter() - t
            rec = {"index": int(i), "view": view.tolist(), "light": light.tolist(), "seconds": dt,
                   "markers": res.markers, "rejected": res.reason}
            if res.image is not None:
                # The truth is known where the sensor recorded it: not within a pixel of a
                # clipped pixel, under the simulator's exact homography.
                h_tex_true = window_homography(h_true, board, args.size)
                lost, holding = (clipped_texels(clipped, h_tex_true, args.size, reach) for reach in (CLIP_REACH_PX, 0))
                keep = ~lost

                def recorded(image):
                    return psnr(image[keep], truth[keep]) if keep.any() else float("nan")

                image709 = to709.apply(res.image)
                rec.update(corner_px=corner_error(res.homography, h_true, pts), residual_px=res.residual_px,
                           psnr_db=recorded(image709), psnr_all_db=psnr(image709, truth),
                           psnr_reach0_db=(psnr(image709[~holding], truth[~holding]) if not holding.all()
                                           else float("nan")),
                           lost_pct=100.0 * float(lost.mean()), flagged_pct=100.0 * res.saturated_share,
                           lost_flagged_pct=100.0 * float(res.saturated[lost].mean()) if lost.any() else 100.0,
                           holding_flagged_pct=100.0 * float(res.saturated[holding].mean()) if holding.any() else 100.0)
                h_tex = window_homography(res.homography, board, args.size)
                rec["psnr_bilinear_db"] = recorded(to709.apply(warp_window(linear, h_tex, args.size,
                                                                           interpolation="linear", deblur=0)))
                bicubic = to709.apply(warp_window(linear, h_tex, args.size, interpolation="cubic", deblur=0))
                rec["psnr_bicubic_db"] = recorded(bicubic)
                rec["psnr_all_bicubic_db"] = psnr(bicubic, truth)
                det = detect_markers(luminance(linear), board, refine=False)
                h_raw, inl, resid = fit_homography(board, det)
                if h_raw is not None:
                    rec["corner_px_aruco"] = corner_error(h_raw, h_true, pts)
                    rec["residual_px_aruco"] = float(resid[inl].mean())
                    rec["psnr_aruco_db"] = recorded(to709.apply(
                        warp_window(linear, window_homography(h_raw, board, args.size), args.size)))
            frames.append(rec)
        scratch.cleanup()
        ok = [f for f in frames if not f["rejected"]]
        run = {"material": name, "render_s": render_s, "frames": frames}
        runs.append(run)

        def stat(key, fn):
            vals = [f[key] for f in ok if key in f and not np.isnan(f[key])]   # nan: no texel recorded
            return fn(vals) if vals else float("nan")

        row = {"material": name, "frames": len(frames), "rectified": len(ok),
               "corner_mean": stat("corner_px", np.mean), "corner_median": stat("corner_px", median),
               "corner_max": stat("corner_px", max), "residual_mean": stat("residual_px", np.mean),
               "psnr_min": stat("psnr_db", min), "psnr_median": stat("psnr_db", median),
               "psnr_mean": stat("psnr_db", np.mean),
               "aruco_corner_mean": stat("corner_px_aruco", np.mean),
               "aruco_residual_mean": stat("residual_px_aruco", np.mean),
               "aruco_psnr_median": stat("psnr_aruco_db", median), "bilinear_psnr_median": stat("psnr_bilinear_db", median),
               "bilinear_psnr_min": stat("psnr_bilinear_db", min), "psnr_max": stat("psnr_db", max),
               "bicubic_psnr_min": stat("psnr_bicubic_db", min), "bicubic_psnr_median": stat("psnr_bicubic_db", median),
               "bicubic_psnr_max": stat("psnr_bicubic_db", max),
               "all_psnr_min": stat("psnr_all_db", min), "all_psnr_median": stat("psnr_all_db", median),
               "all_psnr_max": stat("psnr_all_db", max), "all_bicubic_psnr_min": stat("psnr_all_bicubic_db", min),
               "lost_median": stat("lost_pct", median), "lost_max": stat("lost_pct", max),
               "lost_flagged_min": stat("lost_flagged_pct", min), "flagged_max": stat("flagged_pct", max),
               "holding_flagged_min": stat("holding_flagged_pct", min),
               "reach0_psnr_min": stat("psnr_reach0_db", min), "reach0_psnr_median": stat("psnr_reach0_db", median),
               "seconds_median": stat("seconds", median)}
        by_ring = {}
        for f in ok:
            by_ring.setdefault(f["view"][0], []).append(f["psnr_db"])
        row["psnr_min_by_view_theta"] = {str(k): round(float(min(v)), 2) for k, v in sorted(by_ring.items())}
        rows.append(row)
        print(f"\n## {name}  (frames rendered in {render_s:.1f} s)")
        for f in frames:
            if f["rejected"]:
                print(f"  #{f['index']:5d} view {f['view']} light {f['light']}: REJECTED {f['rejected']}")
            else:
                print(f"  #{f['index']:5d} view {f['view']} light {f['light']}: {f['markers']} markers, corner err "
                      f"{f['corner_px']:.3f} px (ArUco only {f.get('corner_px_aruco', float('nan')):.3f}), residual "
                      f"{f['residual_px']:.3f} px, PSNR {f['psnr_db']:.2f} dB on the {100 - f['lost_pct']:.1f}% "
                      f"recorded texels (bicubic {f['psnr_bicubic_db']:.2f}; all texels {f['psnr_all_db']:.2f} / "
                      f"bicubic {f['psnr_all_bicubic_db']:.2f}; rectifier flagged {f['flagged_pct']:.1f}%, "
                      f"{f['lost_flagged_pct']:.1f}% of the unrecorded, {f['holding_flagged_pct']:.1f}% of those "
                      f"holding a "
                      f"clipped pixel), bilinear {f['psnr_bilinear_db']:.2f}, "
                      f"ArUco corners {f.get('psnr_aruco_db', float('nan')):.2f}), {f['seconds'] * 1000:.0f} ms")
        print(f"  PSNR minimum per view theta: {row['psnr_min_by_view_theta']}")

    print("\n## results (markdown)\n")
    print("| material | frames rectified | corner error mean / median / max (px) | fit residual (px) | "
          "PSNR over recorded texels min / median / max (dB) | texels not recorded: median / max (%); "
          "of those, flagged by the rectifier; of those holding a clipped pixel, flagged (worst frame) | "
          "PSNR over the texels holding no clipped pixel (no reach) min / median (dB) | "
          "PSNR over all texels (old measure) min / median / max (dB) | "
          "before issue 28 (bicubic, no pre-filter): recorded min / median / max, all min (dB) | "
          "baseline ArUco corners: corner error (px) / residual (px) / PSNR median (dB) | "
          "baseline bilinear: PSNR min / median (dB) | time per frame (median) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['material']} | {r['rectified']}/{r['frames']} | {r['corner_mean']:.3f} / {r['corner_median']:.3f} / "
              f"{r['corner_max']:.3f} | {r['residual_mean']:.3f} | {r['psnr_min']:.2f} / {r['psnr_median']:.2f} / "
              f"{r['psnr_max']:.2f} | {r['lost_median']:.1f} / {r['lost_max']:.1f}; {r['lost_flagged_min']:.1f}%; "
              f"{r['holding_flagged_min']:.1f}% | {r['reach0_psnr_min']:.2f} / {r['reach0_psnr_median']:.2f} | "
              f"{r['all_psnr_min']:.2f} / {r['all_psnr_median']:.2f} / {r['all_psnr_max']:.2f} | "
              f"{r['bicubic_psnr_min']:.2f} / {r['bicubic_psnr_median']:.2f} / {r['bicubic_psnr_max']:.2f}, "
              f"{r['all_bicubic_psnr_min']:.2f} | "
              f"{r['aruco_corner_mean']:.3f} / {r['aruco_residual_mean']:.3f} / {r['aruco_psnr_median']:.2f} | "
              f"{r['bilinear_psnr_min']:.2f} / {r['bilinear_psnr_median']:.2f} | {r['seconds_median'] * 1000:.0f} ms |")

    thetas = sorted({t for r in rows for t in r["psnr_min_by_view_theta"]}, key=float)
    print("\nMinimum PSNR over recorded texels per view theta (dB):\n")
    print("| material | " + " | ".join(f"{float(t):g}°" for t in thetas) + " |")
    print("|---|" + "---|" * len(thetas))
    for r in rows:
        print(f"| {r['material']} | " + " | ".join(f"{r['psnr_min_by_view_theta'].get(t, float('nan')):.2f}"
                                                 for t in thetas) + " |")

    def over_all(key):
        vals = [f[key] for run in runs for f in run["frames"] if key in f and not np.isnan(f[key])]
        return min(vals), median(vals), max(vals), len(vals)

    lo, mid, hi, count = over_all("psnr_db")
    print(f"\nall {count} frames, recorded texels: PSNR min / median / max {lo:.2f} / {mid:.2f} / {hi:.2f} dB; "
          "before issue 28 (bicubic, no pre-filter) {:.2f} / {:.2f} / {:.2f} dB".format(
              *over_all("psnr_bicubic_db")[:3]))
    print("all texels (old measure): {:.2f} / {:.2f} / {:.2f} dB; before issue 28 {:.2f} / {:.2f} / {:.2f} dB".format(
        *over_all("psnr_all_db")[:3], *over_all("psnr_all_bicubic_db")[:3]))
    print("texels not recorded per frame: min / median / max {:.1f} / {:.1f} / {:.1f} %".format(
        *over_all("lost_pct")[:3]))
    worst_corner = max(r["corner_mean"] for r in rows)
    worst_psnr, worst_flags = lo, over_all("holding_flagged_pct")[0]
    all_ok = all(r["rectified"] == r["frames"] for r in rows)
    goals = {"mean corner reprojection error <= 0.5 px": (f"{worst_corner:.3f} px", worst_corner <= 0.5),
             f"PSNR over recorded texels >= 30 dB at {args.size}^2 (issue 4)":
                 (f"{worst_psnr:.2f} dB", worst_psnr >= 30),
             "... >= 31 dB on every frame (issue 28)": (f"{worst_psnr:.2f} dB", worst_psnr >= 31),
             "the rectifier flags every texel that holds a clipped pixel":
                 (f"{worst_flags:.1f}%", worst_flags >= 100.0),
             "every frame rectified": ("yes" if all_ok else "NO", all_ok)}
    print("\ntargets: " + "; ".join(f"{k}: {v} {'PASS' if ok else 'FAIL'}" for k, (v, ok) in goals.items()))
    verdict = all(ok for _, ok in goals.values())
    out = write_json(OUT / f"rectify_{timestamp()}.json", {"machine": info, "args": vars(args) | {"workdir": str(args.workdir)},
                                                          "plan": travel, "rows": rows, "runs": runs})
    print(f"details: {out}")
    return 0 if verdict else 1


if __name__ == "__main__":
    sys.exit(main())
