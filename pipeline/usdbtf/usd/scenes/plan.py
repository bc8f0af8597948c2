"""What a scene needs of each bound BTF material (issue 26): a pure function of the composed stage.

:func:`analyse` looks at every whole frame of the stage (``startTimeCode`` .. ``endTimeCode``,
or the default time), every ``UsdGeom.Camera`` at that frame (transform, focal length,
apertures, clipping range), the ``UsdLux`` lights at that frame, and every prim bound to a
material, and says for each material (a :class:`Need`):

* **needed or not, and why not**: a prim counts only where it is rendered: ``purpose``
  default or render (``proxy`` and ``guide`` prims are not in a final render), visible at
  that frame, and with some triangle inside some camera's frustum (between its clipping
  planes) and facing it.  (Inactive prims are not composed, so their bindings never reach
  the plan: ``usd.scenes.build.plan`` never sees those materials.)
* **screen density**: the most screen pixels one texel covers, over cameras x frames x
  visible surface points (``focal_px / depth / texels_per_metre``, head-on: foreshortening
  only shrinks it, so this is an upper bound).  The texel size is the larger of the
  material's measured one and the one the mesh's own UVs give (the built scene's atlas has
  the first, a render of the user's scene the second).  Below one pixel per texel the
  coefficients can be box-filtered by ``factor = 2^floor(log2(1 / density))`` (so a level of
  the reduced mip chain is a level of the full one) without a visible change: the renderers'
  trilinear filter reads level ``log2(factor)`` or coarser there anyway.  Hence
  ``max_texels`` (what ``compress --max-texels`` takes; never below :data:`MIN_TEXELS`) and
  the mip levels still needed.
* **directions**: the local (view, light) directions reached, in each surface point's
  tangent frame (x = tangent, y = bitangent, z = normal: the frame the renderers shade in;
  theta from the normal, phi in the tangent plane), snapped to the material's measured view
  and light sets exactly as the renderers interpolate: the vertices of the triangle of the
  measured directions' Delaunay triangulation (:class:`usdbtf.render.hemisphere.Triangulation`,
  the one the CPU renderer and the GPU tables use) that holds the direction, or the two ends
  of the boundary edge nearest to a direction outside the measured region, each one that
  weighs in (:meth:`~usdbtf.render.hemisphere.Triangulation.stencil`).  Lights below a
  point's horizon add nothing (the renderers give them zero weight).  Shadows are ignored
  (a shadowed point's light direction is kept: conservative).
* **k**: with a screen-space error target (``--target-error``, else the material's
  ``btf:build:targetError`` attribute), the per-texel target that meets it (module
  :func:`texel_target`); compress's own rate control then picks the smallest k that
  reaches it (at most the recipe's k).

**Sampling, so that nothing visible is missed.** Every whole frame; for every camera and
every bound mesh, (a) the mesh rasterised at the render resolution (its own z-buffer, so
other meshes never hide it: conservative), one sample at each covered pixel centre, the
renderer's own perspective-correct interpolation of the position and the tangent frame;
(b) every corner of every front-facing triangle that overlaps the frustum (a conservative
plane test in camera space), so a triangle smaller than a pixel, or one cut by the near
plane, still counts.  Between two neighbouring pixel centres a local direction moves by about
one pixel's angle (0.05 degrees at 1920 pixels and 90 degrees of field of view), far less
than the spacing of any measured set (15 degrees), so the triangles between two samples
are those of the samples.  Sub-frame times (motion blur) are not looked at; a frame identical
to an earlier one (cameras, lights, every bound prim's visibility and placement, animated
points) is not sampled again.

The render resolution is the stage's ``UsdRender.Settings`` resolution (its width; the
height follows each camera's apertures, as ``usdbtf render`` and usdrecord frame it),
else :data:`DEFAULT_WIDTH`.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from ...errors import BTFError

log = logging.getLogger(__name__)

__all__ = ["MaterialFacts", "Need", "analyse", "texel_target", "DEFAULT_WIDTH", "COVERAGE_FORMAT"]

#: Render width (pixels) when the stage has no UsdRender.Settings.
DEFAULT_WIDTH = 1920
#: The smallest side (texels) a shaped build filters a material to: a bound mesh's quilt
#: copies patches of its source (``usdbtf quilt``'s blocks are 8 texels and more).
MIN_TEXELS = 16
#: The ``format`` of the coverage documents ``compress --coverage`` reads.
COVERAGE_FORMAT = "usdbtf-coverage/1"


@dataclass(frozen=True)
class MaterialFacts:
    """What the plan needs to know of a material's source.

    views, lights : (V, 2), (L, 2) degrees (theta, phi): its measured direction sets.
    width, height : texels.  texels_per_metre : its measured density (None: unknown).
    whole : why the material is built whole whatever the scene shows (None: it can be shaped):
    the source is already compressed (nothing is compressed), or its sampling is not every
    light at every view (a coverage keeps a views x lights product).
    """

    views: np.ndarray
    lights: np.ndarray
    width: int
    height: int
    texels_per_metre: float | None = None
    whole: str | None = None

    @classmethod
    def of(cls, source, compressed: bool = False) -> "MaterialFacts":
        """The facts of an opened source: a :class:`usdbtf.model.BTF` or (``compressed``) a
        :class:`usdbtf.compress.format.CompressedBTF`."""
        from ...compress.format import cross_layout

        sampling = source.sampling
        layout = cross_layout(sampling)
        whole = "the source is already compressed: packaged as it is" if compressed else None
        if layout is None:
            whole = "its sampling is not every light at every view: built whole"
            layout = (len(sampling), 1)
        n_views, n_lights = layout
        meta = getattr(source, "metadata", None) or (getattr(source, "info", None) or {}).get("source_metadata") or {}
        size = meta.get("physical_size_m")
        density = None
        if size and len(size) == 2 and min(float(x) for x in size) > 0:
            density = math.sqrt(source.width * source.height / (float(size[0]) * float(size[1])))
        return cls(sampling.view[::n_lights].copy(), sampling.light[:n_lights].copy(), int(source.width),
                   int(source.height), density, whole)


@dataclass
class Need:
    """What the scene needs of one material (module docstring).

    prims : {prim path: what the plan found ("seen", or why not)}.  views, lights : sorted
    indices into the material's measured view and light sets.  pixels_per_texel : the most
    screen pixels one texel covers (None: never seen).  factor : the box-filter factor the
    coefficients may take; max_texels : the larger side after it (None: full resolution).
    target_error : the per-texel percent error target (None: the recipe's k).  samples :
    surface samples looked at; frames : frames in which the material was seen."""

    material: str
    facts: MaterialFacts
    prims: dict = field(default_factory=dict)
    views: list = field(default_factory=list)
    lights: list = field(default_factory=list)
    pixels_per_texel: float | None = None
    samples: int = 0
    frames: int = 0
    screen_target: float | None = None
    full: str | None = None

    @property
    def needed(self) -> bool:
        return self.full is not None or any(status == "seen" for status in self.prims.values())

    @property
    def stand_in(self) -> bool:
        """Not needed, yet built as a stand-in: the scene references the material's asset, so
        something valid must be there (a reference to a missing file fails validation), but one
        measured direction pair at :data:`MIN_TEXELS` and k = 1 is all it holds."""
        return not self.needed and self.full is None and len(self.facts.views) > 0 and len(self.facts.lights) > 0

    @property
    def why_not(self) -> str | None:
        """Why the material is not needed (None when it is)."""
        if self.needed:
            return None
        reasons = sorted(set(self.prims.values()))
        return "; ".join(reasons) if reasons else "no rendered prim is bound to it"

    @property
    def factor(self) -> int:
        if self.full is not None or self.pixels_per_texel is None or self.pixels_per_texel >= 1.0:
            return 1
        return 2 ** int(math.floor(math.log2(1.0 / self.pixels_per_texel)))

    @property
    def max_texels(self) -> int | None:
        """The larger side after the box filter (None: the measured resolution); never below
        :data:`MIN_TEXELS` (nor a filter that would leave the size as it is)."""
        side = max(self.facts.width, self.facts.height)
        if self.stand_in:
            return MIN_TEXELS if side > MIN_TEXELS else None
        texels = max(MIN_TEXELS, -(-side // self.factor))
        return None if texels >= side else texels

    @property
    def mip_levels(self) -> dict:
        """{"finest": the finest level of the full mip chain any pixel reads, "count": levels
        from it to one texel}."""
        side = max(self.facts.width, self.facts.height)
        finest = int(math.floor(math.log2(side / (self.max_texels or side))))
        full = int(math.floor(math.log2(side))) + 1
        return {"finest": finest, "count": max(1, full - finest)}

    @property
    def target_error(self) -> float | None:
        if self.screen_target is None or self.full is not None or not self.needed:
            return self.screen_target
        side = max(self.facts.width, self.facts.height)
        return texel_target(self.screen_target, self.pixels_per_texel, side / (self.max_texels or side))

    def coverage(self) -> dict | None:
        """The ``compress --coverage`` document, or None when every direction is needed (a
        stand-in keeps the view and the light nearest the normal)."""
        if self.stand_in:
            view, light = (int(np.argmin(d[:, 0])) for d in (self.facts.views, self.facts.lights))
            return {"format": COVERAGE_FORMAT, "views": [[float(t), float(p)] for t, p in self.facts.views[[view]]],
                    "lights": [[float(t), float(p)] for t, p in self.facts.lights[[light]]]}
        if self.full is not None or (len(self.views) == len(self.facts.views)
                                     and len(self.lights) == len(self.facts.lights)):
            return None
        return {"format": COVERAGE_FORMAT,
                "views": [[float(t), float(p)] for t, p in self.facts.views[self.views]],
                "lights": [[float(t), float(p)] for t, p in self.facts.lights[self.lights]]}

    def requirements(self) -> dict:
        """What the build of this material depends on (canonical, JSON): its SCons signature."""
        return {"needed": self.needed, "stand_in": self.stand_in, "coverage": self.coverage(),
                "max_texels": self.max_texels,
                "target_error": self.target_error}

    def sample_fraction(self) -> float:
        """Kept samples over measured samples."""
        if self.coverage() is None:
            return 1.0 if self.needed else 0.0
        return len(self.views) * len(self.lights) / (len(self.facts.views) * len(self.facts.lights))

    def report(self) -> dict:
        """The ``--json`` entry of this material."""
        return {"material": self.material, "needed": self.needed, "why_not": self.why_not,
                "stand_in": self.stand_in, "full": self.full,
                "prims": dict(self.prims), "frames_seen": self.frames, "surface_samples": self.samples,
                "views": {"kept": 1 if self.stand_in else len(self.views), "measured": len(self.facts.views)},
                "lights": {"kept": 1 if self.stand_in else len(self.lights), "measured": len(self.facts.lights)},
                "sample_fraction": self.sample_fraction(), "pixels_per_texel": self.pixels_per_texel,
                "texel_factor": self.factor, "max_texels": self.max_texels, "mip_levels": self.mip_levels,
                "screen_target_error": self.screen_target, "target_error": self.target_error,
                "coverage": self.coverage()}


def texel_target(screen_target: float, pixels_per_texel: float | None, factor: float) -> float:
    """The per-texel percent error target that meets ``screen_target`` on screen.

    Model: a pixel averages the (1 / d)^2 texels under it (d = pixels per texel after the
    box filter, ``pixels_per_texel * factor``); the compression errors of neighbouring texels
    are taken as uncorrelated, so the pixel's error is the texels' divided by 1 / d.  Where a
    texel covers one pixel or more the target is the screen's.  Capped at 100 %."""
    if pixels_per_texel is None:
        return screen_target
    d = min(1.0, pixels_per_texel * factor)
    return min(100.0, screen_target / max(d, 1e-12))


@dataclass
class _Shot:
    path: str
    camera: object
    near: float
    far: float


def _cameras(stage, time, width: int, meters: float) -> tuple[list, list]:
    """([_Shot], [problems]) of every UsdGeom.Camera at ``time``."""
    from pxr import Usd, UsdGeom

    from .scene import camera_prims, scene_camera

    shots, problems = [], []
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    for prim in camera_prims(stage):
        try:
            camera = scene_camera(prim, width, meters, time)
        except BTFError as exc:
            problems.append(str(exc))
            continue
        clip = UsdGeom.Camera(prim).GetCamera(code).clippingRange
        shots.append(_Shot(str(prim.GetPath()), camera, float(clip.min) * meters, float(clip.max) * meters))
    return shots, problems


def _in_frustum(points: np.ndarray, shot: _Shot) -> np.ndarray:
    """(T,) triangles (points (T, 3, 3) metres) not wholly outside one plane of the frustum."""
    cam = shot.camera
    local = (points - cam.eye) @ cam.basis().T            # x right, y up, z forward
    x, y, z = local[..., 0], local[..., 1], local[..., 2]
    tx = 0.5 * cam.width / cam.focal_px
    ty = 0.5 * cam.height / cam.focal_px
    outside = ((z < shot.near).all(axis=1) | (z > shot.far).all(axis=1)
               | (x > tx * z).all(axis=1) | (-x > tx * z).all(axis=1)
               | (y > ty * z).all(axis=1) | (-y > ty * z).all(axis=1))
    return ~outside


def _surface_samples(surface, shot: _Shot):
    """(triangle (n,), barycentrics (n, 3)) of the samples of one mesh seen by one camera:
    its covered pixel centres (own z-buffer) and the corners of its front-facing triangles
    inside the frustum (module docstring)."""
    from ...raster import rasterize
    from ...render.core import front_facing, perspective_weights

    cam = shot.camera
    keep = front_facing(surface, cam.eye) & _in_frustum(surface.points, shot)
    tris = np.flatnonzero(keep)
    if not len(tris):
        return np.zeros(0, np.int64), np.zeros((0, 3))
    xy, depth = cam.project(surface.points[tris])
    ahead = (depth > max(shot.near, 1e-9)).all(axis=1)
    corners_tri = np.repeat(tris, 3)
    corners_b = np.tile(np.eye(3), (len(tris), 1))
    corner_depth = depth.ravel()
    ahead_corner = corner_depth > 0
    parts_t, parts_b = [corners_tri[ahead_corner]], [corners_b[ahead_corner]]
    inner = tris[ahead]
    if len(inner):
        raster = rasterize(xy[ahead], -1.0 / depth[ahead], cam.width, cam.height)
        pix = np.flatnonzero(raster.tri.ravel() >= 0)
        local = raster.tri.ravel()[pix]
        py, px = np.divmod(pix, cam.width)
        parts_t.append(inner[local])
        parts_b.append(perspective_weights(xy[ahead][local], depth[ahead][local], px + 0.5, py + 0.5))
    return np.concatenate(parts_t), np.concatenate(parts_b)


def _snap(tri, vectors: np.ndarray) -> np.ndarray:
    """Indices of the measured directions the renderers interpolate ``vectors`` (n, 3) from: the
    one rule, :meth:`usdbtf.render.hemisphere.Triangulation.stencil` (the vertices of the
    triangle holding a direction, or of the nearest boundary edge outside the region, whose
    weight is above 1e-6, as ``inspect --validate``'s coverage check counts them)."""
    if not len(vectors):
        return np.zeros(0, np.int64)
    return np.flatnonzero(tri.stencil(vectors))


class _Accumulator:
    """One material's needs, gathered sample batch by sample batch."""

    def __init__(self, need: Need):
        from ...render.hemisphere import Triangulation

        self.need = need
        # A material built whole needs no directions (its sampling may not even be V x L).
        whole = need.full is not None
        self.views = None if whole else Triangulation.from_directions(need.facts.views, "view directions")
        self.lights = None if whole else Triangulation.from_directions(need.facts.lights, "light directions")
        self.view_set: set = set()
        self.light_set: set = set()
        self.frames: set = set()

    def add(self, surface, tri, b, shot: _Shot, lights, texels_per_metre: float | None, time) -> None:
        from ...camera import unit
        from ...render.core import point_frames

        p = np.einsum("nk,nkd->nd", b, surface.points[tri])
        normal, tangent, bitangent = point_frames(b, surface, tri)
        frame = np.stack([tangent, bitangent, normal], axis=1)                   # (n, 3, 3) rows
        to_eye = unit(shot.camera.eye - p)
        for light in (lights if self.views is not None else []):
            to_light, scale = light.at(p)
            local = np.einsum("nij,nj->ni", frame, to_light)
            lit = (scale > 0) & (local[:, 2] > 0)
            self.light_set.update(_snap(self.lights, local[lit]).tolist())
        if self.views is not None:
            self.view_set.update(_snap(self.views, np.einsum("nij,nj->ni", frame, to_eye)).tolist())
        depth = (p - shot.camera.eye) @ shot.camera.basis()[2]
        if texels_per_metre:
            ppt = float(shot.camera.focal_px / max(float(depth.min()), 1e-9) / texels_per_metre)
            self.need.pixels_per_texel = max(self.need.pixels_per_texel or 0.0, ppt)
        self.need.samples += len(tri)
        self.frames.add(time)

    def finish(self) -> Need:
        self.need.views = sorted(int(i) for i in self.view_set)
        self.need.lights = sorted(int(i) for i in self.light_set)
        self.need.frames = len(self.frames)
        if self.need.needed and not self.need.lights and self.need.full is None:
            # Seen, but never lit by a light above its horizon: black whatever the data; keep one
            # light (the nearest to the pole) so the partial material stays a V x L set.
            self.need.lights = [int(np.argmin(self.need.facts.lights[:, 0]))]
        return self.need


def _scene_target(prim, name: str) -> float | None:
    """The material's screen-space percent error target (``btf:build:targetError``), checked."""
    attr = prim.GetAttribute(name)
    if not attr or not attr.HasAuthoredValue():
        return None
    value = attr.Get()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < float(value) <= 100:
        raise BTFError(f"{prim.GetPath()}: {name} must be a percentage in (0, 100], got {value!r}")
    return float(value)


def _purpose_problem(prim) -> str | None:
    from pxr import UsdGeom

    purpose = UsdGeom.Imageable(prim).ComputePurpose()
    if purpose == UsdGeom.Tokens.proxy:
        return "proxy-only (purpose proxy: not in a final render)"
    if purpose == UsdGeom.Tokens.guide:
        return "guide-only (purpose guide: not rendered)"
    return None


def analyse(stage, materials: dict, facts: dict, *, target_error: float | None = None) -> dict:
    """{material: :class:`Need`} for ``stage`` (a composed Usd.Stage).

    materials : {material path: [prims bound to it]}; facts : {material path: :class:`MaterialFacts`}
    (materials without facts are skipped); target_error : screen-space percent error target
    (None: each material's ``btf:build:targetError``, else none).  Pure: reads the stage only."""
    from pxr import Usd, UsdGeom

    from ...mesh import load_prim
    from ...progress import track
    from ..density import mesh_density
    from ..material import NS
    from .scene import frame_times, render_resolution, scene_lights

    meters = float(UsdGeom.GetStageMetersPerUnit(stage))
    resolution = render_resolution(stage)
    width = resolution[0] if resolution else DEFAULT_WIDTH
    times = frame_times(stage)
    acc = {}
    for material in sorted(materials):
        if material not in facts:
            continue
        need = Need(material, facts[material])
        scene_target = _scene_target(stage.GetPrimAtPath(material), NS + "build:targetError")
        need.screen_target = target_error if target_error is not None else scene_target
        need.full = facts[material].whole
        acc[material] = _Accumulator(need)
    if not acc:
        return {}
    meshes: dict = {}
    seen_frames: dict = {}
    for time in track(times, "scene analysis (frames)", len(times), logger=log):
        shots, problems = _cameras(stage, time, width, meters)
        full_reason = ("; ".join(problems) + ": the scene's views are not analysed") if problems else \
            (None if shots else "the scene has no camera: every direction and texel is kept")
        lights = scene_lights(stage, time, "scene")
        code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
        # A frame that looks exactly like an earlier one (cameras, lights, every bound prim's
        # visibility and placement) reaches the same directions and densities: not sampled again.
        key = _frame_key(stage, shots, problems, lights, materials, code, time)
        if key in seen_frames:
            for a in acc.values():
                if seen_frames[key] in a.frames:
                    a.frames.add(time)
            continue
        seen_frames[key] = time
        for material, a in acc.items():
            for path in materials[material]:
                prim = stage.GetPrimAtPath(path)
                if not prim.IsA(UsdGeom.Gprim):
                    continue                  # an ancestor: its bound descendants are listed themselves
                status = a.need.prims.setdefault(path, "invisible at every frame")
                problem = _purpose_problem(prim)
                if problem is not None:
                    a.need.prims[path] = problem
                    continue
                if UsdGeom.Imageable(prim).ComputeVisibility(code) == UsdGeom.Tokens.invisible:
                    continue
                if status == "invisible at every frame":
                    a.need.prims[path] = "outside every camera's frustum, or facing away, at every frame"
                if full_reason is not None or not prim.IsA(UsdGeom.Mesh):
                    a.need.full = a.need.full or full_reason or f"{path} is a {prim.GetTypeName()}, not a Mesh: " \
                        "not analysed, every direction and texel is kept"
                    a.need.prims[path] = "seen"
                    continue
                mesh = _mesh_at(meshes, prim, time, load_prim)
                if mesh is None:
                    a.need.full = a.need.full or f"{path} has no texture coordinates: not analysed"
                    a.need.prims[path] = "seen"
                    continue
                surface, on_mesh = mesh
                # The coarser of the measured density and the one the mesh's own UVs give (conservative).
                known = [d for d in (a.need.facts.texels_per_metre,
                                     mesh_density(on_mesh, a.need.facts.width, a.need.facts.height)) if d]
                density = min(known) if known else None
                for shot in shots:
                    tri, b = _surface_samples(surface, shot)
                    if len(tri):
                        a.add(surface, tri, b, shot, lights, density, time)
                        a.need.prims[path] = "seen"
    return {material: a.finish() for material, a in acc.items()}


def _frame_key(stage, shots, problems, lights, materials: dict, code, time) -> bytes:
    """What decides a frame's samples, as bytes: every camera (placement, lens, frame, clipping),
    every light, and every bound prim's visibility, world transform and (when its points are
    animated) the time."""
    from pxr import UsdGeom

    parts = [repr(problems).encode()]
    for shot in shots:
        c = shot.camera
        parts.append(np.array([*c.eye, *c.target, *c.up, c.fov, c.width, c.height, shot.near, shot.far]).tobytes())
    for light in lights:
        parts.append(light.kind.encode() + np.array([*light.vector, light.intensity]).tobytes())
    cache = UsdGeom.XformCache(code)
    for path in sorted({p for prims in materials.values() for p in prims}):
        prim = stage.GetPrimAtPath(path)
        if not prim.IsA(UsdGeom.Gprim):
            continue
        parts.append(path.encode() + str(UsdGeom.Imageable(prim).ComputeVisibility(code)).encode()
                     + np.asarray(cache.GetLocalToWorldTransform(prim), np.float64).tobytes())
        if _animated(prim):
            parts.append(repr(time).encode())
    return b"\0".join(parts)


def _animated(prim) -> bool:
    """Whether any attribute of ``prim`` (points, normals, primvars...) may change over time."""
    return any(attr.ValueMightBeTimeVarying() for attr in prim.GetAttributes())


def _mesh_at(cache: dict, prim, time, load_prim):
    """(corner frames, mesh) of ``prim`` at ``time``, or None without texture coordinates;
    loaded once while neither its attributes nor its world transform change."""
    from pxr import Usd, UsdGeom

    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    xf = np.asarray(UsdGeom.XformCache(code).GetLocalToWorldTransform(prim), np.float64)
    key = (str(prim.GetPath()), xf.tobytes(), time if _animated(prim) else None)
    if key not in cache:
        mesh = load_prim(prim, time)
        cache[key] = None if mesh.uv is None else (mesh.corner_frames(), mesh)
    return cache[key]
