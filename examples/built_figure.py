"""What a user gets from ``usdbtf build``, drawn by a real renderer (the docs' Storm and Cycles pictures).

    .venv/bin/python examples/built_figure.py --renderer storm  -o docs/storm_preview.png
    .venv/bin/python examples/built_figure.py --renderer cycles -o docs/cycles_preview.png

Each run makes a small scene as a user would bring it (``scene.usda``, metres, Y up): a torus
knot 20 cm across (``examples/shapes.py``) with its own UVs on the [0, 1] square (the tube's
length and girth, stretched), bound to a BtfMaterialAPI material whose ``btf:build:*`` recipe
names a capture (``usdbtf synth pebbles``: 64 x 64 texels over 5 cm, the ``small`` directions)
and ``--k 16``; a camera ``/World/Cam`` and one ``UsdLux.DistantLight`` ``/World/Sun`` of the
capture light's irradiance (pi x white: :mod:`usdbtf.photometry`).  Then it runs ``usdbtf build
scene.usda --json`` as a user would (the scene-shaped build) and renders the stage that build
reports (``built_scene``: the knot quilted at the material's measured 1280 texels/m) from
``/World/Cam``:

storm   Hydra Storm from a bpy wheel's USD (``--usd`` 25.08 or 25.02), headless EGL, the stage's
        own DistantLight (:func:`usdbtf.usd.preview.hydra.render_frames`);
cycles  Blender 5.0.1's Cycles (CPU, OSL) through the usdbtf add-on, which imports the built
        stage with Blender's USD importer; the add-on's sun has the DistantLight's direction and
        irradiance (:func:`usdbtf.usd.preview.cycles.render_frames`; its OSL BTF answers one sun).

The frame (over grey) gets a legend: renderer and USD version, material, size, the texel density
measured on the built mesh (:func:`usdbtf.usd.density.binding_densities`) and the light.  A first
run took 4 minutes on the shared two-core machine (about 1.5 min of CPU: compress, package, unwrap,
quilt, package the 670 x 670 quilt); ``--workdir DIR`` keeps the scene and its build, so the other
renderer reuses it (SCons runs nothing when nothing changed) and takes about 40 s.  The build's
files and the picture are the same bytes on a rebuild from scratch.  Needs the bpy environments of
``scripts/bootstrap.sh``.

The output must be a ``.png`` path that is absent or already a PNG picture; anything else is
refused (exit 73, ``examples/pictures.py``), as is a ``--workdir`` that is neither empty nor one
this script made.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from pictures import PNG_SIGNATURE, REFUSED, picture_refusal  # noqa: E402,F401
from shapes import torus_knot  # noqa: E402

#: The file that marks a --workdir as this script's (so a second run may reuse it).
MARKER = "built_figure.json"
#: The capture: usdbtf synth PRESET --size SIZE --physical-size METRES --sampling small --seed 1.
PRESET, TEXELS, METRES, SAMPLING, K = "pebbles", 64, 0.05, "small", 16
#: The knot: examples/shapes.py's (2, 3) torus knot at its own size (20 cm across), coarser.
SEGMENTS, SIDES = 240, 20
CAMERA = "eye=0.0,0.21,0.25 target=0.0,-0.01,0.0 fov=40"
#: Towards the DistantLight (Y up); its irradiance is the capture light's, pi (white level 1).
SUN = (0.4, 1.0, 0.6)
IRRADIANCE = math.pi
BACKGROUND = 0.18           # linear grey under the frame's alpha
USAGE = 2


def fail(message: str, code: int) -> int:
    print(f"built_figure: error: {message}", file=sys.stderr)
    return code


def workdir_refusal(path: Path) -> str | None:
    if path.exists() and (not path.is_dir() or (any(path.iterdir()) and not (path / MARKER).is_file())):
        return f"{path}: --workdir exists and was not made by this script; refusing to use it"
    return None


def knot_with_uvs():
    """(points (V, 3) m, triangles (F, 3), st (F, 3, 2)): the knot tube with the UVs a user's
    modelling tool would give it: length along u, girth along v, both on [0, 1] (faceVarying,
    so the two seams wrap without sharing vertices)."""
    points, faces, _ = torus_knot(segments=SEGMENTS, sides=SIDES)
    ring, around = faces // SIDES, faces % SIDES
    for index, count in ((ring, SEGMENTS), (around, SIDES)):
        # A face across the wrap has corners at 0 and count - 1: its 0s are at count.
        index[(index == 0) & (index.max(axis=1, keepdims=True) == count - 1)] = count
    st = np.stack([ring / SEGMENTS, around / SIDES], axis=-1)
    return points, faces, st


def scene_text(width: int, height: int) -> str:
    """The user's scene.usda (its text; the capture and the build's asset are beside it)."""
    from usdbtf.usdstage import usd_warnings_silenced

    with usd_warnings_silenced():       # the material's asset is what the build makes
        return _scene_text(width, height)


def _scene_text(width: int, height: int) -> str:
    from pxr import Sdf, Usd, UsdGeom, UsdShade, Vt

    from usdbtf.camera import parse_camera
    from usdbtf.usd.scenes.scene import add_camera, add_distant

    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    add_camera(stage, "/World/Cam", {None: parse_camera(CAMERA, width, height)})
    add_distant(stage, "/World/Sun", SUN, IRRADIANCE)
    material = UsdShade.Material.Define(stage, "/World/Looks/Pebbles")
    prim = material.GetPrim()
    prim.AddAppliedSchema("BtfMaterialAPI")
    prim.GetReferences().AddReference("./build/Pebbles.usda", Sdf.Path("/Pebbles/mtl/BtfMaterial"))
    prim.CreateAttribute("btf:build:source", Sdf.ValueTypeNames.Asset).Set("./captures/pebbles")
    prim.CreateAttribute("btf:build:options", Sdf.ValueTypeNames.String).Set(f"--k {K}")
    prim.CreateAttribute("btf:build:asset", Sdf.ValueTypeNames.Asset).Set("./build/Pebbles.usda")
    points, faces, st = knot_with_uvs()
    knot = UsdGeom.Mesh.Define(stage, "/World/Knot")
    knot.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, np.float32)))
    knot.CreateFaceVertexCountsAttr([3] * len(faces))
    knot.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces.ravel(), np.int32)))
    knot.CreateSubdivisionSchemeAttr("none")
    UsdGeom.PrimvarsAPI(knot).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying).Set(
        Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(st.reshape(-1, 2), np.float32)))
    UsdShade.MaterialBindingAPI.Apply(knot.GetPrim()).Bind(material)
    return stage.GetRootLayer().ExportToString()


def make_scene(work: Path, width: int, height: int) -> Path:
    """Write the capture (once) and scene.usda (only when its text changes, so a rebuild of an
    unchanged scene runs nothing).  Returns the scene's path."""
    from usdbtf.cli import main as usdbtf_main

    (work / MARKER).write_text(json.dumps({"made_by": "examples/built_figure.py"}) + "\n")
    capture = work / "captures" / PRESET
    if not capture.exists():
        if usdbtf_main(["synth", PRESET, "-o", str(capture), "--sampling", SAMPLING, "--size", str(TEXELS),
                        "--physical-size", str(METRES), "--seed", "1", "-q"]) != 0:
            raise SystemExit("built_figure: usdbtf synth failed")
    scene, text = work / "scene.usda", scene_text(width, height)
    if not scene.is_file() or scene.read_text() != text:
        scene.write_text(text)
    return scene


def run_build(scene: Path) -> tuple[Path, Path]:
    """``usdbtf build SCENE --json`` in its own process, as a user runs it.  Returns (the built
    stage, the asset the build made for the knot's binding)."""
    proc = subprocess.run([sys.executable, "-m", "usdbtf.cli", "build", str(scene), "--json", "-q"],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"built_figure: usdbtf build failed (exit {proc.returncode}): {proc.stderr.strip()}")
    report = json.loads(proc.stdout)
    knot = [b["asset"] for b in report["bindings"] if "/World/Knot" in b["prims"]]
    return Path(report["built_scene"]), Path(knot[0])


def measured_density(built: Path) -> dict:
    """The knot's binding in the built stage: texels per metre on the mesh and the material's."""
    from usdbtf.usd.density import binding_densities
    from usdbtf.usdstage import open_usd

    entries = [e for e in binding_densities(open_usd(built)) if e["prim"] == "/World/Knot"]
    if not entries or entries[0]["mesh_texels_per_metre"] is None:
        raise SystemExit(f"built_figure: {built}: /World/Knot has no measurable texel density")
    return entries[0]


def render_storm(built: Path, out: Path, size: tuple[int, int], usd: str) -> tuple[np.ndarray, str]:
    from usdbtf.usd.preview import cycles, hydra

    pythons = hydra.storm_pythons()
    if usd not in pythons:
        raise SystemExit(f"built_figure: no Storm environment for USD {usd}: run scripts/bootstrap.sh")
    frames = hydra.render_frames(pythons[usd], [(built, out)], "/World/Cam", size)
    if frames.problems:
        raise SystemExit("built_figure: Storm: " + " | ".join(frames.problems))
    wheel = {"25.08": cycles.BLENDER_VERSION, "25.02": "4.5.15"}[usd]
    return frames.images[0], f"Hydra Storm, USD {usd} (bpy {wheel} wheel), headless EGL"


def render_cycles(asset: Path, out: Path, size: tuple[int, int]) -> tuple[np.ndarray, str]:
    """Cycles through the add-on, which imports one usdbtf asset: the one ``build`` made for the
    knot's binding, the material and quilted mesh the built stage binds (same mesh, same place:
    the knot has no transform).  (It does not import a built stage: it takes the first usdbtf
    material it meets, there the user's swatch, and the stage has no lod variant set on its
    default prim.)  The add-on's sun has the stage's DistantLight's direction and irradiance."""
    from usdbtf.camera import parse_camera
    from usdbtf.usd.preview import cycles

    python = cycles.cycles_python()
    if python is None:
        raise SystemExit("built_figure: no bpy 5.0.1 environment (.venv-storm-5.0): run scripts/bootstrap.sh")
    sun = tuple(np.asarray(SUN) / np.linalg.norm(SUN))
    frame = cycles.CyclesFrame(asset, out, sun, camera=parse_camera(CAMERA, *size), size=size, irradiance=IRRADIANCE)
    frames = cycles.render_frames(python, [frame])
    return frames.images[0], f"Blender {cycles.BLENDER_VERSION} Cycles (CPU, OSL) through the usdbtf add-on"


def legend(lines: list[str], width: int) -> np.ndarray:
    """(h, width, 3) uint8: ``lines`` in black on white, the font as large as fits (at most 0.42)."""
    import cv2

    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.42
    while scale > 0.25 and max(cv2.getTextSize(line, font, scale, 1)[0][0] for line in lines) > width - 16:
        scale -= 0.02
    step = int(round(42 * scale))
    strip = np.full((8 + step * len(lines), width, 3), 255, np.uint8)
    for i, line in enumerate(lines):
        cv2.putText(strip, line, (8, step * (i + 1)), font, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return strip


def picture(frame: np.ndarray, working_space: str, lines: list[str]) -> np.ndarray:
    """The frame (linear, premultiplied RGBA) over grey, display-encoded, above its legend."""
    from usdbtf.render import to_display

    rgba = np.asarray(frame, np.float32)
    over = rgba[..., :3] + BACKGROUND * (1.0 - np.clip(rgba[..., 3:4], 0.0, 1.0))
    shown = to_display(over, working_space)
    return np.concatenate([shown, legend(lines, shown.shape[1])], axis=0)


def write_png(path: Path, image: np.ndarray) -> None:
    """Write beside, then rename: a reader never sees half a picture."""
    from usdbtf.imageio import write_image

    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.stem}.partial-{os.getpid()}.png")
    try:
        write_image(partial, image, color_space="sRGB Encoded Rec.709 (sRGB)",
                    attributes={"png:compressionLevel": 9})
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def figure(work: Path, renderer: str, size: tuple[int, int], usd: str) -> np.ndarray:
    from usdbtf.usd.asset.storm import rendering_space_of

    scene = make_scene(work, *size)
    built, knot_asset = run_build(scene)
    density = measured_density(built)
    if renderer == "storm":
        frame, who = render_storm(built, work / "storm.exr", size, usd)
        who += ", drawing the stage `usdbtf build` wrote"
        light = "the stage's UsdLux DistantLight (irradiance pi: the capture light)"
    else:
        frame, who = render_cycles(knot_asset, work / "cycles.exr", size)
        who += ", drawing the asset `usdbtf build` made for the knot"
        light = "the add-on's sun, with the direction and irradiance (pi) of the stage's UsdLux DistantLight"
    lines = [who,
             f"{PRESET}: usdbtf synth, {TEXELS} x {TEXELS} texels over {METRES * 100:g} cm, '{SAMPLING}' directions, "
             f"k {K}",
             f"on a 20 cm torus knot, quilted at {density['mesh_texels_per_metre']:.0f} texels/m as measured on the "
             f"mesh (the material: {density['material_texels_per_metre']:.0f})",
             f"lit by {light}"]
    # Storm and Cycles draw the asset's rendering space (btf:renderingColorSpace; issue 40).
    return picture(frame, rendering_space_of(work / "build" / "Pebbles.usda")[1], lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--renderer", choices=("storm", "cycles"), required=True)
    p.add_argument("-o", "--output", type=Path, required=True, help="the picture (.png; refused if not a PNG)")
    p.add_argument("--usd", default="25.08", choices=("25.08", "25.02"), help="Storm's USD (its bpy wheel)")
    p.add_argument("--size", default="640x400", help="frame WIDTHxHEIGHT in pixels (default 640x400)")
    p.add_argument("--workdir", type=Path, help="keep the scene and its build here (reused by the next run)")
    args = p.parse_args(argv)
    try:
        size = tuple(int(v) for v in args.size.lower().split("x"))
        if len(size) != 2 or min(size) < 16:
            raise ValueError
    except ValueError:
        return fail(f"--size {args.size}: want WIDTHxHEIGHT, each at least 16", USAGE)
    refusal = picture_refusal(args.output) or (workdir_refusal(args.workdir) if args.workdir else None)
    if refusal:
        return fail(refusal, REFUSED)
    if args.workdir:
        args.workdir.mkdir(parents=True, exist_ok=True)
        image = figure(args.workdir.resolve(), args.renderer, size, args.usd)
    else:
        with tempfile.TemporaryDirectory(prefix="usdbtf-built-figure-") as tmp:
            image = figure(Path(tmp), args.renderer, size, args.usd)
    write_png(args.output, image)
    print(f"{args.output} ({args.output.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
