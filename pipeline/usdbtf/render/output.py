"""Writing renders: a float EXR in the working space and an 8-bit PNG through an OCIO display view.

Both files are written to temporary names and renamed only when both succeeded.  Each
carries the image attribute ``usdbtf:output = "usdbtf-render"``, by which ``--force``
recognises a previous render (and replaces nothing else).
"""
from __future__ import annotations

import contextlib
import functools
from pathlib import Path

import numpy as np
import PyOpenColorIO as ocio

from .. import color
from ..atomic import atomic_file
from ..errors import BTFError
from ..imageio import write_image
from ..outputs import IMAGE_ATTRIBUTE, RENDER

__all__ = ["display_processor", "to_display", "write_render", "srgb_encoded", "DEFAULT_VIEW"]

# Measured BTF values are reflectance-like (a white diffuse texel lit head-on reads 0.8):
# show them without a tone curve unless asked.
DEFAULT_VIEW = "Un-tone-mapped"


@functools.lru_cache(maxsize=8)
def display_processor(working_space: str, display: str | None, view: str | None, config: str | None):
    """(CPU processor working space -> display, display name, view name) for ``config``."""
    cfg = color.get_config(config)
    display = display or cfg.getDefaultDisplay()
    if display not in list(cfg.getDisplays()):
        raise BTFError(f"display {display!r} is not in OCIO config {config or color.DEFAULT_CONFIG!r} "
                       f"(has {', '.join(cfg.getDisplays())})")
    views = list(cfg.getViews(display))
    view = view or (DEFAULT_VIEW if DEFAULT_VIEW in views else cfg.getDefaultView(display))
    if view not in views:
        raise BTFError(f"view {view!r} is not a view of display {display!r} (has {', '.join(views)})")
    src = color.resolve_space(working_space, config)
    transform = ocio.DisplayViewTransform(src=src, display=display, view=view)
    return cfg.getProcessor(transform).getDefaultCPUProcessor(), display, view


def to_display(rgba: np.ndarray, working_space: str, *, display=None, view=None, config=None) -> np.ndarray:
    """(H, W, 3 or 4) float working space -> uint8 display-encoded, alpha kept."""
    proc, _, _ = display_processor(working_space, display, view, config)
    rgb = np.ascontiguousarray(rgba[..., :3], np.float32).copy()
    proc.applyRGB(rgb.reshape(-1))
    out = rgb if rgba.shape[-1] == 3 else np.concatenate([rgb, rgba[..., 3:4]], axis=-1)
    return np.clip(np.rint(np.clip(out, 0.0, 1.0) * 255.0), 0, 255).astype(np.uint8)


def write_render(result, exr_path, *, png_path=None, display=None, view=None) -> dict:
    """Write ``result`` (a :class:`~usdbtf.render.core.RenderResult`: (H, W, 3|4) float32 in its
    working space) as EXR (and the PNG through an OCIO display view, if a path is given).
    Returns {"exr", "png", "display", "view"}."""
    image, working_space, config = result.image, result.working_space, result.ocio_config
    exr_path = Path(exr_path)
    if exr_path.suffix.lower() != ".exr":
        raise BTFError(f"{exr_path}: the render is written as OpenEXR; name it *.exr")
    space = color.resolve_space(working_space, config)
    info = {"exr": str(exr_path), "png": None}
    with contextlib.ExitStack() as stack:
        tmp_exr = stack.enter_context(atomic_file(exr_path, kind=RENDER))
        write_image(tmp_exr, np.ascontiguousarray(image, np.float32), color_space=space,
                    attributes={"compression": "zip", IMAGE_ATTRIBUTE: RENDER})
        if png_path is not None:
            _, disp, v = display_processor(working_space, display, view, config)
            tmp_png = stack.enter_context(atomic_file(png_path, kind=RENDER))
            write_image(tmp_png, to_display(image, working_space, display=disp, view=v, config=config),
                        color_space=disp, attributes={"png:compressionLevel": 6, IMAGE_ATTRIBUTE: RENDER})
            info.update(png=str(png_path), display=disp, view=v)
    return info


def srgb_encoded(linear) -> np.ndarray:
    """Linear values clipped to [0, 1] and sRGB-encoded (IEC 61966-2-1): the code values a
    display shows, for comparing frames of different renderers (PSNR, 8-bit steps).  Not a
    colour conversion of data (those go through OCIO): a fixed metric, the same in every
    comparison."""
    x = np.clip(np.asarray(linear, np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
