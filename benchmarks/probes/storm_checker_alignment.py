#!/usr/bin/env python
"""Why Storm (llvmpipe) reads a black/white checker as ~0.5 at one texel a pixel (issue 40 (b)).

A hand-authored unit quad, UsdPreviewSurface <- UsdUVTexture (sRGB PNG n x n black/white
checker) <- st, orthographic camera over the quad, one DistantLight of irradiance pi from the
pole (a white texel reads 1).  Variants, one Storm process per USD version:

default    the UsdUVTexture as authored (Sdr defaults: minFilter linearMipmapLinear, magFilter linear)
linear     minFilter "linear", magFilter "linear" (no mipmaps: a mip level > 0 cannot be the cause)
nearest    minFilter and magFilter "nearest"
half       default filters, camera moved half a texel in x and y (pixel centres on texel corners
           if they were on texel centres, and the other way round)
x2         default filters, two pixels a texel
ramp       a 16-bit raw ramp (R = column, G = row): the texel coordinate each pixel sampled, which a
           shift of the camera or the quad would move (a symmetric blur leaves a ramp as it is)
env        the default checker with ``HGI_MAX_ANISOTROPY=1`` and/or ``HDX_MSAA_SAMPLE_COUNT=1``

Printed per variant: min..max over the frame's middle half (exact: 0..1) and the middle row's
first 8 pixels.  Usage: ``.venv/bin/python benchmarks/probes/storm_checker_alignment.py``.
"""
from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from common import format_machine, machine_info  # noqa: E402


def ramp_png(path: Path, n: int) -> None:
    """16-bit PNG, raw values: R = column / (n - 1), G = row from the bottom / (n - 1) (v up)."""
    import OpenImageIO as oiio

    i = np.arange(n) / (n - 1)
    rgb = np.zeros((n, n, 3), np.float32)
    rgb[..., 0] = i[None, :]
    rgb[..., 1] = i[::-1, None]                      # image row 0 is the top: v = 1
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(n, n, 3, "uint16"))
    out.write_image(rgb)
    out.close()


def quad(folder: Path, n: int, filters=None, shift: float = 0.0, texture: str = "checker") -> Path:
    """Write the quad's stage in ``folder`` (module docstring; ``bench_storm_photometry``'s
    hand-made checker too): ``filters`` = (minFilter, magFilter) or None (as authored), the camera
    moved ``shift`` texels in x and y, ``texture`` "checker" (sRGB) or "ramp" (raw)."""
    import OpenImageIO as oiio
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade

    from usdbtf.usd.scenes.scene import add_distant

    png = folder / "checker.png"
    if not png.exists():
        pixels = np.where((np.add.outer(np.arange(n), np.arange(n)) % 2 == 0)[..., None], 255, 0).astype(np.uint8)
        out = oiio.ImageOutput.create(str(png))
        out.open(str(png), oiio.ImageSpec(n, n, 3, "uint8"))
        out.write_image(np.repeat(pixels, 3, axis=2))
        out.close()
    if texture == "ramp" and not (folder / "ramp.png").exists():
        ramp_png(folder / "ramp.png", n)
    name = f"quad_{texture}_{'_'.join(filters or ('default',))}_{shift:g}.usda"
    path = folder / name
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Quad")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    mesh.CreateExtentAttr([(0, 0, 0), (1, 1, 0)])
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (1, 0), (1, 1), (0, 1)])
    material = UsdShade.Material.Define(stage, "/World/Mat")
    reader = UsdShade.Shader.Define(stage, "/World/Mat/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, "/World/Mat/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(f"./{texture}.png")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB" if texture == "checker" else "raw")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    if filters:
        tex.CreateInput("minFilter", Sdf.ValueTypeNames.Token).Set(filters[0])
        tex.CreateInput("magFilter", Sdf.ValueTypeNames.Token).Set(filters[1])
    tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface = UsdShade.Shader.Define(stage, "/World/Mat/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    surface.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
    surface.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0, 0, 0))
    surface.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    camera = UsdGeom.Camera.Define(stage, "/World/Camera")
    camera.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    camera.CreateHorizontalApertureAttr(10.0)
    camera.CreateVerticalApertureAttr(10.0)
    camera.CreateClippingRangeAttr(Gf.Vec2f(0.5, 2.0))
    d = shift / n
    camera.AddTranslateOp().Set(Gf.Vec3d(0.5 + d, 0.5 + d, 1.0))
    add_distant(stage, "/World/Sun", (0.0, 0.0, 1.0), math.pi)
    stage.GetRootLayer().Save()
    return path


def main() -> int:
    from usdbtf.usd.preview import hydra

    n = 32
    say = print
    say(format_machine(machine_info()))
    variants = [("default", None, 0.0, 1), ("linear", ("linear", "linear"), 0.0, 1),
                ("nearest", ("nearest", "nearest"), 0.0, 1), ("half", None, 0.5, 1), ("x2", None, 0.0, 2),
                ]
    for version, python in sorted(hydra.storm_pythons().items()):
        with tempfile.TemporaryDirectory(prefix="usdbtf-checker-") as tmp:
            folder = Path(tmp)
            for label, filters, shift, mag in variants:
                path = quad(folder, n, filters, shift)
                frame = hydra.render_frames(python, [(path, path.with_suffix(".exr"))], "/World/Camera",
                                            (n * mag, n * mag)).images[0][..., 0]
                m = frame.shape[0]
                middle = frame[m // 4:3 * m // 4, m // 4:3 * m // 4]
                row = frame[m // 2, m // 4:m // 4 + 8]
                say(f"USD {version} {label:12s} checker {frame.shape[1]}x{frame.shape[0]}: middle {middle.min():.3f}.."
                    f"{middle.max():.3f} mean {middle.mean():.3f}; middle row {np.round(row, 3).tolist()}")
                if mag != 1:
                    continue
                # The ramp: the texel coordinate each pixel sampled, against its pixel centre's.
                path = quad(folder, n, filters, shift, "ramp")
                img = hydra.render_frames(python, [(path, path.with_suffix(".exr"))], "/World/Camera",
                                          (n, n)).images[0]
                centre = np.arange(n) + shift                # pixel centres in texel units, from the texel centres
                du = img[..., 0] * (n - 1) - centre[None, :]
                dv = img[::-1, :, 1] * (n - 1) - centre[:, None]
                inner = (slice(2, n - 2), slice(2, n - 2))   # away from the clamped edges
                say(f"USD {version} {label:12s} ramp: sampled - pixel centre, texels: u {du[inner].mean():+.4f} "
                    f"({du[inner].min():+.4f}..{du[inner].max():+.4f}), v {dv[inner].mean():+.4f} "
                    f"({dv[inner].min():+.4f}..{dv[inner].max():+.4f})")
        # The same default checker with Storm's sampling settings changed through its environment.
        with tempfile.TemporaryDirectory(prefix="usdbtf-checker-") as tmp:
            path = quad(Path(tmp), n)
            for extra in ({"HGI_MAX_ANISOTROPY": "1"}, {"HDX_MSAA_SAMPLE_COUNT": "1"},
                          {"HDX_MSAA_SAMPLE_COUNT": "1", "HGI_MAX_ANISOTROPY": "1"}):
                env = dict(hydra.storm_environment(), **extra)
                frame = hydra.render_frames(python, [(path, path.with_suffix(".exr"))], "/World/Camera",
                                            (n, n), env=env).images[0][..., 0]
                middle = frame[n // 4:3 * n // 4, n // 4:3 * n // 4]
                say(f"USD {version} default checker with {extra}: middle {middle.min():.3f}..{middle.max():.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
