"""A Storm frame against ``usdbtf render`` of the same stage (tests of real Storm)."""
from __future__ import annotations

import numpy as np

from usdbtf.cli import main


def against_cpu_render(image, scene, camera: str, size: int, tmp_path) -> tuple[float, np.ndarray, np.ndarray]:
    """(PSNR in dB of the Storm frame ``image`` (H, W, 4) against `usdbtf render SCENE --camera
    PRIM` (no shadows, bilinear), both sRGB-encoded, over the pixels where both have full
    geometry coverage; that mask (H, W) bool; the CPU frame (H, W, 4) float64)."""
    from usdbtf.render.output import srgb_encoded
    from usdbtf.gpu.headless import psnr
    from usdbtf.usd.storm import read_rgba

    cpu_out = tmp_path / "cpu.exr"
    assert main(["render", str(scene), "--camera", camera, "--size", str(size), str(size), "--no-shadows",
                 "--filter", "bilinear", "-o", str(cpu_out), "--no-png", "-q"]) == 0
    cpu = np.asarray(read_rgba(cpu_out), np.float64)
    image = np.asarray(image, np.float64)
    both = (image[..., 3] > 0.999) & (cpu[..., 3] > 0.999)
    return psnr(srgb_encoded(image[..., :3]), srgb_encoded(cpu[..., :3]), both), both, cpu
