"""``usdbtf preview``: the asset's real-time (Storm/MaterialX) shader, run headless on OpenGL.

Reads the GPU textures the packaged asset's Storm network names, draws them with the
shared GLSL (Mesa llvmpipe through EGL, no display needed) and writes the image like
``usdbtf render`` does; ``--compare`` also renders the CPU reference and prints the PSNR.
"""
from __future__ import annotations

import logging
from pathlib import Path

from .render import add_scene_arguments, render_outputs

log = logging.getLogger(__name__)
ORDER = 82


def add_parser(sub) -> None:
    p = sub.add_parser("preview", help="headless OpenGL render of a packaged asset's real-time (Storm) shader")
    p.add_argument("asset", type=Path, help="packaged USD asset (.usda; the one `usdbtf package` wrote)")
    add_scene_arguments(p, mesh_help="mesh with texture coordinates (default: the asset's own)")
    p.add_argument("--lod", help="level of detail (a variant of the asset's lod set, e.g. k16)")
    p.add_argument("--compare", action="store_true",
                   help="also render with the CPU reference renderer (bilinear, no shadows) and print the PSNR")
    p.add_argument("--no-png", action="store_true", help="write only the EXR")
    p.set_defaults(func=run)


outputs = render_outputs


def run(args) -> int:
    import numpy as np

    from ..camera import auto_camera, parse_camera
    from ..errors import UsageError
    from ..gpu.headless import HeadlessRenderer, psnr
    from ..render import RenderOptions, Renderer, RenderResult, parse_light, write_render
    from ..usd.read import load_btf
    from ..usd.storm import layout_from_asset
    from .render import _angles, check_frame_args, parsed, scene_mesh

    W, H = args.size
    check_frame_args(args)
    # Every argument and the mesh are checked before the GPU context is made.
    if args.swatch:
        if args.mesh is not None or args.camera is not None or len(args.light) != 1:
            raise UsageError("--swatch renders the flat patch: one --light THETA,PHI, no --mesh or --camera")
        view, light = _angles(args.view, "view"), _angles(args.light[0], "light")
    else:
        if not args.light:
            raise UsageError("give at least one --light")
        lights = [parsed(parse_light, spec) for spec in args.light]
        camera = parsed(lambda text: parse_camera(text, W, H), args.camera) if args.camera else None
        mesh = scene_mesh(args.asset, args.mesh)
        if mesh is None:
            raise UsageError(f"{args.asset}: not a USD asset; give --mesh")
        camera = camera or auto_camera(mesh.corner(), W, H)
    layout, wrap, k = layout_from_asset(args.asset, lod=args.lod)
    gl = HeadlessRenderer(layout, wrap=wrap)
    reference = None
    cbtf = load_btf(args.asset, lod=args.lod)
    cpu = Renderer(cbtf, RenderOptions(k=min(k, cbtf.k), shadows=False, filter="bilinear", wrap=wrap)) \
        if args.compare else None
    if args.swatch:
        image = gl.swatch(view, light)
        if cpu is not None:
            reference = cpu.swatch(view, light)
        what = f"swatch, view {view}, light {light}"
    else:
        image = gl.render(mesh, camera, lights)
        if cpu is not None:
            reference = cpu.render(mesh, camera, lights)
        what = f"{W}x{H} frame, {len(lights)} light(s)"
    info = write_render(RenderResult(image, cbtf.working_space, cbtf.ocio_config), args.output,
                        png_path=None if args.no_png else args.output.with_suffix(".png"))
    log.info(f"preview (k = {k}) {what} -> {info['exr']}")
    if reference is not None:
        mask = None if args.swatch else (image[..., 3] > 0) & (reference[..., 3] > 0)
        value = psnr(np.asarray(image)[..., :3], np.asarray(reference)[..., :3], mask)
        print(f"PSNR vs CPU renderer: {value:.2f} dB")
    return 0

