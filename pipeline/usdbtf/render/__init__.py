"""CPU reference renderer for compressed BTFs (equation 2 with barycentric interpolation over
triangulated view and light hemispheres): ``render(cbtf, mesh, camera, lights, RenderOptions)
-> RenderResult`` and ``write_render(result, path)``.  Meshes are :class:`usdbtf.mesh.Mesh`,
cameras :class:`usdbtf.camera.Camera`."""
from .core import RenderOptions, Renderer, RenderResult, render, render_parts, render_scene, render_swatch
from .output import to_display, write_render
from .scene import Light, parse_light

__all__ = ["RenderOptions", "RenderResult", "Renderer", "render", "render_parts", "render_scene", "render_swatch", "to_display", "write_render",
           "Light", "parse_light"]
