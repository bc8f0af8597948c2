"""The paper's Fig. 5, synthetically: three materials quilted onto a sphere, a cylinder and a
torus knot, each under a point light at two distances.

    python examples/fig5.py -o docs/quilt_render_fig5.png            # ~2 min on 2 cores
    python examples/fig5.py -o fig5_small.png --size 64 --k 24 --tile 160

Per preset: ``usdbtf synth`` (sampling ``--sampling``, ``--size`` texels, 5 cm across) and
``usdbtf compress --k K``; per shape (examples/shapes.py): ``usdbtf unwrap`` at the sample's
texel density, then quilting into each atlas and rendering, in-process through the library
(``usdbtf.quilt.quilt`` into an atlas, ``usdbtf.render.Renderer``) so each BTF is read once.
Rows: materials; columns: shape x light (near, far; same irradiance at the object).  Colour:
working space -> sRGB display through OCIO (``usdbtf.render.to_display``).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import shapes  # noqa: E402  (examples/shapes.py)
from pictures import refused  # noqa: E402

from usdbtf.camera import auto_camera  # noqa: E402
from usdbtf.cli import main as usdbtf  # noqa: E402
from usdbtf.compress import read_compressed  # noqa: E402
from usdbtf.imageio import write_image  # noqa: E402
from usdbtf.quilt import QuiltOptions, quilt, quilted_btf  # noqa: E402
from usdbtf.render import Light, RenderOptions, Renderer, to_display  # noqa: E402
from usdbtf.unwrap import read_unwrap  # noqa: E402

PRESETS = ("pebbles", "ridged_fabric", "fuzzy_moss")
# Scale of examples/shapes.py's sizes (atlases stay below ~800^2 at 2560 texels per metre) and
# how much closer than the auto camera (which frames the bounding sphere) to stand.
SHAPES = {"sphere": (0.8, 0.8), "cylinder": (0.8, 0.95), "torus_knot": (0.6, 0.72)}
LIGHT_DIRECTIONS = (np.array([-0.6, 0.7, 0.6]), np.array([0.8, 0.5, 0.5]))   # near light, far light
LIGHT_DISTANCES = (0.12, 0.5)


def run(*argv) -> None:
    if usdbtf([str(a) for a in argv]) != 0:
        raise SystemExit(f"usdbtf {' '.join(map(str, argv))} failed")


def tile(image: np.ndarray, space: str) -> np.ndarray:
    rgba = image.copy()
    rgba[..., :3] += (1.0 - rgba[..., 3:4]) * 0.18                # mid-grey background (scene-linear)
    return np.ascontiguousarray(to_display(rgba[..., :3], space))


def label(text: str, width: int, height: int = 24) -> np.ndarray:
    out = np.full((height, width, 3), 255, np.uint8)
    cv2.putText(out, text, (6, height - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-o", "--output", type=Path, required=True)
    p.add_argument("--workdir", type=Path, default=Path("examples/out/fig5"))
    p.add_argument("--sampling", default="small")
    p.add_argument("--size", type=int, default=128, help="sample texels per side (default 128)")
    p.add_argument("--k", type=int, default=48)
    p.add_argument("--tile", type=int, default=256, help="pixels per rendered image (default 256)")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    if (code := refused(args.output, 'fig5')) is not None:
        return code
    t0 = time.perf_counter()
    work = args.workdir
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for preset in PRESETS:
        raw, comp = work / f"{preset}_raw", work / f"{preset}_c"
        if not (comp / "btf-compressed.json").is_file():
            run("synth", preset, "-o", raw, "--sampling", args.sampling, "--size", args.size, "--seed", args.seed, "-q",
                "--force")
            run("compress", raw, "-o", comp, "--k", args.k, "-q", "--force")
        cbtf = read_compressed(comp)
        row = []
        for shape, (scale, closer) in SHAPES.items():
            uv = work / f"{shape}_{args.size}_uv"
            if not (uv / "mesh.usda").is_file():
                points, faces, normals = shapes.SHAPES[shape]()
                obj = shapes.write_obj(work / f"{shape}.obj", points * scale, faces, normals)
                run("unwrap", obj, "-o", uv, "--btf", comp, "-q", "--force")
            unwrapped = read_unwrap(uv / "mesh.usda")
            q = quilt(cbtf, QuiltOptions(seed=args.seed), atlas=unwrapped)
            renderer = Renderer(quilted_btf(q), RenderOptions(threads=2))
            mesh = unwrapped.mesh
            camera = auto_camera(mesh.corner(), args.tile, args.tile, fov=24.0, direction=(0.3, 0.35, 1.0))
            camera.eye = camera.target + (camera.eye - camera.target) * closer
            centre = mesh.corner().reshape(-1, 3).mean(axis=0)
            for direction, dist in zip(LIGHT_DIRECTIONS, LIGHT_DISTANCES):
                pos = centre + direction / np.linalg.norm(direction) * dist
                # The same irradiance at the object: 1.2 capture lights (pi, usdbtf.photometry).
                light = Light("point", pos, 1.2 * np.pi * dist ** 2)
                image = renderer.render(mesh, camera, [light])
                row.append(tile(image, cbtf.working_space))
            print(f"{preset} {shape}: atlas {q.width}x{q.height}, {time.perf_counter() - t0:.0f} s", flush=True)
        rows.append(label(preset, len(row) * args.tile))
        rows.append(np.concatenate(row, axis=1))
    header = np.concatenate([label(f"{shape}, light at {dist:g} m", args.tile) for shape in SHAPES
                             for dist in LIGHT_DISTANCES], axis=1)
    sheet = np.concatenate([header, *rows], axis=0)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_image(args.output, sheet, color_space="sRGB - Display", attributes={"png:compressionLevel": 9})
    print(f"wrote {args.output} ({sheet.shape[1]}x{sheet.shape[0]}) in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
