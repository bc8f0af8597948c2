"""CPU reference renderer for compressed BTFs (equation 2 with barycentric interpolation over
triangulated view and light hemispheres).  File handling (what ``usdbtf render ASSET`` means)
is in :mod:`.assets`."""
from .core import RenderOptions, Renderer, render, render_swatch
from .output import to_display, write_render
from .scene import Camera, Light, RenderMesh, auto_camera, parse_camera, parse_light

__all__ = ["RenderOptions", "Renderer", "render", "render_swatch", "to_display", "write_render", "Camera", "Light",
           "RenderMesh", "auto_camera", "parse_camera", "parse_light"]
