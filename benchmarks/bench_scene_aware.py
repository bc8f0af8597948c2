#!/usr/bin/env python
"""Builds shaped by the scene (issue 26): ``usdbtf build --full`` against the scene-shaped
``usdbtf build`` of one scene, in one run.

The scene (:mod:`usdbtf.bench.scenes`): a camera dollying sideways over ``--frames`` frames
past a 5 cm floor quad (material Near, close up: about a pixel per texel), a 3 cm tile 1.6 m
away (material Far: a few pixels on screen), a quad behind the camera (material Hidden: never
in any frustum), and one distant light.  Three synthetic materials (``--sampling``,
``--size`` texels, recipe ``--k``, ``--codec png --domain srgb``; ``--domain auto`` for the
recipes' automatic choice, which the shaped build takes from the full input, issue 41).

Measures:

build       wall time and bytes written (compressed folders, assets, the bound meshes'
            unwrap/quilt/package chains) of the full build and of the shaped build, each from
            scratch in its own folder; the plan's per-material needs.
frames      every frame of the scene's camera rendered (``usdbtf render SCENE --camera
            /World/Cam --frames``) from both builds; PSNR in sRGB (the display encoding of the
            linear frame, clipped to [0, 1]) over the pixels where either frame has geometry.
cameras     a second camera added (a grazing view of the floor): the next shaped build, the
            steps it ran and its time; then the same scene again: the steps (none) and time.

The recipe's k is the sampling's sample count by default (169 for ``small``): the full build
is then exact up to its 8-bit codes, so the frame comparison measures what the shaped build
leaves out, not the full build's own compression error (at k = 24 on ``ubo81`` that error
alone is 26 dB: see docs/scenes-and-build.md).

Usage (repository root)::

    .venv/bin/python benchmarks/bench_scene_aware.py                 # ~6 min on 2 loaded cores
    .venv/bin/python benchmarks/bench_scene_aware.py --figure docs/scene_aware.png

Writes benchmarks/out/scene_aware_<timestamp>.json and prints a markdown block for RESULTS.md.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "pipeline"))
import usdbtf  # noqa: E402,F401  (pins the numeric platform before numpy's BLAS loads)
from common import OUT, cli_command, format_machine, machine_info, run_measured, timestamp, write_json  # noqa: E402
from usdbtf.render.output import srgb_encoded  # noqa: E402

MATERIALS = {"Near": "pebbles", "Far": "ridged_fabric", "Hidden": "fuzzy_moss"}
LIGHT = (0.3, 0.5, 1.0)


def scene(folder: Path, captures: Path, frames: int, *, second_camera: bool, k: int, resolution,
          domain: str = "srgb") -> Path:
    """Write ``folder/scene.usda`` (module docstring)."""
    from usdbtf.bench.scenes import Quad, Shot, write_scene

    quads = [Quad("Floor", "Near", 0.05, (0, 0, 0)), Quad("Tile", "Far", 0.03, (0.0, 0.45, -1.5)),
             Quad("Ghost", "Hidden", 0.05, (0.0, 0.0, 0.4))]          # behind the camera
    eyes = [(-0.04 + 0.08 * i / max(frames - 1, 1), 0.0, 0.1) for i in range(frames)]
    shots = [Shot("Cam", eyes, [(0, 0, 0)], fov=40)]
    if second_camera:
        shots.append(Shot("Side", [(0.1, 0.0, 0.035)], [(0, 0, 0)], fov=40))
    path = folder / "scene.usda"
    path.unlink(missing_ok=True)
    mats = {name: captures / preset for name, preset in MATERIALS.items()}
    return write_scene(path, mats, quads, shots, light_towards=LIGHT, frames=(1, frames), resolution=resolution,
                       options=f"--k {k} --codec png --domain {domain}")


def built_bytes(folder: Path) -> int:
    """Bytes a build wrote: the assets' folder and the bound meshes' chains and coverage files."""
    roots = [folder / "build", folder / ".usdbtf-build" / "scene" / "bindings",
             folder / ".usdbtf-build" / "scene" / "materials"]
    return sum(f.stat().st_size for r in roots if r.exists() for f in r.rglob("*") if f.is_file())


def usdbtf(*args, cwd: Path):
    res = run_measured(cli_command() + list(args), cwd=cwd)
    if res.returncode:
        raise SystemExit(f"usdbtf {' '.join(args)} failed:\n{res.stderr[-2000:]}")
    return res


def rgba(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    return np.asarray(oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT))


def psnr(a: np.ndarray, b: np.ndarray) -> tuple[float, int]:
    """(PSNR dB in sRGB over pixels with geometry in either frame, those pixels)."""
    mask = (a[..., 3] > 0) | (b[..., 3] > 0)
    d = srgb_encoded(a[..., :3])[mask] - srgb_encoded(b[..., :3])[mask]
    mse = float(np.mean(d * d)) if mask.any() else 0.0
    return (float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)), int(mask.sum())


def figure(path: Path, full: Path, shaped: Path, frames: list[int]) -> None:
    """Rows of frames: the full build's, the shaped build's, |difference| x 20 (sRGB)."""
    import OpenImageIO as oiio

    rows = []
    for f in frames:
        a, b = rgba(full / f"f.{f:04d}.exr"), rgba(shaped / f"f.{f:04d}.exr")
        sa, sb = srgb_encoded(a[..., :3]), srgb_encoded(b[..., :3])
        rows.append(np.concatenate([sa, sb, np.clip(np.abs(sa - sb) * 20, 0, 1)], axis=1))
    img = np.concatenate(rows, axis=0)
    buf = oiio.ImageBuf(oiio.ImageSpec(img.shape[1], img.shape[0], 3, oiio.UINT8))
    buf.set_pixels(oiio.ROI(), np.ascontiguousarray((img * 255 + 0.5).astype(np.uint8)))
    path.parent.mkdir(parents=True, exist_ok=True)
    if not buf.write(str(path)):
        raise SystemExit(f"{path}: {buf.geterror()}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--sampling", default="small")
    ap.add_argument("--size", type=int, default=128, help="texels per side of each material (default 128)")
    ap.add_argument("--k", type=int, help="the recipes' k (default: the sampling's sample count)")
    ap.add_argument("--resolution", type=int, nargs=2, default=(192, 128), metavar=("W", "H"))
    ap.add_argument("--repeats", type=int, default=3, help="builds of each kind, from scratch, alternating "
                    "(the median is reported; default 3)")
    ap.add_argument("--domain", default="srgb", help="the recipes' --domain (default srgb; auto: the shaped "
                    "build keeps the full build's choice, issue 41)")
    ap.add_argument("--work", type=Path, help="work folder (default: a temporary one, removed)")
    ap.add_argument("--figure", type=Path, help="write the frames picture (PNG) here")
    args = ap.parse_args()
    from usdbtf.sampling import preset

    k = args.k or len(preset(args.sampling))
    work = Path(tempfile.mkdtemp(prefix="scene_aware_")) if args.work is None else args.work
    work.mkdir(parents=True, exist_ok=True)
    try:
        captures = work / "captures"
        for preset_name in MATERIALS.values():
            if not (captures / preset_name).exists():
                usdbtf("synth", preset_name, "-o", str(captures / preset_name), "--sampling", args.sampling,
                       "--size", str(args.size), "-q", cwd=work)
        doc = {"machine": machine_info(), "inputs": {"frames": args.frames, "sampling": args.sampling,
                                                     "size": args.size, "k": k, "resolution": list(args.resolution),
                                                     "domain": args.domain,
                                                     "materials": MATERIALS}}
        runs = {"full": {"build_s": []}, "shaped": {"build_s": []}}
        for repeat in range(args.repeats):          # each build from scratch, the two alternating
            for variant in ("full", "shaped"):
                folder = work / variant
                shutil.rmtree(folder, ignore_errors=True)
                folder.mkdir()
                path = scene(folder, captures, args.frames, second_camera=False, k=k, resolution=args.resolution,
                             domain=args.domain)
                flags = ["--full"] if variant == "full" else []
                build = usdbtf("build", str(path), "--json", *flags, cwd=folder)
                report = json.loads(build.stdout)
                r = runs[variant]
                r["build_s"].append(build.wall_s)
                r.update(bytes=built_bytes(folder), steps=len(report["ran"]),
                         step_seconds={m: c["seconds"] for m, c in report["costs"].items()},
                         needs={m: {key: n[key] for key in ("needed", "why_not", "stand_in", "views", "lights",
                                                           "pixels_per_texel", "max_texels", "sample_fraction")}
                                for m, n in report["needs"].items()})
        for variant, r in runs.items():
            folder = work / variant
            render = usdbtf("render", str(folder / "scene.usda"), "--camera", "/World/Cam", "--frames",
                            f"1:{args.frames}", "-o", str(folder / "frames" / "f.####.exr"), "--no-png", cwd=folder)
            r["render_s"] = render.wall_s
            r["build_median_s"] = float(np.median(r["build_s"]))
        scores = [psnr(rgba(work / "full" / "frames" / f"f.{f:04d}.exr"),
                       rgba(work / "shaped" / "frames" / f"f.{f:04d}.exr")) for f in range(1, args.frames + 1)]
        doc["psnr_db"] = [s for s, _ in scores]
        doc["geometry_pixels"] = [n for _, n in scores]
        # A second camera, then nothing changed.
        folder = work / "shaped"
        path = scene(folder, captures, args.frames, second_camera=True, k=k, resolution=args.resolution,
                     domain=args.domain)
        second = usdbtf("build", str(path), "--json", cwd=folder)
        again = usdbtf("build", str(path), "--json", cwd=folder)
        doc["second_camera"] = {"build_s": second.wall_s, "ran": json.loads(second.stdout)["ran"],
                                "bytes": built_bytes(folder),
                                "needs": {m: {key: n[key] for key in ("views", "lights", "max_texels")}
                                          for m, n in json.loads(second.stdout)["needs"].items()}}
        doc["unchanged"] = {"build_s": again.wall_s, "ran": json.loads(again.stdout)["ran"]}
        doc["runs"] = runs
        if args.figure:
            picks = sorted({1, (args.frames + 1) // 2, args.frames})
            figure(args.figure, work / "full" / "frames", work / "shaped" / "frames", picks)
            doc["figure"] = {"path": str(args.figure), "frames": picks}
        out = write_json(OUT / f"scene_aware_{timestamp()}.json", doc)
        print(report_text(doc, args, k, out))
    finally:
        if args.work is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0


def report_text(doc: dict, args, k: int, out: Path) -> str:
    full, shaped = doc["runs"]["full"], doc["runs"]["shaped"]
    p = np.asarray(doc["psnr_db"])
    lines = [format_machine(doc["machine"]), "",
             f"Scene: {args.frames} frames at {args.resolution[0]}x{args.resolution[1]}, materials "
             f"{args.sampling} sampling, {args.size}x{args.size} texels, recipe --k {k} --codec png --domain {args.domain}",
             "", f"| build | wall s (median of {len(full['build_s'])}; each) | bytes | steps run | render all frames s |",
             "|---|---|---|---|---|"]
    for name, r in (("full (`--full`)", full), ("scene-shaped", shaped)):
        each = ", ".join(f"{t:.1f}" for t in r["build_s"])
        lines.append(f"| {name} | {r['build_median_s']:.1f} ({each}) | {r['bytes'] / 1e6:.2f} MB | {r['steps']} | "
                     f"{r['render_s']:.1f} |")
    lines += ["", f"shaped / full: time {shaped['build_median_s'] / full['build_median_s']:.2f}, bytes "
              f"{shaped['bytes'] / full['bytes']:.3f}",
              f"frames: PSNR (sRGB, geometry pixels) min {p.min():.1f} dB, median {np.median(p):.1f} dB over "
              f"{len(p)} frames", "", "| material | needed | views kept | lights kept | pixels/texel | max texels |",
              "|---|---|---|---|---|---|"]
    for m, n in sorted(shaped["needs"].items()):
        ppt = "-" if n["pixels_per_texel"] is None else f"{n['pixels_per_texel']:.2f}"
        lines.append(f"| {m} | {'yes' if n['needed'] else ('no, a k = 1 stand-in: ' if n.get('stand_in') else 'no: ') + n['why_not']} | {n['views']['kept']}/"
                     f"{n['views']['measured']} | {n['lights']['kept']}/{n['lights']['measured']} | {ppt} | "
                     f"{n['max_texels'] or 'full'} |")
    sc = doc["second_camera"]
    lines += ["", f"second camera added: {sc['build_s']:.1f} s, ran {len(sc['ran'])} step(s): "
              + ", ".join(sc["ran"]),
              "views kept then: " + ", ".join(f"{m} {n['views']['kept']}" for m, n in sorted(sc["needs"].items())),
              f"unchanged: {doc['unchanged']['build_s']:.1f} s, ran {len(doc['unchanged']['ran'])} step(s)",
              f"JSON: {out}"]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
