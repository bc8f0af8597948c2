"""Does a stage ask a partial asset for directions it does not keep?  (``inspect --validate``)

A partial asset (``compress --coverage``, :mod:`usdbtf.compress.coverage`) keeps some of its
input's view and light directions.  A renderer interpolates a local direction from the
measured directions of the triangle around it (:mod:`usdbtf.render.hemisphere`); the partial
asset renders it exactly as the full one would when every direction with a weight in the
*full* set's triangle is kept (``btf:coverage:inputViewDirections`` / ``...Light...``).
Where one is not kept, the renderers fall back to the nearest kept directions, and this
check warns (a warning, not an error: the picture is still made, only not as measured).

What is sampled, to stay cheap: up to :data:`POINTS` triangles of every Mesh bound to a
partial BTF material (an even stride, their centroids and mean frames, the mesh at its
default time), every UsdGeom.Camera at up to :data:`FRAMES` frames evenly spread over the
stage's time range, every UsdLux light (Distant: its direction; Sphere, Disk, Rect: its
centre; as the renderers read them, :func:`usdbtf.usd.scenes.scene.scene_light_prims`: Dome and
the other kinds add no directional light) at the same frames.  A point counts for a camera
when it is inside the camera's frustum and faces it; a light counts where it is above the
point's horizon.  Occlusion is not traced: a hidden surface may warn.
"""
from __future__ import annotations

import numpy as np

from ..material import read_coverage

__all__ = ["coverage_warnings", "coverage_for", "CoverageCheck", "sample_times", "POINTS", "FRAMES", "WEIGHT_EPS"]

#: Triangles sampled per bound mesh.
POINTS = 256
#: Frames sampled over the stage's time range.
FRAMES = 8
#: Interpolation weights at or below this do not need their direction.
WEIGHT_EPS = 1e-6


def sample_times(stage) -> list:
    """Up to :data:`FRAMES` Usd.TimeCodes evenly spread over the stage's start..end time
    codes (ends included); the default time when the stage declares no range."""
    from pxr import Usd

    if not stage.HasAuthoredTimeCodeRange():
        return [Usd.TimeCode.Default()]
    start, end = stage.GetStartTimeCode(), stage.GetEndTimeCode()
    count = min(FRAMES, int(end - start) + 1) if end > start else 1
    return [Usd.TimeCode(float(t)) for t in np.unique(np.linspace(start, end, count))]


def _surface_samples(prim):
    """(points (n, 3) metres, frames (n, 3, 3) rows tangent, bitangent, normal) of up to
    :data:`POINTS` triangles of a Mesh prim; None without texture coordinates."""
    from ...errors import BTFError
    from ...mesh import load_prim
    from ...render.core import point_frames

    try:
        surface = load_prim(prim).corner_frames()
    except BTFError:               # no UVs or a broken mesh: the density check reports it
        return None
    tri = np.arange(0, len(surface.points), max(1, -(-len(surface.points) // POINTS)))
    centre = np.full((len(tri), 3), 1.0 / 3.0)
    normal, tangent, bitangent = point_frames(centre, surface, tri)
    return surface.points[tri].mean(axis=1), np.stack([tangent, bitangent, normal], axis=1)


def _cameras(stage, times, meters: float) -> list:
    """[(camera path, frame label, eye (3,) metres, Gf.Frustum in stage units)] per camera and time."""
    from pxr import Gf, UsdGeom

    from .scene import camera_prims

    out = []
    for prim in camera_prims(stage):
        for t in times:
            cam = UsdGeom.Camera(prim).GetCamera(t)
            eye = np.array(cam.transform.Transform(Gf.Vec3d(0, 0, 0))) * meters
            out.append((str(prim.GetPath()), _label(t), eye, cam.frustum))
    return out


def _lights(stage, times) -> list:
    """[(light path, frame label, :class:`usdbtf.render.Light`)] per light and time: the lights
    the renderers honour, as they read them (:func:`usdbtf.usd.scenes.scene.scene_light_prims`)."""
    from .scene import scene_light_prims

    return [(path, _label(t), light) for t in times
            for path, light in scene_light_prims(stage, None if t.IsDefault() else t.GetValue(), "stage")]


def _label(t) -> str:
    return "default time" if t.IsDefault() else f"frame {t.GetValue():g}"


class CoverageCheck:
    """Which measured directions of a set a local direction interpolates from (the full
    set's triangulation), and whether the kept ones suffice."""

    def __init__(self, full: list, kept: list):
        from ...render.hemisphere import Triangulation
        from ...sampling import match_directions

        full = np.asarray(full, np.float64).reshape(-1, 2)
        self.tri = Triangulation.from_directions(full, "input directions")
        self.kept = np.zeros(len(full), bool)
        found = match_directions(np.asarray(kept, np.float64).reshape(-1, 2), full)
        self.kept[found[found >= 0]] = True

    def missing(self, local: np.ndarray) -> np.ndarray:
        """(n,) True where a local direction (n, 3) needs a direction that is not kept."""
        idx, w, _ = self.tri.weights(local)
        return ((w > WEIGHT_EPS) & ~self.kept[idx]).any(axis=1)


def coverage_for(input_views, input_lights, view_vectors, light_vectors):
    """The smallest coverage that renders the given local directions as the full input does:
    the input's directions that some of them interpolate from (their stencils on the full
    sets' triangulations, :meth:`usdbtf.render.hemisphere.Triangulation.stencil`).

    Parameters
    ----------
    input_views, input_lights : (V, 2), (L, 2) degrees, the input's distinct directions.
    view_vectors, light_vectors : (n, 3), (m, 3) local directions (tangent frame) asked for.

    Returns
    -------
    usdbtf.sampling.Coverage, or None when no view or no light is asked for.  What
    :func:`coverage_warnings` checks against, so directions it was made from never warn.
    """
    from ...render.hemisphere import Triangulation
    from ...sampling import Coverage

    views, lights = (np.asarray(d, np.float64).reshape(-1, 2) for d in (input_views, input_lights))
    if not len(view_vectors) or not len(light_vectors):
        return None
    keep_views = Triangulation.from_directions(views).stencil(np.asarray(view_vectors, np.float64), WEIGHT_EPS)
    keep_lights = Triangulation.from_directions(lights).stencil(np.asarray(light_vectors, np.float64), WEIGHT_EPS)
    return Coverage(views[keep_views], lights[keep_lights])


def coverage_warnings(stage) -> list[str]:
    """One ``[usdbtf:Coverage]`` line per (bound mesh, camera or light) that asks a partial BTF
    material for a view or light direction outside what it keeps (module docstring)."""
    from pxr import Gf, Usd, UsdGeom, UsdShade

    meters = float(UsdGeom.GetStageMetersPerUnit(stage))
    times = sample_times(stage)
    cameras = lights = None
    lines = []
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):    # instanced meshes are seen too
        if not prim.IsA(UsdGeom.Mesh):
            continue
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        record = read_coverage(material.GetPrim()) if material else None
        if not record or not record.get("input_view_directions") or not record.get("input_light_directions"):
            continue
        samples = _surface_samples(prim)
        if samples is None:
            continue
        if cameras is None:
            cameras, lights = _cameras(stage, times, meters), _lights(stage, times)
        points, frames = samples
        where = f"{prim.GetPath()} (bound to {material.GetPath()})"
        views = CoverageCheck(record["input_view_directions"], record["views"])
        needed = CoverageCheck(record["input_light_directions"], record["lights"])
        seen = np.zeros(len(points), bool)
        for path, label, eye, frustum in cameras:
            to_eye = eye - points
            local = np.einsum("nij,nj->ni", frames, to_eye / np.linalg.norm(to_eye, axis=1, keepdims=True))
            inside = np.array([frustum.Intersects(Gf.Vec3d(*(p / meters))) for p in points])
            visible = inside & (local[:, 2] > 0)
            seen |= visible
            lines += _report(where, "camera " + path, label, "view", local[visible], views)
        for path, label, light in lights:
            to_light, scale = light.at(points)
            local = np.einsum("nij,nj->ni", frames, to_light)
            lit = (scale > 0) & (local[:, 2] > 0) & (seen if cameras else True)
            lines += _report(where, "light " + path, label, "light", local[lit], needed)
    return _first_per_source(lines)


def _report(where: str, source: str, label: str, what: str, local: np.ndarray, needs: CoverageCheck) -> list:
    """[(where, source, line)] when some of the local directions need a direction not kept."""
    if not len(local):
        return []
    missing = needs.missing(local)
    if not missing.any():
        return []
    v = local[np.argmax(missing)]
    theta = float(np.degrees(np.arccos(np.clip(v[2], -1.0, 1.0))))
    phi = float(np.degrees(np.arctan2(v[1], v[0])) % 360.0)
    return [(where, source, f"[usdbtf:Coverage] {where}: {source} asks for {what} directions outside the "
             f"material's coverage ({int(missing.sum())} of {len(local)} sampled points at {label}, e.g. theta "
             f"{theta:.1f}, phi {phi:.1f} deg); the renderers use the nearest covered {what}s there")]


def _first_per_source(entries: list) -> list[str]:
    """The first line of each (mesh, camera or light): one warning each, not one per frame."""
    seen, lines = set(), []
    for where, source, line in entries:
        if (where, source) not in seen:
            seen.add((where, source))
            lines.append(line)
    return lines
