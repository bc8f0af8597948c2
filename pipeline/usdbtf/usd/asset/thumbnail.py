"""The asset's thumbnail: the packaged geometry rendered by the CPU reference renderer.

``usdbtf.render`` evaluates the BTF itself (equation 2 with cast shadows), so the thumbnail
shows the measured material, not its fallback.  The camera frames the geometry's bounding
sphere from above the front (``auto_camera``); one distant light comes from the upper left,
the capture light (irradiance ``pi * W``, :mod:`usdbtf.photometry`), so the thumbnail shows
the measured values' own brightness.
The image is display-encoded through OCIO (the renderer's default display and view) as an
8-bit RGBA PNG, transparent where nothing was hit, and declared on the root prim with
``UsdMedia.AssetPreviewsAPI`` (``defaultImage``).
"""
from __future__ import annotations

import numpy as np

from ...compress.format import CompressedBTF
from ...mesh import Mesh

__all__ = ["THUMBNAIL_SIZE", "THUMBNAIL_FILE", "render_thumbnail", "thumbnail_png", "declare_thumbnail"]

THUMBNAIL_SIZE = 256
#: The thumbnail's file name inside the asset's texture folder.
THUMBNAIL_FILE = "thumbnail.png"
#: Towards the light, world space (Y up): above, left, in front.
LIGHT_DIRECTION = (-0.45, 0.55, 0.7)


def render_thumbnail(cbtf: CompressedBTF, mesh: Mesh, size: int = THUMBNAIL_SIZE, texels=None) -> np.ndarray:
    """(size, size, 4) uint8 display-encoded RGBA of ``mesh`` (with texture coordinates; its
    own frames, or frames from ``st``) wearing ``cbtf``.  ``texels``: ``cbtf`` as its source
    texels (a :class:`usdbtf.quilt.texels.QuiltTexels`), which the renderer gathers (the same
    image, without holding the quilt's texel-major texture)."""
    from ...camera import auto_camera
    from ...photometry import capture_irradiance, white_level_of
    from ...render import Light, RenderOptions, Renderer, to_display

    camera = auto_camera(mesh.corner(), size, size)
    light = np.asarray(LIGHT_DIRECTION, np.float64)
    source, texel_map = (cbtf, None) if texels is None else (texels.compact, texels.index)
    image = Renderer(source, RenderOptions(threads=2), texel_map=texel_map).render(
        mesh, camera, [Light("directional", light / np.linalg.norm(light), capture_irradiance(white_level_of(cbtf.info)))])
    return to_display(image, cbtf.working_space, config=cbtf.ocio_config)


def thumbnail_png(cbtf: CompressedBTF, mesh: Mesh, size: int = THUMBNAIL_SIZE, texels=None) -> bytes:
    """The thumbnail rendered (:func:`render_thumbnail`) and encoded as a PNG file's bytes, in
    memory (sRGB display encoding, tagged as such)."""
    from ...imageio import encode_image
    from ...render.output import display_processor

    pixels = render_thumbnail(cbtf, mesh, size, texels)
    _, display, _ = display_processor(cbtf.working_space, None, None, cbtf.ocio_config)
    return encode_image(pixels, "png", color_space=display, attributes={"png:compressionLevel": 9})


def declare_thumbnail(prim, asset_path: str) -> None:
    """Declare ``asset_path`` as the prim's default thumbnail (UsdMedia.AssetPreviewsAPI)."""
    from pxr import Sdf, UsdMedia

    api = UsdMedia.AssetPreviewsAPI.Apply(prim)
    thumbs = UsdMedia.AssetPreviewsAPI.Thumbnails()
    thumbs.defaultImage = Sdf.AssetPath(asset_path)
    api.SetDefaultThumbnails(thumbs)
