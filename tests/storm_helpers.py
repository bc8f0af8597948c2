"""A Storm frame against ``usdbtf render`` of the same stage (tests of real Storm)."""
from __future__ import annotations

import numpy as np

from usdbtf.cli import main


def against_cpu_render(image, scene, camera: str, size: int, tmp_path) -> tuple[float, np.ndarray, np.ndarray]:
    """(PSNR in dB of the Storm frame ``image`` (H, W, 4) against `usdbtf render SCENE --camera
    PRIM` (no shadows, bilinear), both sRGB-encoded in the working space `usdbtf render` writes
    (the Storm frame taken there from the space the scene's BTF shaders return, issue 40), over
    the pixels where both have full geometry coverage; that mask (H, W) bool; the CPU frame
    (H, W, 4) float64)."""
    from usdbtf.render.output import srgb_encoded
    from usdbtf.gpu.headless import psnr
    from usdbtf.usd.asset.storm import read_rgba, to_rendering_space

    cpu_out = tmp_path / "cpu.exr"
    assert main(["render", str(scene), "--camera", camera, "--size", str(size), str(size), "--no-shadows",
                 "--filter", "bilinear", "-o", str(cpu_out), "--no-png", "-q"]) == 0
    cpu = np.asarray(read_rgba(cpu_out), np.float64)
    image = to_rendering_space(scene, image, back=True).astype(np.float64)
    both = (image[..., 3] > 0.999) & (cpu[..., 3] > 0.999)
    return psnr(srgb_encoded(image[..., :3]), srgb_encoded(cpu[..., :3]), both), both, cpu


def write_lambertian_asset(out, white_level: float = 0.8, grey: float = 0.35, albedo=None, rendering_space=None):
    """Package (``out``, .usda) a flat Lambertian BTF on the "small" sampling, white (albedo 1)
    on the left half of its 16 x 16 texels and ``grey`` on the right, recorded with
    ``white_level`` (a white Lambertian lit head-on reads it): values ``W x albedo x cos``.  Its
    fallback fit is exact (diffuse = albedo, no specular, flat normal), so the BTF and its
    fallback differ only in what each path makes of a value and of a light (usdbtf.photometry).
    ``albedo``: (16, 16, 3) albedos in linear Rec.709 (what a ``UsdPreviewSurface``
    diffuseColor means) instead, taken to the working space (ACEScg) for the BTF's values, so a
    saturated colour tests what each path makes of the working space (issue 40).
    ``rendering_space``: ``PackageOptions.rendering_space`` (default the package default; the
    working space gives the identity rows, what an asset packaged before them renders)."""
    from usdbtf.color import WORKING_SPACE, processor
    from usdbtf.compress import CompressOptions, compress
    from usdbtf.model import ArrayBTF
    from usdbtf.sampling import preset, to_vectors
    from usdbtf.usd.asset import package as pkg

    sampling = preset("small")
    if albedo is None:
        albedo = np.full((16, 16, 3), grey, np.float32)
        albedo[:, :8] = 1.0
    else:
        albedo = processor(REC709, WORKING_SPACE).apply(np.asarray(albedo, np.float32))
    cos_l = np.clip(to_vectors(sampling.light)[:, 2], 0, 1).astype(np.float32)
    btf = ArrayBTF.from_linear(sampling, white_level * albedo[None] * cos_l[:, None, None, None])
    btf.metadata.update(physical_size_m=[0.02, 0.02], white_level=white_level)
    opts = CompressOptions(k=2, codec="exr")
    opts.extra = {"source_metadata": dict(btf.metadata)}
    options = pkg.PackageOptions(thumbnail=False)
    if rendering_space is not None:
        options.rendering_space = rendering_space
    pkg.write_package(pkg.package(compress(btf, opts), options), out)
    return out


#: OCIO's name of linear Rec.709: what UsdPreviewSurface colours and Storm's and Blender's frames mean.
REC709 = "Linear Rec.709 (sRGB)"


def saturated_albedo() -> np.ndarray:
    """(16, 16, 3) linear Rec.709 albedos: four 8 x 8 patches, saturated red, green and blue
    and a white (row-major: red | green over blue | white)."""
    albedo = np.empty((16, 16, 3), np.float32)
    albedo[:8, :8] = (0.8, 0.05, 0.03)
    albedo[:8, 8:] = (0.04, 0.6, 0.05)
    albedo[8:, :8] = (0.03, 0.06, 0.7)
    albedo[8:, 8:] = (0.9, 0.9, 0.9)
    return albedo


PATCHES = {"red": (slice(0, 8), slice(0, 8)), "green": (slice(0, 8), slice(8, 16)),
           "blue": (slice(8, 16), slice(0, 8)), "white": (slice(8, 16), slice(8, 16))}


def patch_means(image) -> dict:
    """{patch: (3,) mean linear RGB} of a 16 x 16 frame of the saturated swatch, the patches'
    borders (one texel, where bilinear filtering mixes neighbours) left out."""
    img = np.asarray(image, np.float64)[..., :3]
    return {name: img[r.start + 1:r.stop - 1, c.start + 1:c.stop - 1].reshape(-1, 3).mean(axis=0)
            for name, (r, c) in PATCHES.items()}


def channel_agreement(pairs, lights) -> tuple[float, float]:
    """(worst |other / BTF - 1|, worst |BTF / (albedo cos / pi) - 1|) over every channel of every
    patch of the saturated swatch (patch_means), ``pairs`` = [(BTF frame, other frame)] under
    irradiance 1 from ``lights`` [(sample, (theta, phi))] in order: no gain anywhere."""
    import math

    albedo = patch_means(saturated_albedo())
    worst_other = worst_btf = 0.0
    for (btf_frame, other_frame), (_, light) in zip(pairs, lights):
        btf, other = patch_means(btf_frame), patch_means(other_frame)
        cos = math.cos(math.radians(light[0]))
        for name in albedo:
            worst_other = max(worst_other, float(np.abs(other[name] / btf[name] - 1).max()))
            worst_btf = max(worst_btf, float(np.abs(btf[name] * math.pi / (albedo[name] * cos) - 1).max()))
    return worst_other, worst_btf


def to_rendering(asset, rgb) -> np.ndarray:
    """(..., 3 or 4) float64 :func:`usdbtf.usd.asset.storm.to_rendering_space`: working-space values
    of ``asset``'s BTF in the space its shaders return (a Storm or Cycles frame's)."""
    from usdbtf.usd.asset.storm import to_rendering_space

    return to_rendering_space(asset, rgb).astype(np.float64)


def pole_lights(cbtf, count: int) -> list[tuple[int, tuple]]:
    """[(sample index, light (theta, phi))]: ``count`` measured lights at the pole view, theta
    15..65 degrees, spread over the list."""
    view0 = np.flatnonzero(np.all(np.abs(cbtf.sampling.view) < 1e-9, axis=1))
    cand = [int(s) for s in view0 if 15.0 <= cbtf.sampling.light[s][0] <= 65.0]
    return [(cand[i], tuple(float(a) for a in cbtf.sampling.light[cand[i]]))
            for i in np.linspace(0, len(cand) - 1, count).round().astype(int)]


def shipped_openpbr_maps(asset):
    """The OpenPBR maps of a packaged ``asset`` as its files hold them and a renderer reads them
    (usd.asset.openpbr.decode_maps of the written PNGs), in the BTF's working space, with its white level."""
    from pathlib import Path

    from usdbtf.imageio import read_image
    from usdbtf.photometry import white_level_of
    from usdbtf.usd.asset.fallback import FALLBACK_DIR
    from usdbtf.usd.asset.openpbr import MAP_FILES, decode_maps
    from usdbtf.usd.read import load_btf

    asset = Path(asset)
    cbtf = load_btf(asset)
    folder = asset.with_name(f"{asset.stem}_textures") / FALLBACK_DIR
    pixels = {name: read_image(folder / MAP_FILES[name][0])[0] for name in MAP_FILES}
    return decode_maps(pixels, cbtf.working_space, ocio_config=cbtf.ocio_config,
                       white_level=white_level_of(cbtf.info)), cbtf


def openpbr_frame(maps, light_deg, out_space: str, ocio_config=None) -> np.ndarray:
    """(H, W, 3) the fit's own model (usdbtf.openpbr.evaluate of ``maps``) at the pole view under
    ``light_deg`` = (theta, phi) with the capture light (irradiance pi W: radiance = the BTF
    value, usdbtf.photometry), in ``out_space`` (a renderer's rendering space)."""
    from usdbtf import openpbr
    from usdbtf.color import processor

    h, w = maps.shape
    value = openpbr.evaluate(maps, np.zeros((1, 2)), np.asarray([light_deg], float))[0].reshape(h, w, 3)
    return processor(maps.working_space, out_space, ocio_config).apply(np.ascontiguousarray(value, np.float32))
