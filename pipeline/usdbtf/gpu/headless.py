"""The shared GLSL on a real OpenGL driver without a window (Mesa llvmpipe through EGL).

usd-core has no Hydra, so this is how the Storm/MaterialX shading code is run: the same
``btf_core.glsl`` inside :func:`usdbtf.gpu.shaders.harness_fragment`, fed the textures
packaging writes, under the CPU renderer's scene model (:class:`usdbtf.mesh.Mesh`,
:class:`usdbtf.camera.Camera`, :mod:`usdbtf.render.scene` lights: white point and distant
lights, irradiance in the convention of :mod:`usdbtf.photometry`: a light of irradiance
``pi * white_level`` reproduces the measured values).

    >>> from usdbtf.gpu.headless import HeadlessRenderer
    >>> gl = HeadlessRenderer(gpu_layout(cbtf))            # or layout_from_asset("a.usda")
    >>> img = gl.swatch((30, 60), (45, 0))                  # (H, W, 3) working space
    >>> rgba = gl.render(mesh, camera, [light])             # (H, W, 4)

Images are top row first, like the CPU renderer's; textures are uploaded as float32
(normalised codes for PNG packs, exactly what a GPU's unorm read returns) and filtered
bilinearly on level 0, the CPU renderer's ``filter="bilinear"``.
"""
from __future__ import annotations

import numpy as np

from ..errors import BTFError
from ..mesh import Mesh
from ..photometry import capture_irradiance, check_white_level
from . import shaders
from .tables import MAX_PAGES, GpuLayout, with_wrap

__all__ = ["HeadlessRenderer", "create_context", "psnr", "uv_sphere"]

_MAX_CODE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}


def create_context():
    """A standalone OpenGL 3.3+ context on EGL (no display needed)."""
    try:
        import moderngl
    except ImportError:
        raise BTFError("the headless GPU check needs the moderngl package (pip install moderngl)") from None
    try:
        return moderngl.create_context(standalone=True, backend="egl")
    except Exception as exc:  # moderngl/glcontext raise plain Exceptions for a missing EGL
        raise BTFError(f"cannot create a headless OpenGL context through EGL: {' '.join(str(exc).split())}") from None


def psnr(image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Peak signal-to-noise ratio in dB of ``image`` against ``reference`` (same shape,
    (H, W, C) linear values), the peak being the reference's largest value; ``mask`` (H, W)
    restricts it to those pixels.  inf for identical images."""
    a = np.asarray(image, np.float64)
    b = np.asarray(reference, np.float64)
    if mask is not None:
        a, b = a[mask], b[mask]
    mse = float(np.mean((a - b) ** 2)) if a.size else 0.0
    peak = float(b.max()) if b.size else 0.0
    if mse == 0.0:
        return float("inf")
    return 10.0 * np.log10(max(peak, 1e-30) ** 2 / mse)


def uv_sphere(radius: float, columns: int = 48, rows: int = 24) -> Mesh:
    """A UV sphere (Y up, metres): st = (longitude, latitude), tangent = +s, bitangent = +t
    (the sample's image axes)."""
    s, t = np.meshgrid(np.linspace(0, 1, columns + 1), np.linspace(0, 1, rows + 1))
    phi, theta = 2 * np.pi * s, np.pi * t
    normal = np.stack([np.sin(theta) * np.cos(phi), -np.cos(theta), -np.sin(theta) * np.sin(phi)], -1)
    tangent = np.stack([-np.sin(phi), np.zeros_like(phi), -np.cos(phi)], -1)
    a = (np.arange(rows)[:, None] * (columns + 1) + np.arange(columns)[None]).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + columns + 2], 1), np.stack([a, a + columns + 2, a + columns + 1], 1)])
    flat = [x.reshape(-1, x.shape[-1]) for x in (normal * radius, np.stack([s, t], -1), normal, tangent,
                                                  np.cross(normal, tangent))]
    return Mesh(flat[0], faces, uv=flat[1], normals=flat[2], tangents=flat[3], bitangents=flat[4],
                name="uv_sphere", source="uv_sphere")


def _normalised(pixels: np.ndarray) -> np.ndarray:
    """Stored codes as a GPU reads them: unorm for integers, as-is for halves."""
    scale = _MAX_CODE.get(np.dtype(pixels.dtype))
    out = pixels.astype(np.float32)
    return out / scale if scale else out


def _clip_space(camera, points: np.ndarray) -> np.ndarray:
    """(n, 3) world points -> (n, 4) clip coordinates of ``camera`` (usdbtf.camera.Camera):
    the same pinhole projection as the CPU renderer, with w = depth along the view axis."""
    cam = (points - camera.eye) @ camera.basis().T
    depth = cam[:, 2]
    near = max(float(depth[depth > 0].min()) * 0.5, 1e-6) if (depth > 0).any() else 1e-3
    far = max(float(depth.max()) * 2.0, near * 4.0)
    focal = camera.focal_px
    clip = np.empty((len(points), 4))
    clip[:, 0] = 2.0 * focal / camera.width * cam[:, 0]
    clip[:, 1] = 2.0 * focal / camera.height * cam[:, 1]
    clip[:, 2] = depth * (far + near) / (far - near) - 2.0 * far * near / (far - near)
    clip[:, 3] = depth
    return clip


class HeadlessRenderer:
    """Renders a :class:`~usdbtf.gpu.tables.GpuLayout` with the shared shader.

    wrap : "clamp" or "repeat" for the coefficient packs (the CPU renderer's ``wrap``; the
    shader filters them itself, as in Storm: the tables say which).
    """

    def __init__(self, layout: GpuLayout, wrap: str = "clamp", ctx=None, white_level: float = 1.0):
        import moderngl

        layout = with_wrap(layout, wrap)
        self.layout = layout
        self.ctx = ctx or create_context()
        self.program = self.ctx.program(vertex_shader=shaders.HARNESS_VERTEX,
                                        fragment_shader=shaders.harness_fragment())
        rows, width = layout.tables.shape[:2]
        # Bottom row first, as Storm and MaterialX upload every image (btfFetch counts from the top).
        self.tables = self.ctx.texture((width, rows), 4,
                                       np.ascontiguousarray(layout.tables[::-1], np.float32).tobytes(), dtype="f4")
        self.tables.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.pages = []
        for pixels in layout.slots():           # coefficient pages, then the basis page's slot
            if pixels is None:
                self.pages.append(None)
                continue
            h, w = pixels.shape[:2]
            # Image row 0 is the top (t = 1); GL's first row is t = 0 (as Storm uploads it).
            tex = self.ctx.texture((w, h), 4, np.ascontiguousarray(_normalised(pixels)[::-1]).tobytes(), dtype="f4")
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)       # read with texelFetch only
            self.pages.append(tex)
        self.empty = self.ctx.texture((1, 1), 4, np.zeros(4, np.float32).tobytes(), dtype="f4")
        self.program["uTables"].value = 0
        # usdbtf.photometry: radiance = value x irradiance / (pi W).
        self.white_level = check_white_level(white_level)
        self.program["uWhiteLevel"].value = self.white_level
        for p in range(MAX_PAGES):
            self.program[shaders.page_sampler(p)].value = p + 1

    # -- drawing -------------------------------------------------------------------------
    def _draw(self, width: int, height: int, clip, p, n, t, b, st, eye, lights, k) -> np.ndarray:
        if len(lights) > shaders.HARNESS_MAX_LIGHTS:
            raise BTFError(f"the headless renderer takes at most {shaders.HARNESS_MAX_LIGHTS} lights")
        data = np.concatenate([clip, p, n, t, b, st], axis=1).astype(np.float32)
        vbo = self.ctx.buffer(np.ascontiguousarray(data).tobytes())
        vao = self.ctx.vertex_array(self.program, [(vbo, "4f 3f 3f 3f 3f 2f", "aClip", "aP", "aN", "aT", "aB", "aSt")])
        color = self.ctx.renderbuffer((width, height), 4, dtype="f4")
        depth = self.ctx.depth_renderbuffer((width, height))
        fbo = self.ctx.framebuffer(color_attachments=[color], depth_attachment=depth)
        try:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            self.ctx.enable(self.ctx.DEPTH_TEST)
            self.tables.use(0)
            for i in range(MAX_PAGES):
                (self.pages[i] if self.pages[i] is not None else self.empty).use(i + 1)
            light_vec = np.zeros((shaders.HARNESS_MAX_LIGHTS, 4), np.float32)
            light_int = np.zeros(shaders.HARNESS_MAX_LIGHTS, np.float32)
            for i, (vec, w, intensity) in enumerate(lights):
                light_vec[i] = [*vec, w]
                light_int[i] = intensity
            self.program["uLight"].write(light_vec.tobytes())
            self.program["uIntensity"].write(light_int.tobytes())
            self.program["uLightCount"].value = len(lights)
            self.program["uEye"].value = tuple(float(x) for x in eye)
            self.program["uBasisCount"].value = int(self.layout.k if k is None else k)
            vao.render()
            raw = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32)
        finally:
            for obj in (vao, vbo, fbo, color, depth):
                obj.release()
        return raw.reshape(height, width, 4)[::-1].copy()

    def swatch(self, view_deg, light_deg, intensity: float | None = None, k: int | None = None) -> np.ndarray:
        """(H, W, 3) float32: the flat patch, one pixel per texel, one distant light of
        irradiance ``intensity`` (None: the capture light, ``pi W``; the CPU renderer's
        :meth:`~usdbtf.render.core.Renderer.swatch`)."""
        intensity = capture_irradiance(self.white_level) if intensity is None else intensity
        from ..render.hemisphere import directions_to_vectors

        h, w = (int(x) for x in self.layout.tables.reshape(-1, 4)[3, 2:0:-1])     # tile height, width
        corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, -1], [1, 1], [-1, 1]], np.float64)
        n = len(corners)
        clip = np.c_[corners, np.zeros(n), np.ones(n)]
        st = (corners + 1.0) / 2.0
        frame = [np.tile(v, (n, 1)) for v in ([0.0, 0, 1], [1.0, 0, 0], [0.0, 1, 0])]
        view = directions_to_vectors([view_deg])[0]
        light = directions_to_vectors([light_deg])[0]
        out = self._draw(w, h, clip, np.zeros((n, 3)), *frame, st, [*view, 0.0], [(light, 0.0, intensity)], k)
        return out[:, :, :3]

    def render(self, mesh: Mesh, camera, lights, k: int | None = None) -> np.ndarray:
        """(H, W, 4) float32 RGBA of ``mesh`` (with texture coordinates; frames its own or
        computed, :meth:`~usdbtf.mesh.Mesh.corner_frames`) seen by ``camera``
        (usdbtf.camera.Camera) under ``lights`` (render.scene.Light), alpha = coverage; no shadows."""
        surface = mesh.corner_frames()
        corners = surface.points.reshape(-1, 3)
        attrs = [a.reshape(-1, a.shape[-1]) for a in (surface.normals, surface.tangents, surface.bitangents,
                                                      surface.uv)]
        lights_gl = [(lt.vector, 1.0 if lt.kind == "point" else 0.0, lt.intensity) for lt in lights]
        return self._draw(camera.width, camera.height, _clip_space(camera, corners), corners, *attrs,
                          [*camera.eye, 1.0], lights_gl, k)

    def release(self) -> None:
        for tex in [self.tables, self.empty, *(page for page in self.pages if page is not None)]:
            tex.release()
        self.program.release()
