"""``usdbtf preview``: the asset's real-time (Storm/MaterialX) shader, run headless on OpenGL.

``--renderer gl`` (the fast check): reads the GPU textures the packaged asset's Storm network
names and draws them with the shared GLSL (Mesa llvmpipe through EGL, no display needed).
``--renderer storm``: the real thing, Hydra Storm through ``UsdAppUtils.FrameRecorder`` in a
storm environment (:mod:`usdbtf.usd.preview.hydra`), on a stage that references the asset with the
same camera and lights (:func:`usdbtf.usd.scenes.scene.write_scene`; the swatch: seen from the pole,
one pixel per texel).  Either writes the image like ``usdbtf render`` does; ``--compare``
also renders the CPU reference and prints the PSNR (linear and sRGB, where both have
geometry).
"""
from __future__ import annotations

import logging
from pathlib import Path

from .render import add_scene_arguments, render_outputs

log = logging.getLogger(__name__)
ORDER = 82
#: USD builds --renderer storm can use (usdbtf.usd.preview.hydra.STORM_ENVIRONMENTS; no heavy import here).
STORM_VERSIONS = ("25.02", "25.08")


def add_parser(sub) -> None:
    p = sub.add_parser("preview", help="headless OpenGL render of a packaged asset's real-time (Storm) shader")
    p.add_argument("asset", type=Path, help="packaged USD asset (.usda; the one `usdbtf package` wrote)")
    add_scene_arguments(p, mesh_help="mesh with texture coordinates (default: the asset's own)")
    p.add_argument("--lod", help="level of detail (a variant of the asset's lod set, e.g. k16)")
    p.add_argument("--renderer", choices=["gl", "storm"], default="gl",
                   help="gl: the shader in the headless harness (default); storm: real Hydra Storm "
                        "(needs a .venv-storm-* environment, scripts/bootstrap.sh)")
    p.add_argument("--usd", choices=sorted(STORM_VERSIONS), help="--renderer storm: which USD build (default: "
                   "the newest installed)")
    p.add_argument("--compare", action="store_true",
                   help="also render with the CPU reference renderer (bilinear, no shadows) and print the PSNR")
    p.add_argument("--no-png", action="store_true", help="write only the EXR")
    p.set_defaults(func=run)


outputs = render_outputs


def _storm_python(version: str | None):
    from ..errors import BTFError
    from ..usd.preview.hydra import STORM_ENVIRONMENTS, storm_pythons

    found = storm_pythons()
    version = version or (max(found) if found else None)
    if version not in found:
        wheels = ", ".join(f"{v}: {w} in {f}" for v, (w, f) in STORM_ENVIRONMENTS.items())
        raise BTFError(f"--renderer storm: no Storm environment{'' if version is None else ' for USD ' + version} "
                       f"(scripts/bootstrap.sh makes them: {wheels})")
    return version, found[version]


def _storm(args, camera, lights, view, light):
    """(H, W, 4) Storm frame of the asset (the swatch from the pole, or the mesh scene)."""
    import tempfile

    from ..errors import BTFError, UsageError
    from ..usd.preview import hydra
    from ..usd.scenes.scene import write_scene

    version, python = _storm_python(args.usd)
    with tempfile.TemporaryDirectory(prefix="usdbtf-storm-") as tmp:
        scene = Path(tmp) / "scene.usda"
        if args.swatch:
            if view[0] != 0.0:
                raise UsageError("--renderer storm draws the swatch from the pole (orthographic): --view 0,0")
            camera_path, size = hydra.swatch_scene(args.asset.resolve(), scene, light, lod=args.lod)
        else:
            camera_path = write_scene(args.asset.resolve(), scene, camera, lights, lod=args.lod)
            size = (camera.width, camera.height)
        frames = hydra.render_frames(python, [(scene, scene.with_suffix(".exr"))], camera_path, size)
    if frames.problems:
        raise BTFError(f"{args.asset}: Storm (USD {version}): {frames.problems[0]}")
    log.info(f"Storm (USD {version}, {python.parent.parent.name})")
    return frames.images[0]


def run(args) -> int:
    import numpy as np

    from ..camera import auto_camera
    from ..errors import UsageError
    from ..gpu.headless import psnr
    from ..render import RenderOptions, Renderer, RenderResult, write_render
    from ..render.output import srgb_encoded
    from ..usd.read import load_btf
    from ..usd.asset.storm import layout_from_asset
    from .render import _angles, check_frame_args, scene_mesh, scene_view

    W, H = args.size
    check_frame_args(args)
    # Every argument and the mesh are checked before the GPU context is made.
    view = light = mesh = camera = lights = None
    if args.swatch:
        if args.mesh is not None or args.camera is not None or len(args.light) != 1:
            raise UsageError("--swatch renders the flat patch: one --light THETA,PHI, no --mesh or --camera")
        view, light = _angles(args.view, "view"), _angles(args.light[0], "light")
    else:
        if args.renderer == "storm" and args.mesh is not None:
            raise UsageError("--renderer storm draws the asset's own mesh: no --mesh")
        camera, lights = scene_view(args)
        mesh = scene_mesh(args.asset, args.mesh)
        if mesh is None:
            raise UsageError(f"{args.asset}: not a USD asset; give --mesh")
        camera = camera or auto_camera(mesh.corner(), W, H)
    layout, wrap, k = layout_from_asset(args.asset, lod=args.lod)
    reference = None
    cbtf = load_btf(args.asset, lod=args.lod)
    cpu = Renderer(cbtf, RenderOptions(k=min(k, cbtf.k), shadows=False, filter="bilinear", wrap=wrap)) \
        if args.compare else None
    if args.renderer == "storm":
        image = _storm(args, camera, lights, view, light)
        image = image[..., :3] if args.swatch else image
    else:
        from ..gpu.headless import HeadlessRenderer

        from ..photometry import white_level_of

        gl = HeadlessRenderer(layout, wrap=wrap, white_level=white_level_of(cbtf.info))
        image = gl.swatch(view, light) if args.swatch else gl.render(mesh, camera, lights)
    if args.swatch:
        if cpu is not None:
            reference = cpu.swatch(view, light)
        what = f"swatch, view {view}, light {light}"
    else:
        if cpu is not None:
            reference = cpu.render(mesh, camera, lights)
        what = f"{camera.width}x{camera.height} frame, {len(lights)} light(s)"
    info = write_render(RenderResult(image, cbtf.working_space, cbtf.ocio_config), args.output,
                        png_path=None if args.no_png else args.output.with_suffix(".png"))
    log.info(f"preview ({args.renderer}, k = {k}) {what} -> {info['exr']}")
    if reference is not None:
        mask = None if args.swatch else (image[..., 3] > 0.999) & (reference[..., 3] > 0.999)
        linear = psnr(np.asarray(image)[..., :3], np.asarray(reference)[..., :3], mask)
        srgb = psnr(srgb_encoded(image[..., :3]), srgb_encoded(reference[..., :3]), mask)
        print(f"PSNR vs CPU renderer: {linear:.2f} dB (linear), {srgb:.2f} dB (sRGB)")
    return 0
