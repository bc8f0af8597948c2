"""Issue 40, Cycles must-show: the add-on's Principled fallback under one sun against the fit's
own model (no gain) and against the add-on's OSL BTF under the same sun (no gain).

    .venv/bin/python benchmarks/probes/cycles_principled_vs_btf.py \
        [--presets satin_weave metal_flakes velvet] [--sampling ubo81] [--size 16] [--k 32] [--lights 4]

Per preset (``velvet`` is held out from the fit's tuning): ``synth PRESET --sampling S --size N
--seed 5``, ``compress --k K --codec png``, ``package --no-thumbnail`` (the route of
tests/test_cycles.py's asset).  Frames (bpy 5.0.1, Cycles with OSL on the CPU, one sample at
the pixel centre, one texel a pixel, orthographic from the pole), all in one Blender process:
the add-on's ``PRINCIPLED`` surface and its OSL ``BTF`` under one sun of the capture irradiance
pi W (usdbtf.photometry) from ``--lights`` measured light directions at the pole view
(theta 15..65 degrees, tests/storm_helpers.pole_lights).

Printed per light: mean |difference| (8-bit sRGB steps) of the Principled frame against the
fit's model (usdbtf.openpbr.evaluate of the maps as shipped, Blender's linear Rec.709; the
test's reference, storm_helpers.openpbr_frame), Principled mean / model mean, Principled mean /
OSL BTF mean as the frames come (the OSL BTF returns the asset's rendering space,
btf:renderingColorSpace: linear Rec.709 since issue 40's colour fix, working-space values
before; the Principled Blender's linear Rec.709), the same with the BTF frame converted from
that space to linear Rec.709 (one space: the brightness comparison that means something for an
asset packaged before the fix), OSL BTF mean / the decompressed sample's mean (the frame taken
to the working space: the BTF path's own
check, 1 under the capture light), and the fit model's mean / the sample's mean in the working
space (no renderer: the fit's own bias).  After each preset's table: that ratio per colour
channel (swatch sums) averaged over the fit's pole samples (usdbtf.svbrdf.pole_samples: the pole
view, lights up to 70 degrees), the quantity the fits' brightness step (usdbtf.svbrdf.pole_ratio)
drives to 1, its mean over those lights and its range.  ``--lights`` as many as there are
measured lights at 15..65 degrees (ubo81: 56, small: 12) renders every one of them.

``--before REV``: the Principled frames also with the add-on's ``principled.py`` as it was at git
revision REV (a copy of the add-on folder with that module; same assets, lights and OSL BTF frames,
same Blender process kind): the "before" columns, steps against the model, / model and / OSL BTF in
one space, measured in the same run.

``--by-lobe``: per preset and light, the least-squares scale of each of the model's lobes (base,
specular, fuzz: usdbtf.openpbr.evaluate of the maps with the other two colours 0) that fits the
Principled frame (Rec.709, every texel and channel), and each lobe's share of the model: which of
Cycles' lobes departs from MaterialX's, and where.

``--by-parameter``: per preset, the Principled frames' per-texel brightness over the model's
(sum over the lights, Rec.709) against each scalar OpenPBR input: its range and that ratio in
its lower and upper half of texels (where Blender's Principled departs from the fit's model).
"""
from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform; registers the schema plugin)
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parent.parent / "tests"))
from common import format_machine, machine_info  # noqa: E402


def towards(theta_phi) -> tuple:
    theta, phi = (math.radians(a) for a in theta_phi)
    return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))


def build(preset: str, work: Path, sampling: str, size: int, k: int) -> Path:
    from usdbtf.cli import main

    out = work / preset / "a" / f"{preset}.usda"
    for argv in (["synth", preset, "-o", str(work / preset / "src"), "--sampling", sampling, "--size", str(size),
                  "--seed", "5"],
                 ["compress", str(work / preset / "src"), "-o", str(work / preset / "c"), "--k", str(k),
                  "--codec", "png"],
                 ["package", str(work / preset / "c"), "-o", str(out), "--no-thumbnail"]):
        print("$ usdbtf " + " ".join(argv), flush=True)
        if main(argv + ["-q"]) != 0:
            raise SystemExit(f"usdbtf {argv[0]} failed")
    return out


def main(argv=None) -> int:
    from bench_cycles import require_cycles_python
    from storm_helpers import openpbr_frame, pole_lights, shipped_openpbr_maps
    from usdbtf import openpbr
    from usdbtf.color import processor
    from usdbtf.compress import reconstruct
    from usdbtf.photometry import capture_irradiance, white_level_of
    from usdbtf.usd.asset.storm import rendering_space_of
    from usdbtf.usd.preview import cycles

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["satin_weave", "metal_flakes", "velvet"])
    ap.add_argument("--sampling", default="ubo81")
    ap.add_argument("--size", type=int, default=16)
    ap.add_argument("--k", type=int, default=32)
    ap.add_argument("--lights", type=int, default=4)
    ap.add_argument("--by-parameter", action="store_true", help="Principled / model per texel against each input")
    ap.add_argument("--by-lobe", action="store_true", help="per light, the scale of each model lobe that fits the frame")
    ap.add_argument("--before", metavar="REV", help="also render the Principled with principled.py at git revision REV")
    args = ap.parse_args(argv)
    python = require_cycles_python()
    print(format_machine(machine_info()))
    print(f"Blender (bpy) {cycles.BLENDER_VERSION}, Cycles with OSL on the CPU; inputs: --sampling {args.sampling} "
          f"--size {args.size} --seed 5, --k {args.k} --codec png, package --no-thumbnail", flush=True)
    rendering = "Linear Rec.709 (sRGB)"
    with tempfile.TemporaryDirectory(prefix="usdbtf-cyc-pr-") as tmp:
        work = Path(tmp)
        cases, frames = [], []
        for preset in args.presets:
            asset = build(preset, work, args.sampling, args.size, args.k)
            maps, cbtf = shipped_openpbr_maps(asset)
            lights = pole_lights(cbtf, args.lights)
            irradiance = capture_irradiance(white_level_of(cbtf.info))
            first = len(frames)
            frames += [cycles.CyclesFrame(asset, work / f"{preset}_{surface}_{s}.exr", towards(light),
                                          size=maps.shape[::-1], irradiance=irradiance, surface=surface)
                       for surface in ("PRINCIPLED", "BTF") for s, light in lights]
            # The OSL BTF returns the asset's rendering space (btf:renderingColorSpace; linear
            # Rec.709 since issue 40's colour fix, the working space before).
            cases.append((preset, maps, cbtf, lights, first, rendering_space_of(asset)[1]))
        result = cycles.render_frames(python, frames, timeout=1200.0)
        before = None
        if args.before:
            principled = [f for f in frames if f.surface == "PRINCIPLED"]
            for f in principled:
                f.output = f.output.with_name("before_" + f.output.name)
            before = cycles.render_frames(python, principled, timeout=1200.0,
                                          addon=addon_at(args.before, work / "addon_before")).images
            print(f"before: plugin/blender/usdbtf/principled.py at {args.before}", flush=True)
    extra = " before: steps | before: / model | before: / OSL BTF (one space) |" if before else ""
    print("\n| preset | light (theta, phi) | Principled vs fit model (steps) | Principled / model | "
          "Principled / OSL BTF (as rendered) | Principled / OSL BTF (one space, Rec.709) | OSL BTF / sample | "
          "fit model / sample |" + extra)
    print("|---|---|---|---|---|---|---|---|" + "---|" * (3 if before else 0))
    seen = 0
    for preset, maps, cbtf, lights, first, drawn in cases:
        n = len(lights)
        rec = reconstruct(cbtf, [s for s, _ in lights])
        to709 = processor(drawn, rendering, cbtf.ocio_config)
        to_working = processor(drawn, cbtf.working_space, cbtf.ocio_config)
        rows = []
        for i, (s, light) in enumerate(lights):
            principled = result.images[first + i][..., :3].astype(np.float64)
            btf = result.images[first + n + i][..., :3].astype(np.float64)
            model = openpbr_frame(maps, light, rendering, cbtf.ocio_config)
            fit = openpbr.evaluate(maps, np.zeros((1, 2)), np.asarray([light], float))[0]
            btf709 = to709.apply(np.ascontiguousarray(btf, np.float32)).astype(np.float64)
            btf_working = to_working.apply(np.ascontiguousarray(btf, np.float32)).astype(np.float64)
            row = (float(np.abs(cycles.srgb8(principled) - cycles.srgb8(model)).mean()),
                   principled.mean() / model.mean(), principled.mean() / btf.mean(),
                   principled.mean() / btf709.mean(), btf_working.mean() / float(rec[i].mean()),
                   float(fit.mean() / rec[i].mean()))
            if before:
                old = before[seen + i][..., :3].astype(np.float64)
                row += (float(np.abs(cycles.srgb8(old) - cycles.srgb8(model)).mean()), old.mean() / model.mean(),
                        old.mean() / btf709.mean())
            rows.append(row)
            print(f"| {preset} | ({light[0]:.0f}, {light[1]:.0f}) | " + " | ".join(f"{v:.3f}" for v in row) + " |")
        mean = np.mean(rows, axis=0)
        print(f"| {preset} ({cbtf.working_space}) | **mean** | " + " | ".join(f"**{v:.3f}**" for v in mean) + " |", flush=True)
        print(f"  {preset}: fit model / sample over the fit's pole samples: " + pole_mean(maps, cbtf), flush=True)
        seen += n
        if args.by_lobe:
            by_lobe(preset, maps, cbtf, lights, [result.images[first + i][..., :3] for i in range(n)], rendering)
        if args.by_parameter:
            by_parameter(preset, maps, [result.images[first + i][..., :3] for i in range(n)],
                         [openpbr_frame(maps, light, rendering, cbtf.ocio_config) for _, light in lights])
    return 0


def addon_at(rev: str, folder: Path) -> Path:
    """A copy of plugin/blender (with the OSL surface beside the add-on, where network.py looks
    first) whose usdbtf/principled.py is the one at git revision ``rev``; returns the copy."""
    from usdbtf.plugin_folder import plugin_dir

    root = Path(__file__).resolve().parents[2]
    shutil.copytree(plugin_dir() / "blender", folder)
    shutil.copy(plugin_dir() / "usdBtf" / "resources" / "osl" / "usdbtf_surface.osl",
                folder / "usdbtf" / "usdbtf_surface.osl")
    text = subprocess.run(["git", "show", f"{rev}:plugin/blender/usdbtf/principled.py"], cwd=root,
                          capture_output=True, text=True, check=True).stdout
    (folder / "usdbtf" / "principled.py").write_text(text)
    return folder


def pole_mean(maps, cbtf) -> str:
    """Per channel, the fit model's swatch sum over the BTF's, averaged over the fit's own pole
    samples (usdbtf.svbrdf.pole_samples: the views nearest the normal, lights up to
    POLE_MAX_LIGHT_DEG; working space; usdbtf.svbrdf.pole_ratio, what the brightness step drives
    to 1), the mean over those lights of the mean ratio, and its per-light range."""
    from usdbtf import openpbr
    from usdbtf.compress import reconstruct
    from usdbtf.svbrdf import pole_ratio, pole_samples

    pole = pole_samples(cbtf)
    rec = reconstruct(cbtf, pole).reshape(len(pole), -1, 3).astype(np.float64)
    pred = openpbr.evaluate(maps, cbtf.sampling.view[pole], cbtf.sampling.light[pole]).astype(np.float64)
    per_channel = pole_ratio(rec.sum(axis=1), pred.sum(axis=1))
    per_light = pred.mean(axis=(1, 2)) / rec.mean(axis=(1, 2))
    return (f"{len(pole)} lights, per channel {' / '.join(f'{v:.3f}' for v in per_channel)}, "
            f"mean {per_light.mean():.3f}, per light {per_light.min():.3f}..{per_light.max():.3f}")


def by_lobe(preset: str, maps, cbtf, lights, principled: list, rendering: str) -> None:
    """Print, per light, the least-squares scale of the model's base, specular and fuzz lobes
    that fits the Principled frame, and each lobe's share of the model (``--by-lobe``)."""
    from dataclasses import replace

    from storm_helpers import openpbr_frame

    zero = np.zeros_like(maps.base_color)
    lobes = {"base": replace(maps, specular_color=zero, fuzz_color=zero),
             "specular": replace(maps, base_color=zero, fuzz_color=zero),
             "fuzz": replace(maps, base_color=zero, specular_color=zero)}
    for (_, light), frame in zip(lights, principled):
        x = np.stack([openpbr_frame(m, light, rendering, cbtf.ocio_config).reshape(-1) for m in lobes.values()], axis=1)
        scale = np.linalg.lstsq(x.astype(np.float64), np.asarray(frame, np.float64).reshape(-1), rcond=None)[0]
        share = x.sum(axis=0) / max(float(x.sum()), 1e-30)
        print(f"  {preset} ({light[0]:.0f}, {light[1]:.0f}): Principled / model lobe: " +
              ", ".join(f"{k} {s:.3f} (share {w:.2f})" for k, s, w in zip(lobes, scale, share)))


def by_parameter(preset: str, maps, principled: list, models: list) -> None:
    """Print, per scalar input, the Principled / model brightness of the texels below and above
    its median (``--by-parameter``)."""
    p = np.sum([np.asarray(f, np.float64).sum(axis=-1) for f in principled], axis=0).reshape(-1)
    m = np.sum([np.asarray(f, np.float64).sum(axis=-1) for f in models], axis=0).reshape(-1)
    for name in maps.SCALARS:
        value = getattr(maps, name).reshape(-1)
        if np.ptp(value) < 1e-6:
            print(f"  {preset} {name}: constant {value[0]:.3f}")
            continue
        low = value <= np.median(value)
        if low.all():
            low = value < value.max()
        print(f"  {preset} {name}: {value.min():.3f}..{value.max():.3f}; Principled / model "
              f"{p[low].sum() / m[low].sum():.3f} (lower half, {low.sum()} texels), "
              f"{p[~low].sum() / m[~low].sum():.3f} (upper)")


if __name__ == "__main__":
    sys.exit(main())
