"""Render one frame of a USD stage in real Hydra Storm, headless: a script, not a module.

Run by the Python of an environment whose ``pxr`` is a full USD build with imaging (the
USD inside PyPI's ``bpy`` wheels: ``scripts/bootstrap.sh`` makes ``.venv-storm-<version>``),
never imported by usdbtf (usd-core has no Hydra)::

    .venv-storm-5.0/bin/python pipeline/usdbtf/gpu/storm_frame.py SCENE.usda OUT.exr [SCENE2 OUT2 ...] \
        --camera /Cam --size 64x64 [--no-camera-light]

It uses only the standard library, ``pxr``, ``moderngl`` (the EGL context) and ``numpy``.
The OpenGL context is moderngl's standalone EGL context (Mesa llvmpipe on a machine
without a GPU); the frame is drawn the way ``usdrecord`` draws it,
``UsdAppUtils.FrameRecorder`` with ``HdStormRendererPlugin``, no colour correction (the
file holds linear values); several frames share one process and context.  USD's own
warnings and shader compile errors go to stderr, which the caller reads
(:mod:`usdbtf.usd.preview.hydra`).  A surfaceless context reports GL
errors when Storm presents the frame; the frame is still written.

Exit status: 0 written, 3 no imaging-capable pxr, 4 no EGL context, 5 nothing written.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from pathlib import Path


def _pxr_from_bpy() -> None:
    """Put the ``pxr`` inside the bpy wheel on sys.path (importing bpy would start Blender)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        return
    root = Path(list(spec.submodule_search_locations)[0])
    # The wheel's usdMtlx looks for MaterialX's libraries where Blender's build machine had
    # them; Blender points it at its own copy when it starts, and so does this (before pxr loads).
    libraries = root / "lib" / "materialx" / "libraries"
    if libraries.is_dir():
        os.environ.setdefault("PXR_MTLX_STDLIB_SEARCH_PATHS", str(libraries))
    for site in sorted(root.glob("*/python/lib/python3*/site-packages")):
        if (site / "pxr").is_dir():
            sys.path.insert(0, str(site))
            return


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("frames", nargs="+", metavar="SCENE OUT",
                        help="pairs of a stage and its image file (.exr keeps linear floats)")
    parser.add_argument("--camera", required=True, help="UsdGeom.Camera prim path")
    parser.add_argument("--size", default="64x64", help="WIDTHxHEIGHT in pixels")
    parser.add_argument("--no-camera-light", action="store_true", help="only the stage's UsdLux lights")
    parser.add_argument("--complexity", type=float, default=1.0)
    args = parser.parse_args(argv)
    width, height = (int(x) for x in args.size.lower().split("x"))
    if len(args.frames) % 2:
        parser.error("give SCENE OUT pairs")

    _pxr_from_bpy()
    try:
        from pxr import Usd, UsdAppUtils, UsdGeom
    except ImportError as exc:
        print(f"storm_frame: no imaging-capable pxr here ({exc})", file=sys.stderr)
        return 3
    try:
        import moderngl

        ctx = moderngl.create_context(standalone=True, backend="egl")
    except Exception as exc:  # moderngl raises plain Exceptions for a missing EGL
        print(f"storm_frame: no EGL OpenGL context ({' '.join(str(exc).split())})", file=sys.stderr)
        return 4
    fbo = ctx.simple_framebuffer((width, height))
    fbo.use()

    from pxr import Tf

    status = 0
    for scene, output in zip(args.frames[::2], args.frames[1::2]):
        print(f"storm_frame: {scene}", file=sys.stderr)      # which frame the messages after it belong to
        status = max(status, _record(Usd, UsdAppUtils, UsdGeom, Tf, scene, output, args, width))
    return status


def _record(Usd, UsdAppUtils, UsdGeom, Tf, scene: str, output: str, args, width: int) -> int:
    """One frame of ``scene`` into ``output``; 0 written, 5 not."""
    stage = Usd.Stage.Open(scene)
    camera = UsdGeom.Camera.Get(stage, args.camera) if stage else None
    if not camera:
        print(f"storm_frame: {scene}: no UsdGeom.Camera at {args.camera}", file=sys.stderr)
        return 5
    recorder = UsdAppUtils.FrameRecorder("HdStormRendererPlugin", True)
    recorder.SetImageWidth(width)
    recorder.SetComplexity(args.complexity)
    recorder.SetColorCorrectionMode("disabled")
    recorder.SetCameraLightEnabled(not args.no_camera_light)
    recorder.SetIncludedPurposes([UsdGeom.Tokens.default_, UsdGeom.Tokens.render])
    try:
        recorder.Record(stage, camera, Usd.TimeCode.Default(), output)
    except Tf.ErrorException as exc:
        # 25.08 raises the GL errors a surfaceless context reports when the frame is
        # presented (after it is written); they are on stderr for the caller to judge.
        errors = [e.strip() for e in str(exc).split("Error in") if e.strip()]
        print(f"storm_frame: Record raised {len(errors)} errors, the first: {' '.join(errors[0].split())[:300]}"
              if errors else "storm_frame: Record raised", file=sys.stderr)
    sys.stderr.flush()
    if not Path(output).is_file():
        print(f"storm_frame: {output}: Storm wrote no frame", file=sys.stderr)
        return 5
    return 0


if __name__ == "__main__":
    sys.exit(main())
