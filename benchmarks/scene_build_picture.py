#!/usr/bin/env python
"""The picture of issue 31 in docs/scenes-and-build.md: the benchmark's scene (``bench_scene_build.write_scene``: a
sphere, a cylinder and a box with their own [0, 1] UVs, three synthetic 16-texel materials of
5 cm, a camera /World/Cam and a distant light /World/Sun) rendered from its own camera by the
CPU renderer, before the build (each material's swatch asset stretched over the mesh's UVs) and
after (``usdbtf build``'s scene: every mesh quilted at the material's measured scale), side by side.

Usage (repository root)::

    .venv/bin/python benchmarks/scene_build_picture.py              # -> docs/scene_build_scene.png, ~1 min

Each half is ``usdbtf render SCENE --camera /World/Cam --size 480 270`` (SCENE: the user's
``scene.usda``, then the built stage ``scene.built.usda``), composed over grey.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "pipeline"))
import usdbtf  # noqa: E402,F401  (pins the numeric platform before numpy's BLAS loads)
from bench_scene_build import write_scene  # noqa: E402

WIDTH, HEIGHT = 480, 270
GAP = 4
GREY = 0.45          # display-referred background under the frames' alpha


def render(scene: Path, out: Path) -> np.ndarray:
    """(H, W, 4) float display-referred RGBA (its PNG) of ``usdbtf render SCENE --camera /World/Cam``."""
    import OpenImageIO as oiio

    subprocess.run([sys.executable, "-m", "usdbtf.cli", "render", str(scene), "--camera", "/World/Cam", "--size",
                    str(WIDTH), str(HEIGHT), "-o", str(out.with_suffix(".exr")), "-q"], check=True)
    return np.asarray(oiio.ImageBuf(str(out.with_suffix(".png"))).get_pixels(oiio.FLOAT), np.float64)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("-o", "--output", type=Path, default=HERE.parent / "docs" / "scene_build_scene.png")
    args = p.parse_args()
    from usdbtf.imageio import write_image
    from usdbtf.usd.scenes.build import build
    from usdbtf.usdstage import usd_warnings_silenced

    with tempfile.TemporaryDirectory(prefix="scene_build_picture_") as tmp:
        root = Path(tmp)
        with usd_warnings_silenced():           # the materials' assets do not exist before the build
            scene = write_scene(root, 16, WIDTH, HEIGHT)
        built = build(scene)["built_scene"]
        halves = [render(scene, root / "before"), render(built, root / "after")]
    over = [h[..., :3] * h[..., 3:4] + GREY * (1 - h[..., 3:4]) for h in halves]
    picture = np.concatenate([over[0], np.ones((HEIGHT, GAP, 3)), over[1]], axis=1)
    write_image(args.output, np.round(picture * 255).astype(np.uint8), color_space="sRGB - Display",
                attributes={"png:compressionLevel": 9})
    print(f"{args.output} ({args.output.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
