"""The CPU reference renderer: a mesh with a compressed BTF under point and distant lights.

Inputs are plain: a :class:`~usdbtf.compress.format.CompressedBTF`, a
:class:`~usdbtf.mesh.Mesh` with texture coordinates (its own tangent frames, or frames
computed from st: :meth:`~usdbtf.mesh.Mesh.corner_frames`), a :class:`~usdbtf.camera.Camera`
and lights.  Per visible pixel:

1. rasterise (z-buffer, back faces culled), perspective-correct barycentrics; triangles
   reaching behind the camera are dropped, not clipped (keep the camera outside the mesh);
2. interpolate position, normal, tangent, bitangent, st; orthonormalise the frame
   (x = tangent = image right, y = image up, z = normal, the rectified sample's axes);
3. local view and light directions in that frame; for each light its irradiance (1/d^2 for
   point lights) times ``1 / (pi W)`` (:mod:`usdbtf.photometry`: a light of irradiance
   ``pi W`` reproduces the measured values) and shadow-map visibility;
4. equation 2: 3 view x 3 light basis rows blended (:mod:`.shading`), then one dot with the
   k coefficients, filtered bilinearly or trilinearly over mip levels (:mod:`.texture`).

Output: a :class:`RenderResult`, (H, W, 4) float32 RGBA in the BTF's working colour space
(alpha = coverage); :func:`usdbtf.render.write_render` writes it as EXR and PNG.
Pixels are shaded in chunks on a thread pool (numpy releases the GIL in the heavy parts);
each chunk writes its own pixels, so the result does not depend on the thread count.

:func:`render_swatch` renders the measured patch itself: flat, orthographic, one pixel per
texel, one distant light -- the same shading path with constant directions.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..camera import Camera
from ..compress.format import CompressedBTF
from ..errors import BTFError
from ..mesh import CornerFrames, Mesh
from ..raster import barycentrics, rasterize
from .hemisphere import directions_to_vectors
from .scene import Light
from .shading import BasisInterpolator
from .shadows import ShadowMap
from .texture import CoefficientTexture, merge_needed
from ..numeric import single_blas_thread
from ..photometry import radiance_per_irradiance, white_level_of

__all__ = ["CHUNK_BYTES", "chunk_pixels", "RenderOptions", "RenderResult", "Renderer", "render", "render_parts", "render_scene", "render_swatch",
           "front_facing", "point_frames", "perspective_weights"]


@dataclass
class RenderOptions:
    """k : basis vectors used (default all); shadows : cast shadows; filter : "mip" (trilinear)
    or "bilinear"; wrap : texture wrap "repeat"/"clamp" (default repeat for a tileable quilt,
    else clamp); shadow_resolution : texels per side (default: the frame's larger side);
    threads; chunk : pixels per task (default None: :func:`chunk_pixels` of the k shaded)."""

    k: int | None = None
    shadows: bool = True
    filter: str = "mip"
    wrap: str | None = None
    shadow_resolution: int | None = None
    threads: int = 2
    chunk: int | None = None

    def validate(self, cbtf: CompressedBTF) -> None:
        if self.k is not None and not 1 <= self.k <= cbtf.k:
            raise BTFError(f"--k must be in 1..{cbtf.k}, got {self.k}")
        if self.filter not in ("mip", "bilinear"):
            raise BTFError(f"filter must be 'mip' or 'bilinear', got {self.filter!r}")
        if self.wrap not in (None, "repeat", "clamp"):
            raise BTFError(f"wrap must be 'repeat' or 'clamp', got {self.wrap!r}")


#: What one shading task's arrays may hold (bytes), :func:`chunk_pixels`.
CHUNK_BYTES = 16 * 2**20
#: Pixels per task at most (and at least): few tasks for a low k, not one per pixel for a high one.
_CHUNK_RANGE = (1024, 16384)


def chunk_pixels(k: int) -> int:
    """Pixels per shading task for ``k`` coefficients: each task holds about five float32
    arrays of (pixels, k) values (a filter tap's (pixels, 3, k) coefficients, the blended
    rows and their copies), so a fixed pixel count grows with k: 16,384 pixels at k 242 held
    ~110 MB a task, and the 256² thumbnail that ``compress --max-bytes`` renders for each
    packaging it measures peaked 0.33-0.38 GB above what rate control held (issue 42's
    1.2 GB).  Sized so a task's arrays stay near :data:`CHUNK_BYTES`, clipped to
    :data:`_CHUNK_RANGE`; the pixels a task shades are computed the same at any chunk size."""
    lo, hi = _CHUNK_RANGE
    return int(min(hi, max(lo, CHUNK_BYTES // (5 * 4 * max(int(k), 1)))))


def default_wrap(cbtf: CompressedBTF) -> str:
    """Repeat for a tileable quilt (it wraps seamlessly), clamp otherwise."""
    q = cbtf.info.get("quilt") or {}
    return "repeat" if (q.get("options") or {}).get("tileable") else "clamp"


class Renderer:
    """Everything that depends on the BTF only (texture, basis, triangulations): build once,
    render many frames.  ``texel_map`` (H, W), optional: the texture is ``cbtf``'s texels
    gathered through it (:class:`~.texture.CoefficientTexture`; a quilt as its source texels)."""

    def __init__(self, cbtf: CompressedBTF, opts: RenderOptions | None = None, *, texel_map=None):
        self.opts = opts or RenderOptions()
        self.opts.validate(cbtf)
        k = self.opts.k or cbtf.k
        self.cbtf = cbtf
        self.interp = BasisInterpolator(cbtf, k)
        self.domain = cbtf.domain
        self.texture = CoefficientTexture(cbtf, k, self.opts.wrap or default_wrap(cbtf), texel_map)
        # usdbtf.photometry: radiance = value x irradiance / (pi W).
        self.white_level = white_level_of(cbtf.info, "source_metadata.white_level")
        self.radiance_per_irradiance = radiance_per_irradiance(self.white_level)

    # -- swatch ------------------------------------------------------------------------
    def swatch(self, view_deg, light_deg, intensity: float | None = None) -> np.ndarray:
        """(H, W, 3) float32 working-space image of the flat patch, one pixel per texel, under a
        distant light of irradiance ``intensity`` (None: the capture light, ``pi W``, which
        reproduces the measured values)."""
        # The capture light's pi W times 1 / (pi W) is 1 exactly (not 1 - 1 ulp).
        intensity = 1.0 if intensity is None else float(intensity) * self.radiance_per_irradiance
        H, W = self.texture.height, self.texture.width
        j, i = np.meshgrid(np.arange(W), np.arange(H))
        st = np.stack([(j.ravel() + 0.5) / W, 1.0 - (i.ravel() + 0.5) / H], axis=1)
        # The tiles every chunk reads, made in one pass over the pages (not one per chunk).
        self.texture.hold(self._needed(len(st), lambda sl: (None, st[sl], None)))
        view = self.interp.view_weights(directions_to_vectors([view_deg]))
        light = self.interp.light_weights(directions_to_vectors([light_deg]))
        if self.domain.is_linear:
            rows = self.interp.accumulate(np.zeros((1, self.interp.k), np.float32), view, light, intensity)
            out = self._shade_chunks(len(st), lambda sl: self.texture.shade(np.repeat(rows, sl.stop - sl.start, 0),
                                                                            st[sl]))
            return out.reshape(H, W, 3)
        rows, after = self._domain_rows(view, light, np.full(1, intensity))
        out = self._shade_chunks(len(st), lambda sl: self.domain.inverse(
            self.texture.shade(np.repeat(rows, sl.stop - sl.start, 0), st[sl])) * np.float32(after[0]))
        return out.reshape(H, W, 3)

    def _domain_rows(self, view, light, scale):
        """Blended rows (n, k) and the factor (n,) that multiplies after the inverse curve, in a
        non-linear working domain: rows blend with weights that sum to 1, while the light's
        intensity (shadowing included) and its fade beyond the measured region -- both
        radiance factors -- scale the scene-linear result."""
        il, wl = light
        fade = wl.sum(axis=1)
        norm = np.where(fade > 0, fade, 1.0)
        rows = self.interp.accumulate(np.zeros((len(il), self.interp.k), np.float32), view, (il, wl / norm[:, None]))
        return rows, (np.asarray(scale, np.float64) * fade).astype(np.float32)

    # -- mesh --------------------------------------------------------------------------
    def render(self, mesh: Mesh, camera: Camera, lights: list[Light]) -> np.ndarray:
        """(H, W, 4) float32 RGBA, working space."""
        return render_parts([(self, mesh)], camera, lights)

    def _slices(self, n: int) -> list[slice]:
        """The chunks of ``n`` pixels shaded as one task each."""
        step = self.opts.chunk or chunk_pixels(self.interp.k)
        return [slice(a, min(a + step, n)) for a in range(0, n, step)]

    def _shade_chunks(self, n: int, fn) -> np.ndarray:
        slices = self._slices(n)
        if self.opts.threads > 1 and len(slices) > 1:
            with ThreadPoolExecutor(self.opts.threads) as pool:
                parts = list(pool.map(fn, slices))
        else:
            parts = [fn(sl) for sl in slices]
        return np.concatenate(parts) if parts else np.zeros((0, 3), np.float32)

    def _texture_coords(self, surface, tri, tri_xy, tri_depth, x, y):
        """(barycentrics (n, 3), st (n, 2), lod (n,) or None) of pixel points (x, y) on triangles ``tri``."""
        b = perspective_weights(tri_xy, tri_depth, x, y)
        st = np.einsum("nk,nkd->nd", b, surface.uv[tri])
        lod = self._lod(tri_xy, tri_depth, surface.uv[tri], st, x, y) if self.opts.filter == "mip" else None
        return b, st, lod

    def _needed(self, n: int, coords) -> dict:
        """The texture tiles (:meth:`~.texture.CoefficientTexture.needed`) that shading ``n``
        pixels reads, ``coords(slice)`` giving a chunk's :meth:`_texture_coords` (the chunks
        :meth:`_shade_chunks` shades, so the same st and lod, bit for bit)."""
        return merge_needed(*(self.texture.needed(*coords(sl)[1:]) for sl in self._slices(n)))

    def _shade_pixels(self, surface, camera, lights, shadow_maps, tri, tri_xy, tri_depth, x, y) -> np.ndarray:
        b, st, lod = self._texture_coords(surface, tri, tri_xy, tri_depth, x, y)
        p = np.einsum("nk,nkd->nd", b, surface.points[tri])
        normal, tangent, bitangent = point_frames(b, surface, tri)
        to_eye = camera.eye - p
        to_eye /= np.linalg.norm(to_eye, axis=1, keepdims=True)
        frame = np.stack([tangent, bitangent, normal], axis=1)                   # (n, 3, 3) rows
        view = self.interp.view_weights(np.einsum("nij,nj->ni", frame, to_eye))
        rows = np.zeros((len(tri), self.interp.k), np.float32)
        out = None if self.domain.is_linear else np.zeros((len(tri), 3), np.float32)
        for light, smap in zip(lights, shadow_maps):
            to_light, scale = light.at(p)
            scale = scale * self.radiance_per_irradiance
            if smap is not None:
                scale = scale * smap.visibility(p, normal)
            lit = np.flatnonzero(scale > 0)
            if not len(lit):
                continue
            lw = self.interp.light_weights(np.einsum("nij,nj->ni", frame[lit], to_light[lit]))
            vw = (view[0][lit], view[1][lit])
            if out is not None:     # a curve: each light's radiance separately, after the inverse
                sub, after = self._domain_rows(vw, lw, scale[lit])
                d = self.texture.shade(sub, st[lit], None if lod is None else lod[lit])
                out[lit] += self.domain.inverse(d) * after[:, None]
                continue
            sub = np.zeros((len(lit), self.interp.k), np.float32)
            self.interp.accumulate(sub, vw, lw, scale[lit])
            rows[lit] += sub
        return self.texture.shade(rows, st, lod) if out is None else out

    def _lod(self, tri_xy, tri_depth, tri_st, st, x, y) -> np.ndarray:
        """log2 of the texel footprint of one pixel: st at the next pixel right and below,
        from the same triangle's (extended) interpolation."""
        size = np.array([self.texture.width, self.texture.height], np.float64)
        dx = (np.einsum("nk,nkd->nd", perspective_weights(tri_xy, tri_depth, x + 1, y), tri_st) - st) * size
        dy = (np.einsum("nk,nkd->nd", perspective_weights(tri_xy, tri_depth, x, y + 1), tri_st) - st) * size
        foot = np.maximum(np.hypot(dx[:, 0], dx[:, 1]), np.hypot(dy[:, 0], dy[:, 1]))
        return np.log2(np.maximum(foot, 1e-12))


def render_parts(parts: list, camera: Camera, lights: list[Light]) -> np.ndarray:
    """(H, W, 4) float32 RGBA, working space, of several meshes each with its own material.

    parts : [(:class:`Renderer`, :class:`~usdbtf.mesh.Mesh`)], meshes in world space (metres).
    One z-buffer over every part's triangles, so parts occlude each other; each pixel is
    shaded by its part's renderer (the first part's options decide shadows and their
    resolution), and every part casts shadows on every part."""
    if not lights:
        raise BTFError("give at least one --light")
    opts = parts[0][0].opts
    surfaces = [mesh.corner_frames() for _, mesh in parts]
    points = np.concatenate([s.points for s in surfaces])
    owner = np.repeat(np.arange(len(parts)), [len(s.points) for s in surfaces])
    front = np.concatenate([front_facing(s, camera.eye) for s in surfaces])
    xy, depth = camera.project(points)
    near = 1e-6 * max(float(np.ptp(points.reshape(-1, 3), axis=0).max()), 1e-9)
    keep = front & (depth > near).all(axis=1)
    tris = np.flatnonzero(keep)
    raster = rasterize(xy[tris], -1.0 / depth[tris], camera.width, camera.height)
    pix = np.flatnonzero(raster.tri.ravel() >= 0)
    image = np.zeros((camera.height, camera.width, 4), np.float32)
    if not len(pix):
        return image
    tri = tris[raster.tri.ravel()[pix]]
    res = opts.shadow_resolution or max(camera.width, camera.height)
    shadow_maps = [ShadowMap(points, light, res) if opts.shadows else None for light in lights]
    flat = image.reshape(-1, 4)
    first = np.cumsum([0] + [len(s.points) for s in surfaces])
    jobs, needed = [], {}
    for n, ((renderer, _), surface) in enumerate(zip(parts, surfaces)):
        mine = owner[tri] == n
        if not mine.any():
            continue
        own_pix, own_tri = pix[mine], tri[mine]
        local = own_tri - first[n]
        py, px = np.divmod(own_pix, camera.width)

        def args(sl, surface=surface, local=local, own_tri=own_tri, px=px, py=py):
            return surface, local[sl], xy[own_tri[sl]], depth[own_tri[sl]], px[sl] + 0.5, py[sl] + 0.5

        jobs.append((renderer, own_pix, args))
        coords = (lambda sl, a=args, r=renderer: r._texture_coords(*a(sl)))
        needed.setdefault(id(renderer), []).append(renderer._needed(len(own_pix), coords))
    # Each material decodes the texture tiles its pixels sample, in every part it is bound to,
    # in one pass over its pages, before any is shaded (issue 39); it drops the tiles it held
    # for an earlier frame and no longer needs.
    for renderer in {id(r): r for r, _, _ in jobs}.values():
        renderer.texture.hold(merge_needed(*needed[id(renderer)]))
    for renderer, own_pix, args in jobs:
        def task(sl, renderer=renderer, args=args):
            surface, *rest = args(sl)
            return renderer._shade_pixels(surface, camera, lights, shadow_maps, *rest)

        flat[own_pix, :3] = renderer._shade_chunks(len(own_pix), task)
        flat[own_pix, 3] = 1.0
    return image


def perspective_weights(tri_xy, tri_depth, x, y) -> np.ndarray:
    """(n, 3) perspective-correct barycentrics at pixel points (x, y)."""
    b = barycentrics(tri_xy, x, y) / tri_depth
    return b / b.sum(axis=1, keepdims=True)


def point_frames(b, surface: CornerFrames, tri):
    """Orthonormal (normal, tangent, bitangent) per point: the interpolated normal, the tangent
    made perpendicular to it, bitangent = normal x tangent (flipped for mirrored texture)."""
    n = np.einsum("nk,nkd->nd", b, surface.normals[tri])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    t = np.einsum("nk,nkd->nd", b, surface.tangents[tri])
    t -= n * np.einsum("nd,nd->n", t, n)[:, None]
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-300)
    bt = np.cross(n, t)
    given = np.einsum("nk,nkd->nd", b, surface.bitangents[tri])
    bt *= np.where(np.einsum("nd,nd->n", bt, given) < 0, -1.0, 1.0)[:, None]
    return n, t, bt


def front_facing(surface: CornerFrames, eye: np.ndarray) -> np.ndarray:
    """(T,) triangles facing the eye; a triangle's side is the one its vertex normals point to
    (so the result does not depend on the winding order)."""
    c = surface.points
    g = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    g *= np.where(np.einsum("td,td->t", g, surface.normals.sum(axis=1)) < 0, -1.0, 1.0)[:, None]
    return np.einsum("td,td->t", g, eye - c[:, 0]) > 0


@dataclass
class RenderResult:
    """A rendered frame: ``image`` (H, W, 4) float32 RGBA (alpha = coverage; (H, W, 3) for a
    swatch) in ``working_space`` of ``ocio_config`` (None: the default config)."""

    image: np.ndarray
    working_space: str
    ocio_config: str | None = None


@single_blas_thread
def render(cbtf: CompressedBTF, mesh: Mesh, camera: Camera, lights: list[Light],
           options: RenderOptions | None = None) -> RenderResult:
    """One frame of ``mesh`` with ``cbtf`` under ``lights`` (see the module docstring)."""
    return RenderResult(Renderer(cbtf, options).render(mesh, camera, lights), cbtf.working_space, cbtf.ocio_config)


@single_blas_thread
def render_scene(parts: list, camera: Camera, lights: list[Light], options: RenderOptions | None = None
                 ) -> RenderResult:
    """One frame of several meshes, each with its own compressed BTF: ``parts`` [(cbtf, mesh)]
    (a material bound to several meshes: the same cbtf object in several parts).  Every mesh
    hides and shadows the others (:func:`render_parts`: one z-buffer, each material shades the
    pixels where its own triangles are in front)."""
    if not parts:
        raise BTFError("no mesh to render")
    spaces = {(cbtf.working_space, cbtf.ocio_config) for cbtf, _ in parts}
    if len(spaces) > 1:
        raise BTFError(f"the materials are in different working colour spaces ({sorted(spaces)}); "
                       "one frame needs one")
    renderers = {}
    for cbtf, _ in parts:
        renderers.setdefault(id(cbtf), Renderer(cbtf, options))
    image = render_parts([(renderers[id(cbtf)], mesh) for cbtf, mesh in parts], camera, lights)
    working_space, ocio_config = spaces.pop()
    return RenderResult(image, working_space, ocio_config)


@single_blas_thread
def render_swatch(cbtf: CompressedBTF, view_deg, light_deg, options: RenderOptions | None = None) -> RenderResult:
    """The flat patch at (view, light) degrees, one pixel per texel: (H, W, 3) float32."""
    return RenderResult(Renderer(cbtf, options).swatch(view_deg, light_deg), cbtf.working_space, cbtf.ocio_config)
