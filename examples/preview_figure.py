"""Headless-GL render of the asset's real-time shader next to the CPU reference (figure of docs/previews.md).

    python examples/preview_figure.py ASSET.usda -o docs/gpu_preview.png

Rows: the flat swatch (view 40,60 / light 50,200) and a UV sphere under a distant and a
point light.  Columns: the shared GLSL on Mesa llvmpipe (EGL), the CPU renderer
(usdbtf.render, bilinear, no shadows), |difference| x 1000.  Titles give the PSNR.
Colours go working space -> sRGB through OCIO (usdbtf.render.to_display).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from pictures import refused
from usdbtf.camera import auto_camera
from usdbtf.gpu.headless import HeadlessRenderer, psnr, uv_sphere
from usdbtf.imageio import write_image
from usdbtf.render import RenderOptions, Renderer, parse_light, to_display
from usdbtf.usd.read import load_btf
from usdbtf.usd.asset.storm import layout_from_asset


def _tile(image: np.ndarray, working_space: str, title: str, size: int) -> np.ndarray:
    rgb = to_display(image[..., :3], working_space)
    tile = cv2.resize(rgb, (size, size), interpolation=cv2.INTER_NEAREST)
    tile = cv2.copyMakeBorder(tile, 22, 4, 4, 4, cv2.BORDER_CONSTANT, value=(255, 255, 255))
    cv2.putText(tile, title, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return tile


def figure(asset: Path, size: int = 256) -> np.ndarray:
    layout, _, _ = layout_from_asset(asset)
    cbtf = load_btf(asset)
    rows = []
    for wrap, what in (("clamp", "swatch"), ("repeat", "sphere")):
        gl = HeadlessRenderer(layout, wrap=wrap)
        cpu = Renderer(cbtf, RenderOptions(shadows=False, filter="bilinear", wrap=wrap))
        if what == "swatch":
            view, light = (40, 60), (50, 200)
            a, b, mask = gl.swatch(view, light), cpu.swatch(view, light), None
        else:
            mesh = uv_sphere(0.05, 64, 32)
            camera = auto_camera(mesh.corner(), size, size)
            lights = [parse_light("dir:-0.5,0.7,1"), parse_light("point:0.12,-0.02,0.1:0.0314")]
            a, b = gl.render(mesh, camera, lights), cpu.render(mesh, camera, lights)
            mask = (a[..., 3] > 0) & (b[..., 3] > 0)
        value = psnr(a[..., :3], b[..., :3], mask)
        diff = np.abs(a[..., :3] - b[..., :3]) * 1000
        rows.append(np.hstack([_tile(a, cbtf.working_space, f"{what}: headless GL (llvmpipe)", size),
                               _tile(b, cbtf.working_space, f"{what}: CPU reference", size),
                               _tile(diff, cbtf.working_space, f"|diff| x1000, PSNR {value:.0f} dB", size)]))
        gl.release()
    return np.vstack(rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("asset", type=Path, help="packaged asset (.usda)")
    p.add_argument("-o", "--output", type=Path, required=True, help="PNG to write")
    args = p.parse_args(argv)
    if (code := refused(args.output, 'preview_figure')) is not None:
        return code
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_image(args.output, figure(args.asset), color_space="sRGB Encoded Rec.709 (sRGB)")
    print(args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
