"""The asset's thumbnail: the packaged geometry rendered by the CPU reference renderer.

``usdbtf.render`` evaluates the BTF itself (equation 2 with cast shadows), so the thumbnail
shows the measured material, not its fallback.  The camera frames the geometry's bounding
sphere from above the front (``auto_camera``); one distant light comes from the upper left.
The image is display-encoded through OCIO (the renderer's default display and view) as an
8-bit RGBA PNG, transparent where nothing was hit, and declared on the root prim with
``UsdMedia.AssetPreviewsAPI`` (``defaultImage``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..compress.format import CompressedBTF
from .geometry import MeshData

__all__ = ["THUMBNAIL_SIZE", "render_thumbnail", "write_thumbnail", "declare_thumbnail"]

THUMBNAIL_SIZE = 256
#: Towards the light, world space (Y up): above, left, in front.
LIGHT_DIRECTION = (-0.45, 0.55, 0.7)


def _corner_mesh(mesh: MeshData):
    """A RenderMesh of ``mesh``: polygons fanned into triangles, every corner its own vertex
    (so face-varying ``st`` needs no welding); frames from ``st`` (faceted, fine at 256 px)."""
    from ..render.assets import render_mesh_from_arrays

    counts, indices = np.asarray(mesh.counts), np.asarray(mesh.indices)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    corners = np.concatenate([[s, s + j, s + j + 1] for s, c in zip(starts, counts) for j in range(1, c - 1)])
    tris = corners.reshape(-1, 3)
    points = np.asarray(mesh.points, np.float64)[indices]
    st = np.asarray(mesh.st, np.float64)
    st = st[indices] if mesh.st_interpolation == "vertex" else st
    p = points[tris]
    face_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    face_n /= np.maximum(np.linalg.norm(face_n, axis=1, keepdims=True), 1e-30)
    normals = np.zeros_like(points)
    for j in range(3):
        np.add.at(normals, tris[:, j], face_n)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    return render_mesh_from_arrays(points, tris, st, normals)


def render_thumbnail(cbtf: CompressedBTF, mesh: MeshData, size: int = THUMBNAIL_SIZE) -> np.ndarray:
    """(size, size, 4) uint8 display-encoded RGBA of ``mesh`` wearing ``cbtf``."""
    from ..render.core import RenderOptions, Renderer
    from ..render.output import to_display
    from ..render.scene import Light, auto_camera

    rmesh = _corner_mesh(mesh)
    camera = auto_camera(np.asarray(mesh.points, np.float64), size, size)
    light = np.asarray(LIGHT_DIRECTION, np.float64)
    image = Renderer(cbtf, RenderOptions(threads=2)).render(
        rmesh, camera, [Light("directional", light / np.linalg.norm(light), 1.0)])
    return to_display(image, cbtf.working_space, config=cbtf.ocio_config)


def write_thumbnail(cbtf: CompressedBTF, mesh: MeshData, path: Path, size: int = THUMBNAIL_SIZE) -> None:
    """Render and write the thumbnail PNG (sRGB display encoding, tagged as such)."""
    from ..imageio import write_image
    from ..render.output import display_processor

    pixels = render_thumbnail(cbtf, mesh, size)
    _, display, _ = display_processor(cbtf.working_space, None, None, cbtf.ocio_config)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, pixels, color_space=display, attributes={"png:compressionLevel": 9})


def declare_thumbnail(prim, asset_path: str) -> None:
    """Declare ``asset_path`` as the prim's default thumbnail (UsdMedia.AssetPreviewsAPI)."""
    from pxr import Sdf, UsdMedia

    api = UsdMedia.AssetPreviewsAPI.Apply(prim)
    thumbs = UsdMedia.AssetPreviewsAPI.Thumbnails()
    thumbs.defaultImage = Sdf.AssetPath(asset_path)
    api.SetDefaultThumbnails(thumbs)
