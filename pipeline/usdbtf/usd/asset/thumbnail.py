"""The asset's thumbnail: the packaged geometry rendered by the CPU reference renderer.

``usdbtf.render`` evaluates the BTF itself (equation 2 with cast shadows), so the thumbnail
shows the measured material, not its fallback.  The camera frames the geometry's bounding
sphere from above the front (``auto_camera``); one distant light comes from the upper left,
the capture light (irradiance ``pi * W``, :mod:`usdbtf.photometry`), so the thumbnail shows
the measured values' own brightness.
The image is display-encoded through OCIO (the renderer's default display and view),
composited over a flat grey (:data:`BACKGROUND`) where nothing was hit, written as a 256²
baseline JPEG (:data:`JPEG_ATTRIBUTES`: what studio asset browsers show; every lod loads it,
so its bytes count against ``--max-bytes``: 0.20-0.25 of the RGBA PNG it replaced on the
seven paper-scale assets, issue 39) and declared on the root prim with ``UsdMedia.AssetPreviewsAPI`` (``defaultImage``).
The JPEG is encoded in memory by OpenCV (libjpeg-turbo in its wheel), never through a file: OIIO's
JPEG writer lets libjpeg end the process (status 1) when a write fails, e.g. under a file size
limit, where usdbtf must report an I/O error (74) and clean up.  An sRGB display needs no tag: a
plain JFIF file is sRGB by convention and OIIO reads it back as ``srgb_rec709_scene``.  Another
display (an OCIO config whose default display is not sRGB) goes through OIIO, which records it.
"""
from __future__ import annotations

import numpy as np

from ...compress.format import CompressedBTF
from ...errors import IOFailure
from ...mesh import Mesh

__all__ = ["THUMBNAIL_SIZE", "THUMBNAIL_FILE", "BACKGROUND", "JPEG_ATTRIBUTES", "render_thumbnail",
           "composite_background", "thumbnail_jpeg", "declare_thumbnail"]

THUMBNAIL_SIZE = 256
#: The thumbnail's file name inside the asset's texture folder (assets before issue 39 hold
#: ``thumbnail.png``, an RGBA PNG: readers take whatever ``defaultImage`` names).
THUMBNAIL_FILE = "thumbnail.jpg"
#: Display code (8-bit) of the grey behind the geometry: 18 % grey through an sRGB display.
BACKGROUND = 118
#: OIIO's JPEG options: quality 90 with 4:2:0 chroma, the usual setting of a browser's
#: thumbnail (256² metal_flakes paper-scale asset: 12,826 bytes against its PNG's 64,061;
#: quality 95 4:4:4 would be 0.43 of the PNG; benchmarks/probes/smallfiles_bytes.py).
JPEG_ATTRIBUTES = {"Compression": "jpeg:90", "jpeg:subsampling": "4:2:0"}
#: The same options for OpenCV's in-memory encoder (4:2:0 is its default sampling).
JPEG_PARAMS = (1, 90)       # (cv2.IMWRITE_JPEG_QUALITY, 90): cv2 is imported only where it is used
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


def composite_background(rgba: np.ndarray, background: int = BACKGROUND) -> np.ndarray:
    """(H, W, 3) uint8: the display-encoded (H, W, 4) uint8 ``rgba`` over a flat ``background``
    code, blended on the display codes as straight alpha (the renderer's alpha is whether a
    pixel hit the geometry: 0 or 255 in its thumbnails, so the blend only picks)."""
    rgb = rgba[..., :3].astype(np.float32)
    alpha = rgba[..., 3:4].astype(np.float32) / 255.0
    return np.rint(rgb * alpha + np.float32(background) * (1.0 - alpha)).astype(np.uint8)


def thumbnail_jpeg(cbtf: CompressedBTF, mesh: Mesh, size: int = THUMBNAIL_SIZE, texels=None) -> bytes:
    """The thumbnail rendered (:func:`render_thumbnail`), composited over :data:`BACKGROUND`
    and encoded as a JPEG file's bytes (:data:`JPEG_ATTRIBUTES`), in memory; its display
    encoding is declared (module docstring)."""
    from ...imageio import encode_image
    from ...render.output import display_processor

    pixels = composite_background(render_thumbnail(cbtf, mesh, size, texels))
    _, display, _ = display_processor(cbtf.working_space, None, None, cbtf.ocio_config)
    if "srgb" in display.lower():
        import cv2

        ok, data = cv2.imencode(".jpg", np.ascontiguousarray(pixels[..., ::-1]), list(JPEG_PARAMS))
        if not ok:
            raise IOFailure("thumbnail: OpenCV could not encode the JPEG")
        return data.tobytes()
    return encode_image(pixels, "jpg", color_space=display, attributes=JPEG_ATTRIBUTES)


def declare_thumbnail(prim, asset_path: str) -> None:
    """Declare ``asset_path`` as the prim's default thumbnail (UsdMedia.AssetPreviewsAPI)."""
    from pxr import Sdf, UsdMedia

    api = UsdMedia.AssetPreviewsAPI.Apply(prim)
    thumbs = UsdMedia.AssetPreviewsAPI.Thumbnails()
    thumbs.defaultImage = Sdf.AssetPath(asset_path)
    api.SetDefaultThumbnails(thumbs)
