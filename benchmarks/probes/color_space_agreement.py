"""Issue 40, colour: the BTF and its fallbacks per colour channel, no gain, in one frame's space.

    .venv/bin/python benchmarks/probes/color_space_agreement.py [--usd 25.02 25.08] [--no-cycles]

The asset: tests/storm_helpers.write_lambertian_asset with ``saturated_albedo()`` (16 x 16
texels on the "small" sampling, patches of saturated red, green and blue and a white, given in
linear Rec.709 -- what a UsdPreviewSurface diffuseColor means -- and taken through OCIO to the
BTF's working space, ACEScg, for its values; white level 0.8).  Its fallback fits are exact (a
Lambertian), so the BTF and its fallbacks can differ only in what each path makes of the
values' colour space.

The baseline, in the same run: the same BTF packaged with ``rendering_space`` = its working
space, so its shaders' rendering rows are the identity: exactly what an asset packaged before
issue 40's colour fix draws (working-space values in the renderer's frame).

Frames (no gain anywhere): real Storm (``.venv-storm-*``: USD 25.02 and 25.08), pole view,
orthographic, one texel a pixel, one DistantLight of irradiance 1 from ``--lights`` measured
pole-view directions: the BTF shader (now, and the baseline), the UsdPreviewSurface
(``fallback="preview"``) and the OpenPBR network (``fallback="openpbr"``).  Cycles (bpy 5.0.1):
the add-on's OSL BTF (now, and the baseline) and its Principled surface under one sun of
irradiance 1 from the same directions.

Printed per renderer, surface and patch: the patch's mean linear RGB over the lights (each
light's frame divided by cos(theta_l), so the mean is the patch's albedo / pi as a white
Lambertian UsdPreviewSurface would return it), and each channel's ratio to the expected
``albedo / pi`` in linear Rec.709 (Storm's and Blender's frame buffers).  1.000 in every
channel is agreement; the BTF before issue 40's colour fix returns ACEScg values in a Rec.709
frame (the red patch's green and blue several times too high).
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform; registers the schema plugin)
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parent.parent / "tests"))
from common import format_machine, machine_info  # noqa: E402

WHITE_LEVEL = 0.8


def towards(theta_phi) -> tuple:
    theta, phi = (math.radians(a) for a in theta_phi)
    return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))


def table(title: str, by_surface: dict, albedo_means: dict) -> None:
    """Print one renderer's per-patch, per-channel means and ratios to albedo / pi."""
    print(f"\n{title}\n")
    print("| surface | patch | mean R, G, B (x pi) | / expected R | G | B |")
    print("|---|---|---|---|---|---|")
    for surface, patches in by_surface.items():
        for name, rgb in patches.items():
            want = albedo_means[name] / math.pi
            ratio = rgb / want
            print(f"| {surface} | {name} | {', '.join(f'{v * math.pi:.4f}' for v in rgb)} | "
                  + " | ".join(f"{r:.3f}" for r in ratio) + " |")


def main(argv=None) -> int:
    from storm_helpers import patch_means, pole_lights, saturated_albedo, write_lambertian_asset
    from usdbtf.usd.preview import cycles, hydra
    from usdbtf.usd.read import load_btf

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--usd", nargs="+", default=sorted(hydra.STORM_ENVIRONMENTS))
    ap.add_argument("--lights", type=int, default=2)
    ap.add_argument("--no-cycles", action="store_true")
    ap.add_argument("--rendering-space", default=None,
                    help="package with this rendering space (default: package's own default)")
    args = ap.parse_args(argv)
    print(format_machine(machine_info()))
    pythons = hydra.storm_pythons()
    albedo = saturated_albedo()
    albedo_means = patch_means(albedo)
    with tempfile.TemporaryDirectory(prefix="usdbtf-color-") as tmp:
        work = Path(tmp)
        asset = write_lambertian_asset(work / "a" / "sat.usda", WHITE_LEVEL, albedo=albedo)
        before = write_lambertian_asset(work / "b" / "sat.usda", WHITE_LEVEL, albedo=albedo,
                                        rendering_space="scene_linear")
        cbtf = load_btf(asset)
        print(f"asset: saturated Lambertian, working space {cbtf.working_space}, W {WHITE_LEVEL}; "
              f"Material: {rendering_space_of(asset)}; baseline: {rendering_space_of(before)} (identity rows)")
        lights = pole_lights(cbtf, args.lights)
        print(f"lights (theta, phi): {[light for _, light in lights]}, irradiance 1, no gain")
        kinds = {"BTF shader": (asset, False), "BTF shader, before (identity rows)": (before, False),
                 "UsdPreviewSurface": (asset, "preview"), "OpenPBR": (asset, "openpbr")}
        for version in args.usd:
            if version not in pythons:
                print(f"USD {version}: no storm environment, skipped")
                continue
            frames = []
            for s, light in lights:
                for j, (source, fallback) in enumerate(kinds.values()):
                    scene = work / f"{version}_{s}_{j}.usda"
                    camera, size = hydra.swatch_scene(source, scene, light, irradiance=1.0, fallback=fallback)
                    frames.append((scene, scene.with_suffix(".exr")))
            result = hydra.render_frames(pythons[version], frames, camera, size)
            if result.problems:
                print("\n".join(result.problems))
            by_surface = {}
            for j, kind in enumerate(kinds):
                per_light = [patch_means(result.images[i * len(kinds) + j])
                             for i in range(len(lights))]
                by_surface[kind] = {name: np.mean([p[name] / math.cos(math.radians(light[0]))
                                                   for p, (_, light) in zip(per_light, lights)], axis=0)
                                    for name in albedo_means}
            table(f"Storm, USD {version} (frame: linear Rec.709)", by_surface, albedo_means)
        if not args.no_cycles:
            python = cycles.cycles_python()
            if python is None:
                print("no .venv-storm-5.0: Cycles skipped")
                return 0
            surfaces = {"BTF": (asset, "BTF"), "BTF, before (identity rows)": (before, "BTF"),
                        "PRINCIPLED": (asset, "PRINCIPLED")}
            frames = [cycles.CyclesFrame(source, work / f"cyc_{j}_{s}.exr", towards(light), size=(16, 16),
                                         irradiance=1.0, surface=surface)
                      for j, (source, surface) in enumerate(surfaces.values()) for s, light in lights]
            result = cycles.render_frames(python, frames, timeout=600.0)
            by_surface = {}
            for j, surface in enumerate(surfaces):
                imgs = result.images[j * len(lights):(j + 1) * len(lights)]
                by_surface[f"Cycles {surface}"] = {
                    name: np.mean([patch_means(img)[name] / math.cos(math.radians(light[0]))
                                   for img, (_, light) in zip(imgs, lights)], axis=0) for name in albedo_means}
            table(f"Cycles, bpy {cycles.BLENDER_VERSION} (frame: Blender's scene linear, linear Rec.709)",
                  by_surface, albedo_means)
    return 0


def rendering_space_of(asset: Path) -> str:
    """The Material's recorded rendering space, or "none recorded" (an asset before issue 40's colour fix)."""
    from pxr import Usd

    from usdbtf.usd.material import btf_materials

    stage = Usd.Stage.Open(str(asset))
    attr = btf_materials(stage)[0].GetAttribute("btf:renderingColorSpace")
    if attr and attr.HasAuthoredValue():
        return f"btf:renderingColorSpace = {attr.Get()!r}"
    return "no rendering space recorded"


if __name__ == "__main__":
    raise SystemExit(main())
