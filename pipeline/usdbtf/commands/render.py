"""``usdbtf render``: CPU reference renderer (a mesh under point/distant lights, or the flat swatch)."""
from __future__ import annotations

import logging
from pathlib import Path

from ..argtypes import MAX_FRAME_SIDE, WORKERS, int_in

log = logging.getLogger(__name__)
ORDER = 80
#: Arguments that name outputs (every other path argument is an input).
OUTPUT_ARGS = ("output", "png")
#: ``--size``'s default (a scene's camera otherwise takes the scene's UsdRender.Settings width).
DEFAULT_SIZE = (512, 512)
#: Bytes per frame pixel the renderer holds (RGBA float, depth, triangle ids, barycentrics,
#: interpolated frames and directions, shadow-map lookups).
BYTES_PER_PIXEL = 160


def add_scene_arguments(p, *, mesh_help: str) -> None:
    """Output, mesh/swatch, view, lights, camera and frame size: shared with ``usdbtf preview``."""
    p.add_argument("-o", "--output", required=True, type=Path, help="output .exr (working colour space)")
    p.add_argument("--mesh", type=Path, help=mesh_help)
    p.add_argument("--swatch", action="store_true", help="the flat patch, orthographic, one pixel per texel")
    p.add_argument("--view", metavar="THETA,PHI", help="swatch: view direction in degrees")
    p.add_argument("--light", action="append", default=[], metavar="SPEC",
                   help="swatch: THETA,PHI degrees (distant light); mesh: point:X,Y,Z[:I] or dir:X,Y,Z[:I] "
                        "(repeatable; I = irradiance, default pi: radiance = value x I / (pi W), so pi W is "
                        "the capture light; point lights I/d^2)")
    p.add_argument("--camera", metavar="SPEC", help='"eye=X,Y,Z target=X,Y,Z [up=X,Y,Z] [fov=DEG]" '
                   "(default: frame the mesh), or the prim path of a UsdGeom.Camera of a USD scene (/World/Cam): "
                   "then the scene's UsdLux lights light it too, and the frame's height follows the apertures")
    p.add_argument("--size", type=int_in(1, MAX_FRAME_SIDE), nargs=2, default=DEFAULT_SIZE, metavar=("W", "H"),
                   help=f"frame size, 1..{MAX_FRAME_SIDE} each (default 512 512; a scene's camera: the width of "
                   "its UsdRender.Settings resolution, the height from the camera's apertures)")


def add_parser(sub) -> None:
    p = sub.add_parser("render", help="CPU reference render of a BTF on a mesh, or the flat measured swatch")
    p.add_argument("asset", type=Path, help="compressed BTF folder, packaged USD asset, or a USD scene (with "
                   "several BTF materials: each bound mesh with its own)")
    add_scene_arguments(p, mesh_help="`usdbtf unwrap` layer or a mesh with texture coordinates")
    p.add_argument("--k", type=int_in(1), help="use only the first k basis vectors")
    p.add_argument("--no-shadows", action="store_true", help="no cast shadows")
    p.add_argument("--filter", choices=["mip", "bilinear"], default="mip", help="coefficient filtering (default mip)")
    p.add_argument("--wrap", choices=["repeat", "clamp"], help="texture wrap (default: repeat for a tileable quilt)")
    p.add_argument("--png", type=Path, help="sRGB PNG path (default: the output with .png)")
    p.add_argument("--no-png", action="store_true", help="write only the EXR")
    p.add_argument("--display", help="OCIO display for the PNG (default: the config's default)")
    p.add_argument("--display-view", help="OCIO view for the PNG (default: Un-tone-mapped)")
    p.add_argument("--threads", type=WORKERS, default=2, help="shading threads (default 2)")
    p.add_argument("--frames", metavar="A:B", help="a USD scene with --camera /PRIM: render its whole frames A..B "
                   "(inclusive), each mesh with its bound BTF material, as the sequence the output names with a "
                   "run of # (out.####.exr -> out.0001.exr ...; PNGs beside them)")
    p.set_defaults(func=run)


def render_outputs(args):
    """The EXR and (unless --no-png) the PNG a render or preview writes (one pair per frame of
    ``--frames``)."""
    from ..outputs import RENDER

    frames = getattr(args, "frames", None)
    if frames:
        from ..usd.scenes.shots import frame_path, parse_frames

        exrs = [frame_path(args.output, f) for f in parse_frames(frames)]
        if args.png is not None:
            from ..errors import UsageError

            raise UsageError("--png names one file; with --frames the PNGs are the EXRs' names with .png")
        return [(p, RENDER) for exr in exrs for p in [exr] + ([] if args.no_png else [exr.with_suffix(".png")])]
    png = None if args.no_png else (getattr(args, "png", None) or args.output.with_suffix(".png"))
    return [(args.output, RENDER)] + ([(png, RENDER)] if png is not None else [])


outputs = render_outputs


def _angles(text: str | None, what: str):
    import math

    from ..errors import UsageError

    try:
        theta, phi = (float(x) for x in (text or "").split(","))
    except ValueError:
        raise UsageError(f"--{what} must be THETA,PHI in degrees, got {text!r}") from None
    if not (math.isfinite(theta) and math.isfinite(phi) and 0 <= theta <= 90 and abs(phi) <= 360):
        raise UsageError(f"--{what}: theta must be in [0, 90] and phi in [-360, 360] degrees, got {text}")
    return theta, phi


def open_asset(asset: Path, *, lazy: bool = False):
    """The compressed BTF of ASSET: a ``btf-compressed/1`` folder (an original or a quilt) or a
    packaged USD asset (.usda/.usdc/.usd/.usdz, read back through :func:`usdbtf.io.open_compressed`)."""
    from ..compress.format import METADATA
    from ..errors import BTFError
    from ..io import open_compressed
    from ..usdstage import usd_exists

    # A USD asset is found through the asset resolver (a search-path-relative name works).
    if (asset.is_dir() and (asset / METADATA).is_file()) or usd_exists(asset):
        return open_compressed(asset, lazy=lazy)
    raise BTFError(f"{asset}: not a compressed BTF folder (no {METADATA}) or a USD asset")


def scene_mesh(asset: Path, mesh: Path | None):
    """The mesh to render: ``--mesh`` (an unwrap layer, whose stored frames are used, or any mesh
    file with texture coordinates), else a USD asset's own Mesh; None for a folder without --mesh."""
    from ..mesh import load_mesh
    from ..usdstage import USD_SUFFIXES

    if mesh is None and asset.suffix.lower() not in USD_SUFFIXES:
        return None
    return load_mesh(mesh if mesh is not None else asset, need_uv=True)


def scene_parts(asset: Path, mesh: Path | None):
    """[(cbtf, mesh)] of a USD scene that binds more than one BTF material to its meshes (each
    mesh is rendered with its own material: :func:`usdbtf.render.render_scene`); None otherwise
    (``--mesh`` given, a compressed folder, or one material: the asset is rendered as before)."""
    from ..usdstage import USD_SUFFIXES

    if mesh is not None or asset.suffix.lower() not in USD_SUFFIXES:
        return None
    from ..usd.read import open_stage
    from ..usd.scenes.scene import bound_btf_meshes

    # Lazily: the renderer reads the pages of the mip levels a frame samples (issue 39).
    parts = bound_btf_meshes(open_stage(asset), lazy=True)
    return parts if len({id(cbtf) for cbtf, _ in parts}) > 1 else None


def check_frame_args(args) -> None:
    """Checks shared with ``usdbtf preview``: the output name and the frame's memory."""
    from ..errors import UsageError
    from ..resources import require_memory

    if args.output.suffix.lower() != ".exr":
        raise UsageError(f"{args.output}: the render is written as OpenEXR; name it *.exr")
    W, H = args.size
    require_memory(float(W) * H * BYTES_PER_PIXEL, f"a {W}x{H} frame", error=UsageError)


def scene_view(args):
    """(camera, lights) for a mesh frame: ``--camera`` as a spec, or as the prim path of a
    UsdGeom.Camera of the USD scene ``args.asset`` (whose UsdLux lights join ``--light``'s),
    else the mesh framed automatically (camera None)."""
    from ..camera import parse_camera
    from ..errors import UsageError
    from ..render import parse_light
    from ..usdstage import USD_SUFFIXES

    W, H = args.size
    lights = [parsed(parse_light, spec) for spec in args.light]
    camera = None
    if args.camera and args.camera.startswith("/"):
        if args.asset.suffix.lower() not in USD_SUFFIXES:
            raise UsageError(f"--camera {args.camera}: a camera prim needs a USD scene as the input")
        from ..usd.scenes.scene import read_scene

        camera, scene_lights = read_scene(args.asset, args.camera, W)
        lights += scene_lights
    elif args.camera:
        camera = parsed(lambda text: parse_camera(text, W, H), args.camera)
    if not lights:
        raise UsageError("give at least one --light point:X,Y,Z[:I] or dir:X,Y,Z[:I] (or a scene with UsdLux lights)")
    return camera, lights


def parsed(parse, text):
    """A --light/--camera value parsed, its errors as usage errors (exit status 2)."""
    from ..errors import BTFError, UsageError

    try:
        return parse(text)
    except UsageError:
        raise
    except BTFError as exc:
        raise UsageError(str(exc)) from None


def _render_scene(args, opts, t0: float) -> int:
    """A USD scene's own shots: each rendered mesh with its bound BTF material, the scene's
    camera ``--camera`` and UsdLux lights (plus ``--light``), for each frame of ``--frames``."""
    import time
    from dataclasses import replace

    import numpy as np

    from ..color import WORKING_SPACE
    from ..errors import BTFError, UsageError
    from ..render import Renderer, RenderResult, parse_light, render_parts, write_render
    from ..usd.scenes.shots import check_pattern, frame_path, parse_frames, scene_shots
    from ..resources import require_memory
    from ..usdstage import USD_SUFFIXES

    if args.asset.suffix.lower() not in USD_SUFFIXES:
        raise UsageError(f"--camera {args.camera}: a camera prim needs a USD scene as the input")
    frames = parse_frames(args.frames) if args.frames else None
    check_pattern(args.output, frames)
    extra = [parsed(parse_light, spec) for spec in args.light]
    width = None if args.size is DEFAULT_SIZE else args.size[0]
    materials, shots = scene_shots(args.asset, args.camera, width, frames, lazy=True)
    spaces = {(c.working_space, c.ocio_config) for c in materials.values()}
    if len(spaces) > 1:
        raise BTFError(f"{args.asset}: its BTF materials are in different working spaces ({sorted(spaces)}); "
                       "render them apart")
    space, config = spaces.pop() if spaces else (None, None)
    renderers = {m: Renderer(c, replace(opts)) for m, c in materials.items()}
    for shot in shots:
        lights = shot.lights + extra
        if not lights:
            raise UsageError(f"{args.asset}: no UsdLux light at frame {shot.time}; add --light")
        camera = shot.camera
        require_memory(float(camera.width) * camera.height * BYTES_PER_PIXEL, f"a {camera.width}x{camera.height} "
                       "frame", error=UsageError)
        image = (render_parts([(renderers[m], mesh) for m, mesh in shot.parts], camera, lights) if shot.parts
                 else np.zeros((camera.height, camera.width, 4), np.float32))
        exr = frame_path(args.output, None if shot.time is None else int(shot.time))
        png = None if args.no_png else (args.png if args.png and frames is None else exr.with_suffix(".png"))
        write_render(RenderResult(image, space or WORKING_SPACE, config), exr, png_path=png, display=args.display,
                     view=args.display_view)
        log.info(f"frame {shot.time if shot.time is not None else '(default time)'}: {camera.width}x{camera.height}, "
                 f"{len(shot.parts)} mesh(es), {len(lights)} light(s) -> {exr}")
    log.info(f"rendered {len(shots)} frame(s) of {args.camera} ({len(materials)} BTF material(s)) in "
             f"{time.perf_counter() - t0:.2f} s")
    return 0


def run(args) -> int:
    import time

    from ..camera import auto_camera
    from ..errors import UsageError
    from ..render import RenderOptions, render, render_scene, render_swatch, write_render

    t0 = time.perf_counter()
    W, H = args.size
    check_frame_args(args)
    opts = RenderOptions(k=args.k, shadows=not args.no_shadows, filter=args.filter, wrap=args.wrap,
                         threads=args.threads)
    # Every argument is checked before any file is read.
    if args.swatch:
        if args.mesh is not None or args.camera is not None:
            raise UsageError("--swatch renders the flat patch: it takes no --mesh or --camera")
        if len(args.light) != 1:
            raise UsageError("--swatch needs exactly one --light THETA,PHI")
        view, light = _angles(args.view, "view"), _angles(args.light[0], "light")
        cbtf = open_asset(args.asset, lazy=True)
        result = render_swatch(cbtf, view, light, opts)
        what = f"swatch {cbtf.width}x{cbtf.height}, view {view}, light {light}"
    else:
        if args.view is not None:
            raise UsageError("--view is for --swatch; place the camera with --camera")
        scene_camera = bool(args.camera and args.camera.startswith("/"))
        if args.frames is not None and not (scene_camera and args.mesh is None):
            raise UsageError("--frames renders a USD scene's own camera: give the scene and --camera /PRIM "
                             "(and no --mesh)")
        if scene_camera and args.mesh is None:
            return _render_scene(args, opts, t0)
        camera, lights = scene_view(args)
        parts = scene_parts(args.asset, args.mesh)
        if parts is not None:           # a scene: every bound mesh with its own material
            import numpy as np

            camera = camera or auto_camera(np.concatenate([m.corner() for _, m in parts]), W, H)
            result = render_scene(parts, camera, lights, opts)
            triangles = sum(len(m.triangles) for _, m in parts)
            materials = len({id(cbtf) for cbtf, _ in parts})
            what = (f"{camera.width}x{camera.height} frame, {len(parts)} meshes with {materials} BTF materials, "
                    f"{triangles} triangles, {len(lights)} light(s)")
        else:
            cbtf = open_asset(args.asset, lazy=True)
            mesh = scene_mesh(args.asset, args.mesh)
            if mesh is None:
                raise UsageError("give --mesh (an unwrap layer or a mesh with texture coordinates), or --swatch")
            for note in mesh.notes:
                log.info(f"{mesh.source}: {note}")
            camera = camera or auto_camera(mesh.corner(), W, H)
            result = render(cbtf, mesh, camera, lights, opts)
            what = f"{camera.width}x{camera.height} frame, {len(mesh.triangles)} triangles, {len(lights)} light(s)"
    png = None if args.no_png else (args.png or args.output.with_suffix(".png"))
    info = write_render(result, args.output, png_path=png, display=args.display, view=args.display_view)
    log.info(f"rendered {what} in {time.perf_counter() - t0:.2f} s -> {info['exr']}"
        + (f" and {info['png']} ({info['display']} / {info['view']})" if info["png"] else ""))
    return 0
