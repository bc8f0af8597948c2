#!/usr/bin/env python
"""The BTF and its UsdPreviewSurface fallback under the same UsdLux light, in real Storm (issue 40).

For each preset: ``usdbtf synth PRESET --sampling SAMPLING --size SIZE`` (seed 5),
``compress --k K --codec png``, ``package --physical-size 0.05 0.05``; then per USD version
(the ``.venv-storm-*`` environments) one Storm process draws, for each of ``--lights``
measured light directions at the pole view, orthographically from the pole, one texel a
pixel, under one ``UsdLux.DistantLight`` of irradiance 1 (``usd.preview.hydra.swatch_scene``):

btf       the asset as packaged (the BTF shader, this convention: radiance = value x E / (pi W));
fallback  the same asset with ``outputs:glslfx:surface`` and ``outputs:mtlx:surface`` blocked: the
          UsdPreviewSurface fallback (``swatch_scene(fallback="preview")``);
nearest   the fallback with its maps sampled texel by texel (``swatch_scene(nearest=True)``:
          ``minFilter``/``magFilter`` "nearest" on each ``UsdUVTexture``, which Storm honours):
          at one texel a pixel Storm on llvmpipe otherwise low-passes the maps (``checker``
          below), and the fallback's brightness is not linear in them (normals renormalised,
          roughness and F0 inside products);
aniso1    the fallback as drawn, with ``HGI_MAX_ANISOTROPY=1`` in Storm's environment: llvmpipe's
          anisotropic filtering (Storm asks for 16x) is what low-passes the maps at one texel a
          pixel (``probes/storm_checker_alignment.py``: with it off a checker reads 0 and 1);
openpbr   the same asset drawing only its OpenPBR network (``fallback="openpbr"``);
legacy    the BTF shader with ``inputs:exposure = pi W``: exactly the shader before this convention
          (irradiance 1 = the capture light), the baseline, measured in the same run.

``--before``: each preset also packaged with the fits' brightness step off (``svbrdf.keep_brightness``,
``openpbr.keep_brightness``; :func:`brightness_step_off`) from the same compressed BTF, measured in
the same run.  A last table gives per preset, USD version and fit the mean (min-max) over the
lights of: the UsdPreviewSurface as drawn, with ``HGI_MAX_ANISOTROPY=1``, sampled nearest, the
fit's model, and the same for OpenPBR (its model from the OpenPBR maps as shipped,
``openpbr.evaluate``), the Storm frames taken to the working space.

Reported: the BTF's gain against the decompressed samples (``usd.preview.cycles.common_gain``: one
least-squares gain per light, their mean; the convention says pi W) and its mean |difference|
in 8-bit sRGB steps after that gain; per light the fallback's mean brightness over the BTF's
(``fallback.mean() / btf.mean()``, linear RGB, no gain) now and before (over ``legacy``).  To
tell the causes apart, in the same run and at the same lights:

model     the fit's own prediction (``svbrdf.evaluate`` of the maps as shipped) over the BTF's
          reconstruction, mean over the swatch (exact sampling, no renderer);
working   the Storm fallback frame taken from linear Rec.709 (what Storm shades the sRGB maps
          in), and the BTF's from the asset's rendering space (btf:renderingColorSpace: linear
          Rec.709 since issue 40's colour fix, the working space before), to the BTF's working
          space before the mean (the BTF's gain against the samples is taken there too);
flat      the Storm fallback with its normal map blocked;
cycles    Cycles (bpy 5.0.1): Blender's USD importer's Principled BSDF from the fallback over
          the add-on's OSL BTF, one sun of 1 W/m^2 (``--cycles``);
checker   Storm's sampling of a UsdUVTexture: the fallback's diffuse map replaced by a
          black/white checker, flat normal, no specular, light at the pole; min and max over the
          white level 1/pi of the frame's middle half at one texel a pixel (in brackets: at four
          pixels a texel); exact sampling: 0 and 1.  Once per USD version the same checker on a
          hand-authored quad (UsdPreviewSurface <- UsdUVTexture, no usdbtf asset).

Usage (repository root)::

    .venv/bin/python benchmarks/bench_storm_photometry.py
    .venv/bin/python benchmarks/bench_storm_photometry.py --presets satin_weave --usd 25.08

Writes benchmarks/out/storm_photometry_<timestamp>.json and prints a markdown block.
"""
from __future__ import annotations

import argparse
import contextlib
import math
import sys
import tempfile
import time
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform; registers the schema plugin)
import numpy as np

from common import OUT, format_machine, machine_info, timestamp, write_json


def say(msg: str = "") -> None:
    print(msg, flush=True)


@contextlib.contextmanager
def brightness_step_off():
    """Within: ``svbrdf.fit_svbrdf`` and ``openpbr.fit_openpbr`` default to ``brightness=False``
    (the fits before their brightness step, issue 40: ``--before``).  ``usdbtf package`` runs in
    this process, so the asset it writes carries the fits as they were."""
    import inspect

    from usdbtf import openpbr, svbrdf

    fits = [inspect.unwrap(svbrdf.fit_svbrdf), inspect.unwrap(openpbr.fit_openpbr)]
    saved = [dict(f.__kwdefaults__) for f in fits]
    for f in fits:
        f.__kwdefaults__["brightness"] = False
    try:
        yield
    finally:
        for f, kw in zip(fits, saved):
            f.__kwdefaults__ = kw


def build(preset: str, work: Path, sampling: str, size: int, k: int, before: bool = False) -> Path:
    """The preset's asset (module docstring); ``before``: packaged with :func:`brightness_step_off`
    from the same compressed BTF."""
    from usdbtf.cli import main

    src, comp = work / "src", work / "c"
    asset = work / ("a_before" if before else "a") / f"{preset}.usda"
    steps = [["package", str(comp), "-o", str(asset), "--physical-size", "0.05", "0.05"]]
    if not (comp / "btf-compressed.json").is_file():
        steps[:0] = [["synth", preset, "-o", str(src), "--sampling", sampling, "--size", str(size), "--seed", "5"],
                     ["compress", str(src), "-o", str(comp), "--k", str(k), "--codec", "png"]]
    for argv in steps:
        with brightness_step_off() if before else contextlib.nullcontext():
            if main(argv + ["-q"]) != 0:
                raise SystemExit(f"usdbtf {' '.join(argv)} failed")
    return asset


def pole_lights(cbtf, count: int) -> list[tuple[int, tuple[float, float]]]:
    """[(sample index, light (theta, phi))] of ``count`` measured lights at the pole view with
    theta in 15..65 degrees, spread over the list (deterministic)."""
    view0 = np.flatnonzero(np.all(np.abs(cbtf.sampling.view) < 1e-9, axis=1))
    cand = [int(s) for s in view0 if 15.0 <= cbtf.sampling.light[s][0] <= 65.0]
    picks = [cand[int(round(i))] for i in np.linspace(0, len(cand) - 1, min(count, len(cand)))]
    return [(s, tuple(float(a) for a in cbtf.sampling.light[s])) for s in picks]


def flat_normal(scene: Path) -> None:
    """Block the fallback's normal-map connection in ``scene`` (normal (0, 0, 1))."""
    from pxr import Gf, Usd, UsdShade

    from usdbtf.usd.material import btf_materials

    stage = Usd.Stage.Open(str(scene))
    for material in btf_materials(stage):
        surface = UsdShade.Shader(stage.GetPrimAtPath(material.GetPath().AppendChild("PreviewSurface")))
        surface.GetInput("normal").GetAttr().SetConnections([])
        surface.GetInput("normal").Set(Gf.Vec3f(0.0, 0.0, 1.0))
    stage.Save()


def fit_model_ratios(asset: Path, cbtf, samples: list[int], kind: str = "preview") -> list[float]:
    """Per sample: the shipped fallback maps' prediction over the BTF's reconstruction, mean
    over the swatch; ``kind`` "preview" (UsdPreviewSurface maps, ``svbrdf.evaluate``) or
    "openpbr" (the OpenPBR maps, ``openpbr.evaluate``)."""
    from usdbtf import openpbr, svbrdf
    from usdbtf.compress import reconstruct
    from usdbtf.imageio import read_image
    from usdbtf.usd.asset import fallback
    from usdbtf.usd.asset import openpbr as usd_openpbr

    module, evaluate = (fallback, svbrdf.evaluate) if kind == "preview" else (usd_openpbr, openpbr.evaluate)
    folder = asset.with_name(f"{asset.stem}_textures") / fallback.FALLBACK_DIR
    pixels = {name: read_image(folder / module.MAP_FILES[name][0])[0] for name in module.MAP_FILES}
    maps = module.decode_maps(pixels, cbtf.working_space, ocio_config=cbtf.ocio_config)
    pred = evaluate(maps, cbtf.sampling.view[samples], cbtf.sampling.light[samples])
    rec = reconstruct(cbtf, samples)
    return [float(pred[i].mean() / rec[i].mean()) for i in range(len(samples))]


def cycles_ratios(asset: Path, lights, work: Path) -> list[float]:
    """Per light: Blender's Principled BSDF from the fallback over the add-on's OSL BTF (Cycles)."""
    from usdbtf.usd.preview import cycles
    from usdbtf.usd.preview.hydra import storm_pythons

    def towards(light):
        theta, phi = (math.radians(a) for a in light)
        return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))

    frames = [cycles.CyclesFrame(asset, work / f"cycles_{s}_{fb}.exr", towards(light), size=(32, 32), fallback=fb)
              for s, light in lights for fb in (False, True)]
    images = cycles.render_frames(storm_pythons()["25.08"], frames).images
    return [float(images[2 * i + 1][..., :3].mean() / images[2 * i][..., :3].mean()) for i in range(len(lights))]


def storm_checker(asset: Path, python: Path, work: Path) -> dict:
    """Storm's sampling of a UsdUVTexture at one texel a pixel (see the module docstring)."""
    import shutil

    import OpenImageIO as oiio
    from pxr import Gf, Usd, UsdShade

    from usdbtf.usd.preview import hydra
    from usdbtf.usd.material import btf_materials

    copy = work / "checker"
    shutil.copytree(asset.parent, copy)
    asset = copy / asset.name
    diffuse = copy / f"{asset.stem}_textures" / "fallback" / "diffuse.png"
    h, w = oiio.ImageInput.open(str(diffuse)).spec().height, oiio.ImageInput.open(str(diffuse)).spec().width
    pixels = np.where((np.add.outer(np.arange(h), np.arange(w)) % 2 == 0)[..., None], 255, 0).astype(np.uint8)
    out = oiio.ImageOutput.create(str(diffuse))
    out.open(str(diffuse), oiio.ImageSpec(w, h, 3, "uint8"))
    out.write_image(np.repeat(pixels, 3, axis=2))
    out.close()
    scene = copy / "scene.usda"
    camera, size = hydra.swatch_scene(asset, scene, (0.0, 0.0), irradiance=1.0, fallback="preview")
    stage = Usd.Stage.Open(str(scene))
    for material in btf_materials(stage):
        surface = UsdShade.Shader(stage.GetPrimAtPath(material.GetPath().AppendChild("PreviewSurface")))
        for name, value in (("normal", Gf.Vec3f(0, 0, 1)), ("specularColor", Gf.Vec3f(0, 0, 0))):
            surface.GetInput(name).GetAttr().SetConnections([])
            surface.GetInput(name).Set(value)
    stage.Save()
    out = {}
    for mag in (1, 4):
        frame = hydra.render_frames(python, [(scene, copy / f"x{mag}.exr")], camera,
                                    (size[0] * mag, size[1] * mag)).images[0][..., 0] * math.pi
        h4, w4 = frame.shape[0] // 4, frame.shape[1] // 4
        middle = frame[h4:3 * h4, w4:3 * w4]                 # the frame's middle half, away from the edges
        out[f"x{mag}"] = {"min": float(frame.min()), "max": float(frame.max()),
                          "middle_min": float(middle.min()), "middle_max": float(middle.max())}
    out.update(min=out["x1"]["min"], max=out["x1"]["max"])
    return out


def storm_minimal_checker(python: Path, work: Path, n: int = 32) -> dict:
    """The checker without usdbtf: a hand-authored unit quad, UsdPreviewSurface <- UsdUVTexture
    (sRGB PNG, n x n black/white checker) <- UsdPrimvarReader_float2 st, an orthographic camera
    one texel a pixel, one DistantLight of irradiance pi from the pole.  Frame middle-half
    min..max over the white level (exact: 0..1)."""
    from probes.storm_checker_alignment import quad
    from usdbtf.usd.preview import hydra

    folder = work / "minimal"
    folder.mkdir()
    path = quad(folder, n)
    frame = hydra.render_frames(python, [(path, folder / "quad.exr")], "/World/Camera", (n, n)).images[0][..., 0]
    middle = frame[n // 4:3 * n // 4, n // 4:3 * n // 4]
    return {"middle_min": float(middle.min()), "middle_max": float(middle.max())}


def legacy_exposure(scene: Path, value: float) -> None:
    """Set the BTF shader's inputs:exposure in ``scene`` (the old convention's brightness)."""
    from pxr import Usd

    from usdbtf.usd.material import btf_materials
    from usdbtf.usd.asset.storm import storm_shader

    stage = Usd.Stage.Open(str(scene))
    for material in btf_materials(stage):
        storm_shader(material).GetInput("exposure").Set(float(value))
    stage.Save()


def measure(asset: Path, python: Path, work: Path, count: int) -> dict:
    from usdbtf.color import processor
    from usdbtf.decompress import DecompressOptions, decompress
    from usdbtf.usd.asset.storm import rendering_space_of
    from usdbtf.photometry import capture_irradiance, white_level_of
    from usdbtf.usd.preview import hydra
    from usdbtf.usd.preview.cycles import common_gain
    from usdbtf.usd.read import load_btf

    cbtf = load_btf(asset)
    white = white_level_of(cbtf.info)
    lights = pole_lights(cbtf, count)
    frames, kinds = [], []
    for s, light in lights:
        for kind in ("btf", "fallback", "nearest", "openpbr", "legacy", "flat"):
            scene = work / f"{kind}_{s}.usda"
            # "fallback" is the UsdPreviewSurface (Storm would otherwise draw the OpenPBR network).
            pick = {"fallback": "preview", "nearest": "preview", "flat": "preview", "openpbr": "openpbr"}.get(kind, False)
            camera, size = hydra.swatch_scene(asset, scene, light, irradiance=1.0, fallback=pick,
                                              nearest=kind == "nearest")
            if kind == "legacy":
                legacy_exposure(scene, capture_irradiance(white))
            if kind == "flat":
                flat_normal(scene)
            frames.append((scene, scene.with_suffix(".exr")))
            kinds.append((s, kind))
    t = time.perf_counter()
    result = hydra.render_frames(python, frames, camera, size)
    seconds = time.perf_counter() - t
    if result.problems:
        raise SystemExit("\n".join(result.problems))
    images = {key: img[..., :3].astype(np.float64) for key, img in zip(kinds, result.images)}
    # The fallback again with llvmpipe's anisotropic filtering off (HGI_MAX_ANISOTROPY=1, which
    # reaches Storm only through the environment render_frames passes): at one texel a pixel
    # llvmpipe's anisotropic path blurs a checker to 0.49-0.51, with it off 0 and 1 (probes/
    # storm_checker_alignment.py).
    again = [(s, kind, scene) for (scene, _), (s, kind) in zip(frames, kinds) if kind in ("fallback", "openpbr")]
    aniso = hydra.render_frames(python, [(scene, scene.with_name(f"{scene.stem}_aniso1.exr")) for _, _, scene in again],
                                camera, size, env=dict(hydra.storm_environment(), HGI_MAX_ANISOTROPY="1"))
    for (s, kind, _), img in zip(again, aniso.images):
        images[(s, "aniso1" if kind == "fallback" else "openpbr_aniso1")] = img[..., :3].astype(np.float64)
    # Storm decodes the fallback's sRGB maps to linear Rec.709 and shades in it; the BTF shader
    # returns the asset's rendering space (btf:renderingColorSpace, linear Rec.709 since issue 40's
    # colour fix; an older asset: its working space).  The "working" columns take every frame to
    # the working space (the samples' and the fit model's), the others compare them as drawn.
    to_working = processor("Linear Rec.709 (sRGB)", cbtf.working_space, cbtf.ocio_config)
    _, drawn_space, _ = rendering_space_of(asset)
    btf_to_working = processor(drawn_space, cbtf.working_space, cbtf.ocio_config)
    for s, _ in lights:
        for kind in ("btf", "legacy"):
            images[(s, kind + "_working")] = btf_to_working.apply(
                images[(s, kind)].astype(np.float32)).astype(np.float64)
    matched = {s: to_working.apply(images[(s, "fallback")].astype(np.float32)).astype(np.float64) for s, _ in lights}
    matched_nearest = {s: to_working.apply(images[(s, "nearest")].astype(np.float32)).astype(np.float64)
                       for s, _ in lights}
    def working_ratio(frame, btf):
        """The mean of ``frame`` taken to the working space over ``btf``'s (MaterialX in Storm
        shades in linear Rec.709 too: the OpenPBR maps are srgb_texture)."""
        return float(to_working.apply(frame.astype(np.float32)).mean() / btf.mean())

    samples = {s: decompress(cbtf, DecompressOptions(samples=str(s))).btf.read_samples([0])[0] for s, _ in lights}
    gain, gains, steps = common_gain([(images[(s, "btf_working")], samples[s]) for s, _ in lights])
    lgain, _, _ = common_gain([(images[(s, "legacy_working")], samples[s]) for s, _ in lights])
    rows = [{"sample": s, "light": light, "btf_gain": g, "btf_steps": d,
             "fallback_over_btf": float(images[(s, "fallback")].mean() / images[(s, "btf")].mean()),
             "nearest_over_btf": float(images[(s, "nearest")].mean() / images[(s, "btf")].mean()),
             "aniso1_over_btf": float(images[(s, "aniso1")].mean() / images[(s, "btf")].mean()),
             "aniso1_working_over_btf": working_ratio(images[(s, "aniso1")], images[(s, "btf_working")]),
             "nearest_working_over_btf": float(matched_nearest[s].mean() / images[(s, "btf_working")].mean()),
             "openpbr_over_btf": float(images[(s, "openpbr")].mean() / images[(s, "btf")].mean()),
             "openpbr_aniso1_over_btf": float(images[(s, "openpbr_aniso1")].mean() / images[(s, "btf")].mean()),
             "openpbr_working_over_btf": working_ratio(images[(s, "openpbr")], images[(s, "btf_working")]),
             "openpbr_aniso1_working_over_btf": working_ratio(images[(s, "openpbr_aniso1")], images[(s, "btf_working")]),
             "fallback_over_legacy": float(images[(s, "fallback")].mean() / images[(s, "legacy")].mean()),
             "fallback_working_over_btf": float(matched[s].mean() / images[(s, "btf_working")].mean()),
             "flat_normal_over_btf": float(images[(s, "flat")].mean() / images[(s, "btf")].mean())}
            for (s, light), g, d in zip(lights, gains, steps)]
    model = fit_model_ratios(asset, cbtf, [s for s, _ in lights])
    for row, m, o in zip(rows, model, fit_model_ratios(asset, cbtf, [s for s, _ in lights], "openpbr")):
        row["model_over_btf"], row["openpbr_model_over_btf"] = m, o
    return {"white_level": white, "btf_gain": gain, "legacy_gain": lgain, "convention_gain": capture_irradiance(white),
            "storm_seconds": seconds, "lights": rows}


def main(argv=None) -> int:
    from usdbtf.usd.preview import hydra

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--presets", nargs="+", default=["satin_weave", "pebbles", "velvet"])
    ap.add_argument("--sampling", default="small")
    ap.add_argument("--size", type=int, default=32)
    ap.add_argument("--k", type=int, default=64)
    ap.add_argument("--lights", type=int, default=6)
    ap.add_argument("--usd", nargs="+", default=None, help="USD versions (default: every Storm environment)")
    ap.add_argument("--cycles", action="store_true", help="also Cycles (bpy 5.0.1, .venv-storm-5.0)")
    ap.add_argument("--before", action="store_true", help="also the asset packaged with the fits' brightness step "
                    "off (brightness_step_off), from the same compressed BTF, in the same run")
    args = ap.parse_args(argv)
    pythons = hydra.storm_pythons()
    versions = args.usd or sorted(pythons)
    info = machine_info()
    say(format_machine(info))
    say(f"inputs: synth --sampling {args.sampling} --size {args.size} --seed 5, compress --k {args.k} --codec png, "
        f"package --physical-size 0.05 0.05; {args.lights} pole-view lights, DistantLight irradiance 1")
    out = {"machine": info, "args": vars(args), "results": {}}
    lines = ["| preset | USD | BTF gain vs samples (pi W = 3.1416) | before | BTF steps | Storm UsdPreviewSurface / BTF | "
             "same, maps sampled nearest | HGI_MAX_ANISOTROPY=1, in the working space | nearest, in the working space | Storm OpenPBR / BTF | "
             "before (/ legacy BTF) | in the working space | normal map blocked | fit model / BTF | "
             "Cycles Principled / OSL BTF | Storm checker |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    summary = ["| preset | USD | fits | UsdPreviewSurface as drawn | HGI_MAX_ANISOTROPY=1 | maps sampled nearest | "
               "fit model / BTF | OpenPBR as drawn | OpenPBR, HGI_MAX_ANISOTROPY=1 | OpenPBR fit model / BTF | "
               "OpenPBR, HGI_MAX_ANISOTROPY=1, not in the working space |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    fits = ["after", "before"] if args.before else ["after"]
    with tempfile.TemporaryDirectory(prefix="usdbtf-bench-") as tmp:
        for preset in args.presets:
            for fit in fits:
                asset = build(preset, Path(tmp) / preset, args.sampling, args.size, args.k, before=fit == "before")
                for version in versions:
                    work = Path(tmp) / preset / f"storm{version}_{fit}"
                    work.mkdir()
                    r = measure(asset, pythons[version], work, args.lights)
                    r["checker"] = storm_checker(asset, pythons[version], work)
                    if args.cycles and version == versions[-1]:
                        r["cycles"] = cycles_ratios(asset, [(row["sample"], row["light"]) for row in r["lights"]], work)
                    out["results"][f"{preset} {version} {fit}"] = r

                    def cell(key):
                        values = [row[key] for row in r["lights"]]
                        return f"{np.mean(values):.3f} ({min(values):.3f}-{max(values):.3f})"

                    summary.append(f"| {preset} | {version} | {fit} | {cell('fallback_working_over_btf')} | "
                                   f"{cell('aniso1_working_over_btf')} | {cell('nearest_working_over_btf')} | "
                                   f"{cell('model_over_btf')} | {cell('openpbr_working_over_btf')} | "
                                   f"{cell('openpbr_aniso1_working_over_btf')} | {cell('openpbr_model_over_btf')} | "
                                   f"{cell('openpbr_aniso1_over_btf')} |")
                    ratios = [row["fallback_over_btf"] for row in r["lights"]]
                    before = [row["fallback_over_legacy"] for row in r["lights"]]
                    steps = [row["btf_steps"] for row in r["lights"]]
                    say(f"{preset} USD {version}: BTF gain {r['btf_gain']:.4f} (pi W = {r['convention_gain']:.4f}, "
                        f"{r['btf_gain'] / r['convention_gain']:.4f} of it), before {r['legacy_gain']:.4f}; "
                        f"UsdPreviewSurface/BTF {np.round(ratios, 3).tolist()}, OpenPBR/BTF "
                        f"{np.round([row['openpbr_over_btf'] for row in r['lights']], 3).tolist()}, UsdPreviewSurface sampled "
                        f"nearest / BTF {np.round([row['nearest_over_btf'] for row in r['lights']], 3).tolist()}, anisotropy 1 / BTF {np.round([row['aniso1_over_btf'] for row in r['lights']], 3).tolist()} (in the working space "
                        f"{np.round([row['nearest_working_over_btf'] for row in r['lights']], 3).tolist()}), in the working space "
                        f"{np.round([row['fallback_working_over_btf'] for row in r['lights']], 3).tolist()}, normal map blocked "
                        f"{np.round([row['flat_normal_over_btf'] for row in r['lights']], 3).tolist()}, before {np.round(before, 3).tolist()} "
                        f"({r['storm_seconds']:.1f} s Storm); fit model / BTF "
                        f"{np.round([row['model_over_btf'] for row in r['lights']], 3).tolist()}; Storm checker at one "
                        f"texel a pixel: {r['checker']['min']:.3f}..{r['checker']['max']:.3f}, middle "
                        f"{r['checker']['x1']['middle_min']:.3f}..{r['checker']['x1']['middle_max']:.3f}, at 4 pixels a "
                        f"texel middle {r['checker']['x4']['middle_min']:.3f}..{r['checker']['x4']['middle_max']:.3f} "
                        "(exact: 0..1)"
                        + (f"; Cycles Principled / OSL BTF {np.round(r['cycles'], 3).tolist()}" if "cycles" in r else ""))
                    def span(key):
                        values = [row[key] for row in r["lights"]]
                        return f"{min(values):.3f}-{max(values):.3f}"

                    cyc = f"{min(r['cycles']):.3f}-{max(r['cycles']):.3f}" if "cycles" in r else "-"
                    lines.append(f"| {preset} {fit} | {version} | {r['btf_gain']:.4f} | {r['legacy_gain']:.4f} | "
                                 f"{min(steps):.2f}-{max(steps):.2f} | {span('fallback_over_btf')} | {span('nearest_over_btf')} | {span('aniso1_working_over_btf')} | {span('nearest_working_over_btf')} | {span('openpbr_over_btf')} | "
                                 f"{span('fallback_over_legacy')} | {span('fallback_working_over_btf')} | "
                                 f"{span('flat_normal_over_btf')} | {span('model_over_btf')} | {cyc} | "
                                 f"{r['checker']['x1']['middle_min']:.2f}..{r['checker']['x1']['middle_max']:.2f} "
                                 f"({r['checker']['x4']['middle_min']:.2f}..{r['checker']['x4']['middle_max']:.2f}) |")
    with tempfile.TemporaryDirectory(prefix="usdbtf-bench-") as tmp:
        for version in versions:
            work = Path(tmp) / version
            work.mkdir()
            m = storm_minimal_checker(pythons[version], work)
            out[f"minimal checker {version}"] = m
            say(f"USD {version}: the checker on a hand-authored UsdPreviewSurface quad (no usdbtf), one texel a "
                f"pixel: middle {m['middle_min']:.3f}..{m['middle_max']:.3f} (exact: 0..1)")
    path = OUT / f"storm_photometry_{timestamp()}.json"
    write_json(path, out)
    say(f"\nwrote {path}\n")
    say("\n".join(lines))
    say("\nMean over the lights (min-max), no gain; the Storm fallback frames taken to the working space:\n")
    say("\n".join(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
