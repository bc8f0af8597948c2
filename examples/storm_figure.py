"""Real Hydra Storm next to the CPU reference on a curved mesh (a comparison sheet).

    python examples/storm_figure.py ASSET.usda -o storm_vs_cpu.png [--usd 25.08] [--size 256]

(The docs' Storm picture, ``docs/storm_preview.png``, shows a built scene instead:
``examples/built_figure.py --renderer storm``.)

ASSET is a packaged asset on a curved unwrapped mesh (``usdbtf unwrap`` then ``usdbtf package
--mesh``).  One stage references it with a UsdGeom camera, a DistantLight and a SphereLight
(:func:`usdbtf.usd.scenes.scene.write_scene`); Storm renders it through ``UsdAppUtils.FrameRecorder``
in a storm environment (``scripts/bootstrap.sh``), ``usdbtf render SCENE --camera /World/Camera``
renders the same stage on the CPU.  Columns: Storm, the CPU renderer (bilinear, no shadows),
|difference| x 10; the title gives the PSNR (sRGB, where both have full coverage).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from preview_figure import _tile
from pictures import refused
from usdbtf.camera import Camera
from usdbtf.cli import main as usdbtf_main
from usdbtf.render.output import srgb_encoded
from usdbtf.gpu.headless import psnr
from usdbtf.imageio import write_image
from usdbtf.render import parse_light
from usdbtf.usd.preview import hydra
from usdbtf.usd.scenes.scene import write_scene
from usdbtf.usd.asset.storm import read_rgba, rendering_space_of, to_rendering_space


def figure(asset: Path, version: str, size: int) -> np.ndarray:
    pythons = hydra.storm_pythons()
    if version not in pythons:
        raise SystemExit(f"no Storm environment for USD {version}: run scripts/bootstrap.sh")
    camera = Camera(np.array([0.05, 0.06, 0.15]), np.zeros(3), np.array([0.0, 1.0, 0.0]), 35.0, size, size)
    lights = [parse_light("dir:0.3,0.5,1"), parse_light("point:0.1,0.05,0.1:0.0628")]
    with tempfile.TemporaryDirectory(prefix="usdbtf-figure-") as tmp:
        scene, cpu_out = Path(tmp) / "scene.usda", Path(tmp) / "cpu.exr"
        prim = write_scene(asset.resolve(), scene, camera, lights)
        storm = hydra.render_frames(pythons[version], [(scene, Path(tmp) / "storm.exr")], prim, (size, size))
        if storm.problems:
            raise SystemExit("\n".join(storm.problems))
        assert usdbtf_main(["render", str(scene), "--camera", prim, "--size", str(size), str(size), "--no-shadows",
                            "--filter", "bilinear", "-o", str(cpu_out), "--no-png", "-q"]) == 0
        # usdbtf render writes the working space; Storm draws the asset's rendering space (issue 40).
        cpu = to_rendering_space(asset, read_rgba(cpu_out))
        _, shown, _ = rendering_space_of(asset)
    image = storm.images[0]
    both = (image[..., 3] > 0.999) & (cpu[..., 3] > 0.999)
    value = psnr(srgb_encoded(image[..., :3]), srgb_encoded(cpu[..., :3]), both)
    diff = np.abs(image[..., :3] - cpu[..., :3]) * 10.0
    return np.concatenate([_tile(image, shown, f"Storm (USD {version})", size),
                           _tile(cpu, shown, "usdbtf render (CPU)", size),
                           _tile(diff, shown, f"|diff| x10, {value:.1f} dB sRGB", size)], axis=1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("asset", type=Path)
    p.add_argument("-o", "--output", type=Path, required=True)
    p.add_argument("--usd", default="25.08", choices=sorted(hydra.STORM_ENVIRONMENTS))
    p.add_argument("--size", type=int, default=256)
    args = p.parse_args(argv)
    if (code := refused(args.output, 'storm_figure')) is not None:
        return code
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_image(args.output, figure(args.asset, args.usd, args.size), color_space="sRGB Encoded Rec.709 (sRGB)")
    print(args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
