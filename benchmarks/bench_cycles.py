"""Issue 30: the usdbtf OSL shader in Blender's Cycles against the decompressed samples, the CPU
reference and Storm; and the figure of docs/production-renderers-and-fallbacks.md (Cycles, Storm, CPU side by side).

    python benchmarks/bench_cycles.py [--figure docs/cycles_preview.png] [--size 192]

Needs the bpy 5.0.1 environment (``.venv-storm-5.0``, made by ``scripts/bootstrap.sh``).
Inputs, made here by the usdbtf commands (printed): a held-out material (``satin_weave``, the
UBO2003 sampling of measured directions, 16 x 16 texels, k = 32, the tests' asset) and, for
the figure, the example's pebbles (small sampling, 64 texels, k = 32) on a 5 cm icosphere
unwrapped by ``usdbtf unwrap``.  Measured in one run:

* the swatch from the pole under one sun at 5 measured light directions, one pixel per texel:
  each light's own gain and mean |difference| (8-bit sRGB steps) after the common gain, at
  the full lod and at lod k8 (the add-on's lod choice);
* the curved mesh under one sun against ``usdbtf render`` of the same camera and light: PSNR
  (sRGB, where both have geometry), and Storm (USD 25.08) against the same;
* render times: Cycles' render (the import excluded), ``usdbtf render`` and Storm as wall
  time of their call (a process each for Storm), single runs (the figure's frames).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import format_machine, machine_info
from usdbtf.camera import Camera
from usdbtf.cli import main as usdbtf
from usdbtf.render.output import srgb_encoded
from usdbtf.decompress import DecompressOptions, decompress
from usdbtf.gpu.headless import psnr
from usdbtf.render.scene import Light
from usdbtf.usd.preview import cycles, hydra
from usdbtf.usd.read import load_btf
from usdbtf.usd.scenes.scene import write_scene
from usdbtf.usd.asset.storm import read_rgba, to_rendering_space

#: Measured light directions of the UBO2003 sampling (theta, phi degrees).
LIGHTS = [(15.0, 60.0), (30.0, 0.0), (45.0, 180.0), (60.0, 120.0), (75.0, 240.0)]
SUN = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])


def require_cycles_python() -> Path:
    """The bpy 5.0.1 environment's Python; exits with the reason where it is absent."""
    python = cycles.cycles_python()
    if python is None:
        raise SystemExit("no .venv-storm-5.0 (bpy 5.0.1): run scripts/bootstrap.sh")
    return python


def run(*args: str) -> None:
    print("$ usdbtf " + " ".join(args), flush=True)
    if usdbtf([*args, "-q"]) != 0:
        raise SystemExit(f"usdbtf {args[0]} failed")


def towards(theta_phi) -> tuple:
    theta, phi = np.radians(theta_phi)
    return (float(np.sin(theta) * np.cos(phi)), float(np.sin(theta) * np.sin(phi)), float(np.cos(theta)))


def make_assets(work: Path) -> dict:
    """{"swatch", "satin_sphere", "pebbles_sphere"}: packaged assets (.usda)."""
    import trimesh

    run("synth", "satin_weave", "-o", str(work / "satin_src"), "--sampling", "ubo81", "--size", "16", "--seed", "5")
    run("compress", str(work / "satin_src"), "-o", str(work / "satin_c"), "--k", "32", "--codec", "png")
    run("package", str(work / "satin_c"), "-o", str(work / "swatch" / "satin.usda"))
    run("synth", "pebbles", "-o", str(work / "pebbles_src"), "--sampling", "small", "--size", "64", "--seed", "1")
    run("compress", str(work / "pebbles_src"), "-o", str(work / "pebbles_c"), "--k", "32")
    trimesh.creation.icosphere(4, radius=0.05).export(work / "sphere.obj")
    out = {"swatch": work / "swatch" / "satin.usda"}
    for name in ("satin", "pebbles"):
        run("unwrap", str(work / "sphere.obj"), "-o", str(work / f"{name}_uv"), "--btf", str(work / f"{name}_c"))
        out[f"{name}_sphere"] = work / f"{name}_sphere" / f"{name}.usda"
        run("package", str(work / f"{name}_c"), "-o", str(out[f"{name}_sphere"]), "--mesh",
            str(work / f"{name}_uv" / "mesh.usda"))
    return out


def swatch_rows(python: Path, asset: Path, work: Path) -> list[str]:
    from usdbtf.compress.format import cross_layout

    rows = []
    for lod in (None, "k8"):
        cbtf = load_btf(asset, lod=lod)
        _, n_lights = cross_layout(cbtf.sampling)
        lights = cbtf.sampling.light[:n_lights]
        frames, references, used = [], [], []
        for i, want in enumerate(LIGHTS):
            j = int(np.argmin(np.abs(lights - np.asarray(want)).sum(axis=1)))
            used.append(tuple(lights[j]))
            frames.append(cycles.CyclesFrame(asset, work / f"swatch_{lod}_{i}.exr", towards(lights[j]), size=(16, 16),
                                             lod=lod))
            # In the space the OSL shader returns (the asset's rendering space; issue 40).
            references.append(to_rendering_space(asset, decompress(cbtf, DecompressOptions(samples=str(j)))
                                                 .btf.read_samples([0])[0]).astype(np.float64))
        result = cycles.render_frames(python, frames)
        gain, gains, steps = cycles.common_gain([(img[..., :3].astype(np.float64), ref)
                                                 for img, ref in zip(result.images, references)])
        spread = 100.0 * (max(gains) / min(gains) - 1.0)
        for (theta, phi), own, step, seconds in zip(used, gains, steps, result.seconds):
            rows.append(f"| swatch, lod {lod or 'full'} (k {cbtf.k}) | light ({theta:.0f}, {phi:.0f}) | {step:.4f} | "
                        f"{own:.5f} | {seconds:.2f} |")
        rows.append(f"| swatch, lod {lod or 'full'} | common gain {gain:.5f}, spread {spread:.4f} % | | | |")
    return rows


def mesh_frames(python: Path, asset: Path, size: int, work: Path) -> dict:
    """Cycles, CPU and Storm frames of ``asset`` under one camera and one sun, with timings."""
    camera = Camera(np.array([0.05, 0.06, 0.15]), np.zeros(3), np.array([0.0, 1.0, 0.0]), 35.0, size, size)
    scene = work / f"{asset.stem}_{size}_scene.usda"
    prim = write_scene(asset.resolve(), scene, camera, [Light("directional", SUN, 1.0)])
    start = time.perf_counter()
    cpu_out = work / f"{asset.stem}_{size}_cpu.exr"
    assert usdbtf(["render", str(scene), "--camera", prim, "--size", str(size), str(size), "--no-shadows", "--filter",
                   "bilinear", "-o", str(cpu_out), "--no-png", "-q"]) == 0
    cpu_seconds = time.perf_counter() - start
    result = cycles.render_frames(python, [cycles.CyclesFrame(asset, work / f"{asset.stem}_{size}_cycles.exr",
                                                              tuple(SUN), camera=camera, size=(size, size))])
    # usdbtf render writes the working space, Cycles and Storm the asset's rendering space (issue 40):
    # their frames are taken to the working space.
    out = {"cpu": np.asarray(read_rgba(cpu_out), np.float64),
           "cycles": to_rendering_space(asset, result.images[0], back=True).astype(np.float64),
           "cpu_s": cpu_seconds, "cycles_s": result.seconds[0]}
    storm_python = hydra.storm_pythons().get("25.08")
    if storm_python is not None:
        start = time.perf_counter()
        storm = hydra.render_frames(storm_python, [(scene, work / f"{asset.stem}_{size}_storm.exr")], prim,
                                    (size, size))
        out["storm"], out["storm_s"] = (to_rendering_space(asset, storm.images[0], back=True).astype(np.float64),
                                        time.perf_counter() - start)
    for name in ("cycles", "storm"):
        if name in out:
            both = (out[name][..., 3] > 0.999) & (out["cpu"][..., 3] > 0.999)
            out[f"{name}_db"] = psnr(srgb_encoded(out[name][..., :3]), srgb_encoded(out["cpu"][..., :3]), both)
    return out


def figure(frames: dict, working_space: str, size: int) -> np.ndarray:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "examples"))
    from preview_figure import _tile

    tiles = [_tile(frames["cycles"], working_space, f"Cycles OSL, {frames['cycles_db']:.1f} dB", size)]
    if "storm" in frames:
        tiles.append(_tile(frames["storm"], working_space, f"Storm glslfx, {frames['storm_db']:.1f} dB", size))
    tiles.append(_tile(frames["cpu"], working_space, "usdbtf render (CPU)", size))
    return np.concatenate(tiles, axis=1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--figure", type=Path, help="write the Cycles | Storm | CPU figure (PNG) here")
    p.add_argument("--size", type=int, default=192, help="the figure's frame size (pixels)")
    args = p.parse_args(argv)
    python = require_cycles_python()
    print(format_machine(machine_info()))
    print(f"Blender (bpy) {cycles.BLENDER_VERSION}, Cycles on the CPU with OSL, 1 sample at the pixel centre, "
          "2 threads")
    with tempfile.TemporaryDirectory(prefix="usdbtf-bench-cycles-") as tmp:
        work = Path(tmp)
        assets = make_assets(work)
        rows = swatch_rows(python, assets["swatch"], work)
        mesh_rows = []
        for name, size in (("satin_sphere", 64), ("pebbles_sphere", args.size)):
            frames = mesh_frames(python, assets[name], size, work)
            storm = (f"{frames['storm_db']:.2f} dB, {frames['storm_s']:.2f} s" if "storm" in frames else "no Storm env")
            mesh_rows.append(f"| {name.split('_')[0]} on an icosphere, {size}² px | {frames['cycles_db']:.2f} | "
                             f"{frames['cycles_s']:.2f} | {frames['cpu_s']:.2f} | {storm} |")
            if name == "pebbles_sphere" and args.figure:
                from usdbtf.imageio import write_image

                image = figure(frames, load_btf(assets[name]).working_space, size)
                args.figure.parent.mkdir(parents=True, exist_ok=True)
                write_image(args.figure, image, color_space="sRGB Encoded Rec.709 (sRGB)")
                print(f"figure: {args.figure}")
    print("\n| swatch | light (theta, phi) | mean abs diff (8-bit steps) | own gain | Cycles s |")
    print("|---|---|---|---|---|")
    print("\n".join(rows))
    print("\n| curved mesh, one sun | Cycles vs usdbtf render PSNR (dB, sRGB) | Cycles s | usdbtf render s | "
          "Storm vs usdbtf render (25.08) |")
    print("|---|---|---|---|---|")
    print("\n".join(mesh_rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
