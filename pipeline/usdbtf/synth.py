"""Procedural synthetic BTFs: tileable heightfield materials rendered over any sampling.

No measured BTF data ships with the project, so this module makes stand-ins that have
the properties real BTFs are about: a material sample is a tileable heightfield with
per-texel reflectance, rendered as a rectified image per (view, light) pair with

* masking / parallax: texel ``(i, j)`` of an image shows the first heightfield point
  hit by the viewing ray through that texel's point on the reference plane;
* cast shadows: per-texel visibility of the light (horizon test along the light's
  azimuth, slightly softened);
* foreshortening: the ``max(n.l, 0)`` term with ``n`` the heightfield normal;
* a GGX specular lobe, an optional sheen ("fuzz") lobe and an optional
  retro-reflective lobe;
* an optional normal map (extra slopes) for facets smaller than the heightfield
  resolves, e.g. metallic flakes.

Everything is pure numpy and deterministic: the same ``(preset, size, seed)`` gives
bit-identical arrays.

Conventions (shared with :mod:`usdbtf.sampling`)
-----------------------------------------------
* Directions at interfaces are ``(theta, phi)`` in degrees: ``theta`` from the normal,
  ``phi`` the azimuth in the sample's tangent frame, x = image right, y = image up,
  z = normal.  Both view and light directions point *away* from the surface (towards
  the camera / the light).
* Images and texture maps are arrays indexed ``[row, col]``; row 0 is the TOP of the
  image.  Texel ``(i, j)`` has its centre at surface position ``x = j``, ``y = -i``
  (texel units), so +x is increasing column and +y is *decreasing* row.
* Heights are in texel units (``height == 3`` is three texel widths tall).
* Reference plane: ``z = 0`` is the **mean** of ``material.height`` (the absolute
  offset of a material's heights is irrelevant).  A point above the plane seen from
  view ``v`` lands, in the rectified image, at ``p - h * tan(theta_v) * (cos phi_v,
  sin phi_v)``, i.e. displaced *away* from the camera; equivalently the hit map of
  texel ``p`` points ``+h * tan(theta_v) * (cos phi_v, sin phi_v)`` from ``p`` (see
  :class:`ViewHits`).
* Radiance: scene-linear, linear Rec.709 primaries.  The distant light has irradiance
  :data:`IRRADIANCE` ``= 0.8 * pi`` on a plane facing it, so a white Lambertian surface
  lit head-on reads exactly 0.8.  Specular peaks may exceed 1.
* ``Material.roughness`` is the **GGX alpha** (``alpha = r**2`` for a UsdPreviewSurface
  / Disney perceptual roughness ``r``); ``Material.specular`` is the Fresnel
  reflectance at normal incidence F0; towards grazing it rises along Schlick's
  curve for a dielectric (exact for F0 = 0.04), scaled so 0 disables the lobe.
  Alpha is clamped to :data:`MIN_ALPHA` when rendering.
* Directions are clamped to ``theta <= MAX_THETA_DEG`` (89 deg) when rendering.

How an image is made
--------------------
1. Per distinct view (cached, :meth:`RenderCache.hits`): every texel's ray is marched
   down from above the highest point in steps of <= 1/2 texel (horizontal and
   vertical), the first sign change of ``z_ray - h`` is bracketed and refined
   (Illinois regula falsi).  Heights are looked up bilinearly with wrap-around.
   Normals (central differences, wrap), albedo, F0 and alpha are then gathered at
   the hit points.
2. Per distinct light (cached, :meth:`RenderCache.shadow`): for each heightfield texel,
   the steepest elevation of the heightfield seen towards the light's azimuth
   (1/2-texel steps, as far as any height could still occlude) is compared with the
   light's elevation; visibility = smoothstep over +-SHADOW_SOFTNESS_DEG.
3. Per (view, light): visibility is looked up bilinearly at the view's hit points and

       L = E * vis * max(n.l, 0) * (albedo/pi + F*D*V + sheen * albedo * D_s * V_s
                                    + retro * albedo * (p + 2) / (2 pi) * max(v.l, 0)^p * (1 - n.v))

   with GGX D, height-correlated Smith V, the Fresnel F above, and the Charlie sheen
   distribution D_s (roughness 0.5) with Neubelt's V_s: a lobe that brightens the
   surface when view and light are grazing and is zero head-on.  The retro lobe
   (exponent p = :data:`RETRO_EXPONENT`) peaks when the light sits behind the camera
   and grows as the view grazes the surface, as light scattered back along fibres
   seen from the side does (velvet: dark head-on, bright towards the rim).  No extra 1/cos(theta_v):
   rectified images are radiance per unit area of the sample.
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np

from .sampling import Sampling
from .numeric import single_blas_thread

__all__ = [
    "Material",
    "PRESETS",
    "make_material",
    "RenderCache",
    "ViewHits",
    "trace_view",
    "shadow_map",
    "render_sample",
    "render_samples",
    "render_all",
    "SynthOptions",
    "SynthResult",
    "synth",
    "write_synth",
    "IRRADIANCE",
    "MAX_THETA_DEG",
    "MIN_ALPHA",
    "SHADOW_SOFTNESS_DEG",
    "RETRO_EXPONENT",
]

#: Irradiance of the distant light on a plane facing it.  0.8 * pi makes a white
#: Lambertian (albedo 1, BRDF 1/pi) lit head-on read 0.8, leaving headroom below 1.0
#: for 8-bit encodings so that only specular peaks clip.
IRRADIANCE = 0.8 * math.pi
#: Directions are clamped to this polar angle; at 90 deg the marches would be unbounded.
MAX_THETA_DEG = 89.0
#: Smallest GGX alpha used when shading (smaller would make the lobe a sub-texel spike).
MIN_ALPHA = 0.02
#: Exponent p of the retro-reflective lobe max(v.l, 0)^p: about 35 deg to half maximum.
RETRO_EXPONENT = 6.0
#: Half-width of the shadow penumbra, as an angle between the light's elevation and
#: the horizon's (a small area light); keeps shadow edges from aliasing.
SHADOW_SOFTNESS_DEG = 2.5

_F32 = np.float32


# --------------------------------------------------------------------------- material


@dataclass(frozen=True, eq=False)
class Material:
    """A tileable heightfield material; N is the texture size in texels.

    Attributes
    ----------
    height : (N, N) float32, texel units; the texture wraps in both axes.
    albedo : (N, N, 3) float32 in [0, 1], linear Rec.709 diffuse albedo.
    specular : (N, N) float32 in [0, 1], Fresnel reflectance at normal incidence (F0)
        of the GGX lobe, ~0.04 for a dielectric; 0 disables the lobe.
    roughness : (N, N) float32 > 0, GGX alpha (not perceptual roughness).
    sheen : weight of the sheen ("fuzz") lobe, tinted by the albedo; 0 disables it.
    name : free text, e.g. the preset name.
    retro : weight of the retro-reflective lobe, tinted by the albedo; 0 disables it.
    slope : None, or (N, N, 2) float32 extra surface slopes (dh/dx, dh/dy), added to the
        heightfield's own where normals are computed: a normal map for facets below the
        heightfield's resolution (flakes).  It tilts the shading only, never the geometry
        that masks and shadows.

    The arrays are copied on construction and made read-only, so renders and caches
    made from a Material stay valid.  ``eq=False``: materials compare by identity.
    """

    height: np.ndarray
    albedo: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    sheen: float = 0.0
    name: str = ""
    retro: float = 0.0
    slope: np.ndarray | None = None

    def __post_init__(self):
        height = np.array(self.height, dtype=_F32)
        if height.ndim != 2 or height.shape[0] != height.shape[1] or height.shape[0] < 2:
            raise ValueError(f"height must be (N, N) with N >= 2, got shape {height.shape}")
        n = height.shape[0]
        albedo = np.array(self.albedo, dtype=_F32)
        specular = np.array(self.specular, dtype=_F32)
        roughness = np.array(self.roughness, dtype=_F32)
        slope = None if self.slope is None else np.array(self.slope, dtype=_F32)
        for label, arr, shape in (
            ("albedo", albedo, (n, n, 3)),
            ("specular", specular, (n, n)),
            ("roughness", roughness, (n, n)),
            ("slope", slope, (n, n, 2)),
        ):
            if arr is None:
                continue
            if arr.shape != shape:
                raise ValueError(f"{label} must have shape {shape}, got {arr.shape}")
        for label, arr in (("height", height), ("albedo", albedo), ("specular", specular), ("roughness", roughness),
                           ("slope", slope)):
            if arr is not None and not np.all(np.isfinite(arr)):
                raise ValueError(f"{label} has non-finite values")
        if albedo.min() < 0 or albedo.max() > 1:
            raise ValueError("albedo must lie in [0, 1]")
        if specular.min() < 0 or specular.max() > 1:
            raise ValueError("specular (F0) must lie in [0, 1]")
        if roughness.min() <= 0:
            raise ValueError("roughness (GGX alpha) must be > 0")
        sheen, retro = float(self.sheen), float(self.retro)
        for label, weight in (("sheen", sheen), ("retro", retro)):
            if not (math.isfinite(weight) and weight >= 0):
                raise ValueError(f"{label} must be a finite weight >= 0")
        for label, arr in (("height", height), ("albedo", albedo), ("specular", specular), ("roughness", roughness),
                           ("slope", slope)):
            if arr is not None:
                arr.flags.writeable = False
            object.__setattr__(self, label, arr)
        object.__setattr__(self, "sheen", sheen)
        object.__setattr__(self, "retro", retro)
        object.__setattr__(self, "name", str(self.name))

    def __repr__(self) -> str:
        return f"Material(name={self.name!r}, size={self.size}, sheen={self.sheen}, retro={self.retro})"

    @property
    def size(self) -> int:
        """N, the texture size in texels."""
        return self.height.shape[0]


# ------------------------------------------------------------------ procedural noise


def _filtered_noise(rng: np.random.Generator, n: int, wavelength, *, band: float | None = None) -> np.ndarray:
    """Periodic noise: white noise filtered in the Fourier domain, so it tiles exactly.

    wavelength : feature size in texels; a scalar, or (along rows, along columns) for
        anisotropic noise.
    band : None for low-pass noise (Gaussian blur of about wavelength / 4), or the
        relative width of a band-pass ring centred on frequency 1 / wavelength.
    Returns (n, n) float64 with zero mean and unit standard deviation.
    """
    wl_r, wl_c = np.broadcast_to(np.asarray(wavelength, dtype=np.float64), (2,))
    white = rng.standard_normal((n, n))
    fr = np.fft.fftfreq(n)[:, None]
    fc = np.fft.fftfreq(n)[None, :]
    if band is None:
        sigma_r, sigma_c = wl_r / 4.0, wl_c / 4.0
        filt = np.exp(-2.0 * math.pi**2 * ((sigma_r * fr) ** 2 + (sigma_c * fc) ** 2))
    else:
        f = np.sqrt((fr * wl_r) ** 2 + (fc * wl_c) ** 2)  # 1.0 on the ring
        filt = np.exp(-0.5 * ((f - 1.0) / band) ** 2)
    filt[0, 0] = 0.0  # zero mean
    out = np.fft.ifft2(np.fft.fft2(white) * filt).real
    std = out.std()
    return out / std if std > 0 else out


def _grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) texel-centre coordinates, each (n, n) float64."""
    r, c = np.mgrid[0:n, 0:n]
    return r.astype(np.float64), c.astype(np.float64)


def _pack(name, n, height, albedo, specular, roughness, sheen, *, retro=0.0, slope=None) -> Material:
    return Material(
        height=np.asarray(height, dtype=_F32),
        albedo=np.clip(albedo, 0.0, 1.0).astype(_F32),
        specular=np.clip(np.broadcast_to(specular, (n, n)), 0.0, 1.0).astype(_F32),
        roughness=np.clip(np.broadcast_to(roughness, (n, n)), MIN_ALPHA, 1.0).astype(_F32),
        sheen=sheen,
        name=name,
        retro=retro,
        slope=slope,
    )


def _worley(rows: np.ndarray, cols: np.ndarray, g: int, cell: float, jitter: np.ndarray):
    """Periodic Worley (cellular) layout: one feature point per cell of a g x g grid.

    rows, cols : (n, n) float64 (possibly domain-warped) texel coordinates; cell = n / g
        texels; jitter : (g, g, 2) feature position inside its cell, in cell units.
    Returns f1, f2 (n, n) distances to the nearest and second-nearest feature point
    (texels), ident (n, n) int64 nearest cell index ``i * g + j``, and offset (2, n, n),
    the (row, col) offset of each texel from its nearest feature point.
    """
    n = rows.shape[0]
    ci = np.floor(rows / cell).astype(np.int64)
    cj = np.floor(cols / cell).astype(np.int64)
    f1 = np.full((n, n), np.inf)
    f2 = np.full((n, n), np.inf)
    ident = np.zeros((n, n), dtype=np.int64)
    offset = np.zeros((2, n, n))
    # The nearest feature point is in the 3 x 3 cells around a texel.  Neighbour cells
    # are taken modulo g but positioned unwrapped, so distances across the tile seam are
    # the periodic ones.
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            ki, kj = ci + di, cj + dj
            mi, mj = ki % g, kj % g
            dr = rows - (ki + jitter[mi, mj, 0]) * cell
            dc = cols - (kj + jitter[mi, mj, 1]) * cell
            d = np.hypot(dr, dc)
            closer = d < f1
            f2 = np.where(closer, f1, np.minimum(f2, d))
            ident = np.where(closer, mi * g + mj, ident)
            offset = np.where(closer, np.stack([dr, dc]), offset)
            f1 = np.where(closer, d, f1)
    return f1, f2, ident, offset


def _pebbles(size: int, seed: int) -> Material:
    """Rounded stones on a periodic jittered Voronoi layout, dark soil in the gaps.

    7 x 7 stones per tile whatever the size; stone height about 5% of the tile width
    (6.4 texels at N = 128).  Grey to brown stones, moderate gloss (alpha 0.18..0.35).
    """
    n = size
    rng = np.random.default_rng(seed)
    g = 7
    cell = n / g
    jitter = rng.uniform(0.2, 0.8, (g, g, 2))
    stone_amp = rng.uniform(0.6, 1.0, g * g)
    stone_lum = rng.uniform(0.22, 0.5, g * g)
    stone_tint = rng.uniform(0.0, 1.0, g * g)
    stone_alpha = rng.uniform(0.18, 0.35, g * g)
    warp_r = _filtered_noise(rng, n, n / 4)
    warp_c = _filtered_noise(rng, n, n / 4)
    grain = _filtered_noise(rng, n, n / 24)
    mottle = _filtered_noise(rng, n, n / 40)
    soil = _filtered_noise(rng, n, n / 16)

    rows, cols = _grid(n)
    # A periodic domain warp makes the cells rounder and less polygonal; it is a
    # function of the (periodic) noise, so the layout still tiles.
    rw = rows + 0.025 * n * warp_r
    cw = cols + 0.025 * n * warp_c
    f1, f2, ident, _ = _worley(rw, cw, g, cell, jitter)
    edge = 0.5 * (f2 - f1)  # distance to the cell border (exact for straight borders)
    x = np.clip((edge - 0.04 * cell) / (0.3 * cell), 0.0, 1.0)
    dome = np.sqrt(x * (2.0 - x))  # quarter-circle shoulder: rounded stone edges
    bulge = np.clip(1.0 - (f1 / (0.7 * cell)) ** 2, 0.0, 1.0)
    amp = 0.05 * n
    height = amp * stone_amp[ident] * dome * (0.7 + 0.3 * bulge)
    height += amp * (0.05 * grain * dome + 0.06 * soil * (1.0 - dome))

    stone_col = _tinted(stone_lum[ident], stone_tint[ident], np.array([0.95, 0.95, 0.95]), np.array([1.08, 0.90, 0.68]))
    stone_col = stone_col * (1.0 + 0.12 * mottle[..., None]) * (0.75 + 0.25 * dome[..., None])
    soil_col = np.array([0.09, 0.07, 0.05]) * (1.0 + 0.2 * soil[..., None])
    m = np.clip(dome * 3.0, 0.0, 1.0)[..., None]
    albedo, specular, roughness = _stones_over_gaps(stone_col, soil_col, m, stone_alpha[ident], 0.02)
    return _pack("pebbles", n, height, albedo, specular, roughness, 0.0)


def _tinted(lum: np.ndarray, tint: np.ndarray, cool, warm) -> np.ndarray:
    """(n, n, 3) colours of luminance ``lum`` (n, n) between a ``cool`` and a ``warm`` RGB,
    ``tint`` (n, n) in [0, 1] the warm share."""
    t = tint[..., None]
    return lum[..., None] * ((1.0 - t) * cool + t * warm)


def _stones_over_gaps(stone_col, gap_col, m, stone_alpha, spec_gain):
    """Albedo (n, n, 3), F0 and GGX alpha (n, n) of stones (weight ``m`` (n, n, 1)) over a
    matte filling (alpha 0.8) between them; F0 rises from 0.02 by ``spec_gain`` on stone."""
    albedo = gap_col * (1.0 - m) + stone_col * m
    specular = 0.02 + spec_gain * m[..., 0]
    roughness = 0.8 * (1.0 - m[..., 0]) + stone_alpha * m[..., 0]
    return albedo, specular, roughness


_DYES = np.array(
    [
        [0.62, 0.07, 0.07],  # madder red
        [0.07, 0.14, 0.45],  # indigo
        [0.72, 0.52, 0.09],  # ochre
        [0.09, 0.34, 0.14],  # green
        [0.42, 0.10, 0.38],  # purple
        [0.80, 0.74, 0.62],  # undyed
    ]
)


def _ridged_fabric(size: int, seed: int) -> Material:
    """Plain weave: warp threads along y (columns), weft threads along x (rows).

    16 threads per tile (fewer for N < 128 so a thread keeps >= ~8 texels), each
    over-under its crossing threads, with twisted-ply ridges and fibre noise.  Two
    dyes from a palette, low gloss (alpha 0.55), sheen 0.35.
    """
    n = size
    rng = np.random.default_rng(seed)
    threads = 2 * int(np.clip(round(n / 16), 1, 8))  # even: over-under needs period 2
    p = n / threads
    dyes = rng.choice(len(_DYES), size=2, replace=False)
    warp_dye, weft_dye = _DYES[dyes[0]], _DYES[dyes[1]]
    warp_w = rng.uniform(0.78, 0.92, threads)
    weft_w = rng.uniform(0.78, 0.92, threads)
    warp_lum = rng.uniform(0.9, 1.1, threads)
    weft_lum = rng.uniform(0.9, 1.1, threads)
    fibre_warp = _filtered_noise(rng, n, (p * 2.0, p / 6.0))  # streaks along the thread
    fibre_weft = _filtered_noise(rng, n, (p / 6.0, p * 2.0))

    rows, cols = _grid(n)
    k = np.floor(cols / p).astype(np.int64)  # warp thread index (vertical threads)
    m = np.floor(rows / p).astype(np.int64)  # weft thread index (horizontal threads)
    u = cols / p - k - 0.5  # across-thread coordinate in [-0.5, 0.5)
    v = rows / p - m - 0.5
    radius = 0.3 * p  # thread bulge height
    wave = 0.25 * p  # over-under amplitude
    prof_warp = np.sqrt(np.clip(1.0 - (2.0 * u / warp_w[k]) ** 2, 0.0, 1.0))
    prof_weft = np.sqrt(np.clip(1.0 - (2.0 * v / weft_w[m]) ** 2, 0.0, 1.0))
    # At crossing (k, m) the warp is on top when k + m is even; period 2p along each
    # thread, and `threads` is even so the pattern tiles.
    off_warp = 0.5 * wave * np.cos(math.pi * (rows / p - 0.5) + math.pi * k)
    off_weft = -0.5 * wave * np.cos(math.pi * (cols / p - 0.5) + math.pi * m)
    # Twisted plies: diagonal ridges across each thread.
    ply_warp = 0.12 * radius * np.cos(2.0 * math.pi * (3.0 * rows / p + 1.5 * u))
    ply_weft = 0.12 * radius * np.cos(2.0 * math.pi * (3.0 * cols / p + 1.5 * v))
    floor = -0.5 * wave - 0.2 * radius
    h_warp = np.where(prof_warp > 0, off_warp + radius * prof_warp + ply_warp * prof_warp + 0.05 * radius * fibre_warp, floor)
    h_weft = np.where(prof_weft > 0, off_weft + radius * prof_weft + ply_weft * prof_weft + 0.05 * radius * fibre_weft, floor)
    on_warp = h_warp >= h_weft
    height = np.maximum(np.maximum(h_warp, h_weft), floor)

    prof = np.where(on_warp, prof_warp, prof_weft)[..., None]
    col_warp = warp_dye * warp_lum[k][..., None] * (1.0 + 0.1 * fibre_warp[..., None])
    col_weft = weft_dye * weft_lum[m][..., None] * (1.0 + 0.1 * fibre_weft[..., None])
    albedo = np.where(on_warp[..., None], col_warp, col_weft) * (0.55 + 0.45 * prof)
    return _pack("ridged_fabric", n, height, albedo, 0.03, 0.55, 0.35)


def _fuzzy_moss(size: int, seed: int) -> Material:
    """Dense fine tall tufts on low clumps: strong masking and shadowing.

    Tufts of about N / 28 texels (>= 3) standing up to ~6% of the tile width
    (about 8 texels at N = 128) on clumps of N / 5.  Green albedo, brighter and
    yellower at the tips; almost no specular (F0 0.005, alpha 0.9), sheen 1.0.
    """
    n = size
    rng = np.random.default_rng(seed)
    clumps = _filtered_noise(rng, n, n / 5)
    tufts = _filtered_noise(rng, n, max(n / 28, 3.0), band=0.35)
    patches = _filtered_noise(rng, n, n / 6)
    speckle = _filtered_noise(rng, n, 3.0)
    strands = np.clip(tufts, 0.0, None) ** 1.3  # rectified: sharp tips, flat troughs
    # Normalise by a high percentile, not the max, so typical tufts stand tall.
    strands = np.minimum(strands / np.percentile(strands, 99.0), 1.25)
    height = 0.015 * n * clumps + 0.055 * n * strands

    tip = np.clip((height - height.min()) / (np.ptp(height) + 1e-12), 0.0, 1.0)[..., None]
    deep = np.array([0.035, 0.09, 0.015])
    bright = np.array([0.22, 0.36, 0.06])
    albedo = deep + (bright - deep) * tip**0.8
    brownish = np.clip(patches - 0.8, 0.0, 1.0)[..., None]  # dry patches
    albedo = albedo * (1.0 - brownish) + np.array([0.20, 0.15, 0.06]) * brownish * (0.5 + tip)
    albedo = albedo * (1.0 + 0.12 * speckle[..., None])
    return _pack("fuzzy_moss", n, height, albedo, 0.005, 0.9, 1.0)


def _crevice_stones(size: int, seed: int) -> Material:
    """Angular stones packed tight, split by deep narrow crevices: strong cast shadows.

    6 x 6 stones per tile; stones about 9 % of the tile width tall (11.5 texels at
    N = 128) with near-vertical flanks, tilted chipped tops and crevices about a fifth
    of a stone wide that reach the floor.  A crevice floor sees the light only when the
    light is within ~25 deg of the normal and is hidden from grazing views, so much of
    the BTF's energy sits in dark, often shadowed texels.  Pale limestone-like stones
    (albedo 0.35..0.6), dark grit in the crevices, low gloss (alpha 0.35..0.6).
    """
    n = size
    rng = np.random.default_rng(seed)
    g = 6
    cell = n / g
    jitter = rng.uniform(0.15, 0.85, (g, g, 2))
    stone_amp = rng.uniform(0.75, 1.0, g * g)
    tilt = rng.normal(0.0, 0.2, (g * g, 2))  # top slope, height per texel along (row, col)
    stone_lum = rng.uniform(0.35, 0.6, g * g)
    stone_tint = rng.uniform(0.0, 1.0, g * g)
    stone_alpha = rng.uniform(0.35, 0.6, g * g)
    warp_r = _filtered_noise(rng, n, n / 3)
    warp_c = _filtered_noise(rng, n, n / 3)
    chips = _filtered_noise(rng, n, n / 12)
    mottle = _filtered_noise(rng, n, n / 30)
    grit = _filtered_noise(rng, n, max(n / 40, 2.0))

    rows, cols = _grid(n)
    rw = rows + 0.035 * n * warp_r
    cw = cols + 0.035 * n * warp_c
    f1, f2, ident, offset = _worley(rw, cw, g, cell, jitter)
    edge = 0.5 * (f2 - f1)
    # Crevice half-width 0.1 cell, then a steep flank over 0.12 cell (quarter circle:
    # vertical at the foot) up to the stone's top.
    x = np.clip((edge - 0.1 * cell) / (0.12 * cell), 0.0, 1.0)
    flank = np.sqrt(x * (2.0 - x))
    amp = 0.09 * n
    top = amp * stone_amp[ident] + (tilt[ident, 0] * offset[0] + tilt[ident, 1] * offset[1])
    top += 0.06 * amp * chips
    floor = -0.05 * amp + 0.03 * amp * grit
    height = floor + (top - floor) * flank

    stone_col = _tinted(stone_lum[ident], stone_tint[ident], np.array([0.95, 0.95, 0.93]), np.array([1.06, 0.95, 0.80]))
    stone_col = stone_col * (1.0 + 0.1 * mottle[..., None])
    grit_col = np.array([0.12, 0.10, 0.085]) * (1.0 + 0.25 * grit[..., None])
    albedo, specular, roughness = _stones_over_gaps(stone_col, grit_col, flank[..., None] ** 2, stone_alpha[ident], 0.015)
    return _pack("crevice_stones", n, height, albedo, specular, roughness, 0.0)


_PAINTS = np.array(
    [
        [0.45, 0.03, 0.03],  # candy red
        [0.03, 0.08, 0.35],  # deep blue
        [0.04, 0.20, 0.08],  # racing green
        [0.30, 0.14, 0.02],  # copper
    ]
)


def _metal_flakes(size: int, seed: int) -> Material:
    """Metallic flake paint: small mirror-like flakes with random tilts in a coloured base coat.

    Flakes sit on a grid of cells 2.5 texels wide (51 x 51 per tile at N = 128: the
    flakes are a fixed size in texels, so their count grows with N), about 2 texels
    across, covering ~30 % of the surface.  Each flake has its own tilt (normal map:
    Gaussian slopes, sd tan 20 deg), F0 0.9 and alpha 0.04: it lights up only for half
    vectors near its own normal, so the highlights are tiny, sharp and spatially random
    (sparkle).  Base coat: one paint colour (diffuse albedo), F0 0.04, alpha 0.3.
    Relief: a gentle orange peel (about 5 texels peak to peak at N = 128 over a
    wavelength of half the tile: slopes of a few degrees).
    """
    n = size
    rng = np.random.default_rng(seed)
    g = max(4, int(round(n / 2.5)))
    cell = n / g
    jitter = rng.uniform(0.25, 0.75, (g, g, 2))
    present = rng.uniform(0.0, 1.0, g * g) < 0.7
    flake_slope = rng.normal(0.0, math.tan(math.radians(20.0)), (g * g, 2))
    flake_alpha = rng.uniform(0.03, 0.05, g * g)
    paint = _PAINTS[rng.integers(len(_PAINTS))]
    peel = _filtered_noise(rng, n, n / 2)
    shade = _filtered_noise(rng, n, n / 8)

    rows, cols = _grid(n)
    f1, _, ident, _ = _worley(rows, cols, g, cell, jitter)
    flake = (f1 < 0.4 * cell) & present[ident]
    fl = flake[..., None]
    height = 0.01 * n * peel
    # (dh/dx, dh/dy) of each flake's plane: x = +col, y = -row.
    slope = np.where(fl, flake_slope[ident], 0.0)
    base = paint * (1.0 + 0.08 * shade[..., None])
    albedo = np.where(fl, 0.15 * base + 0.02, base)
    specular = np.where(flake, 0.9, 0.04)
    roughness = np.where(flake, flake_alpha[ident], 0.3)
    return _pack("metal_flakes", n, height, albedo, specular, roughness, 0.0, slope=slope.astype(_F32))


def _velvet(size: int, seed: int) -> Material:
    """Crushed velvet: a dense fine pile, flattened in patches; grazing sheen and retro-reflection.

    Fibre tufts about 2.5 texels apart (band-pass noise) standing up to ~3 % of the
    tile width (4 texels at N = 128) where the pile is upright and a third of that
    where it is crushed (a low-frequency pattern, ~40 % crushed, which also lies
    ~2 texels lower).  A saturated dark dye (albedo 0.1..0.35, lighter where crushed),
    no specular lobe, sheen 3.0 and retro-reflection 1.0, both tinted by the dye.
    """
    n = size
    rng = np.random.default_rng(seed)
    dye = _DYES[rng.choice([0, 1, 3, 4])] * 0.55
    crush = _filtered_noise(rng, n, n / 4)
    fibres = _filtered_noise(rng, n, 2.5, band=0.4)
    speckle = _filtered_noise(rng, n, 2.0)
    upright = 1.0 / (1.0 + np.exp(-4.0 * (crush + 0.25)))      # 1 upright, 0 crushed (~40 %)
    pile = np.clip(fibres, 0.0, None) ** 1.2
    pile = np.minimum(pile / np.percentile(pile, 99.0), 1.2)
    height = 0.016 * n * upright + 0.03 * n * pile * (1.0 / 3.0 + 2.0 / 3.0 * upright)

    tip = np.clip(pile, 0.0, 1.0)[..., None]
    albedo = dye * (0.6 + 0.4 * tip) * (1.0 + 0.35 * (1.0 - upright[..., None]))
    albedo = albedo * (1.0 + 0.08 * speckle[..., None])
    return _pack("velvet", n, height, albedo, 0.0, 0.8, 3.0, retro=1.0)


def _satin_weave(size: int, seed: int) -> Material:
    """5-harness satin: glossy warp floats over four weft threads: anisotropic highlights.

    Warp threads run along y (columns), weft along x (rows), 20 of each per tile (5
    per 32 texels for smaller N; the satin repeat is 5 threads).  Warp thread k passes
    under weft m where (m - 2 k) mod 5 == 0 and floats over the other four, so ~80 %
    of the face is long, glossy warp floats (alpha 0.1, F0 0.05) with fine fibre
    grooves along the thread: each float's highlight is a line across the thread and
    moves with the light's azimuth very differently along and across the threads.
    Weft threads show only at the interlacings (matte, alpha 0.4).  Two dyes, sheen 0.2.
    """
    n = size
    rng = np.random.default_rng(seed)
    threads = 5 * max(1, int(round(n / 32)))
    p = n / threads
    dyes = rng.choice(len(_DYES), size=2, replace=False)
    warp_dye, weft_dye = _DYES[dyes[0]], _DYES[dyes[1]]
    warp_w = rng.uniform(0.85, 0.95, threads)
    warp_lum = rng.uniform(0.92, 1.08, threads)
    fibre = _filtered_noise(rng, n, (p * 3.0, p / 8.0))  # streaks along the warp

    rows, cols = _grid(n)
    # Thread centres on the tile's edges, so the seam runs along threads, not between them.
    rows, cols = rows + 0.5 * p, cols + 0.5 * p
    k = np.floor(cols / p).astype(np.int64) % threads  # warp (vertical) thread index
    m = np.floor(rows / p).astype(np.int64) % threads  # weft (horizontal) thread index
    u = cols / p - np.floor(cols / p) - 0.5  # across the warp, [-0.5, 0.5)
    v = rows / p - np.floor(rows / p) - 0.5  # across the weft
    radius = 0.35 * p
    lift = 0.45 * p
    # Distance (in threads) along the warp to its nearest interlacing (where it dips under
    # a weft), and along the weft to its nearest crossing over a warp.  Period 5 threads.
    def to_nearest(pos, phase):
        off = np.mod(pos - phase, 5.0)
        return np.minimum(off, 5.0 - off)

    warp_dip = np.exp(-(to_nearest(rows / p - 0.5, np.mod(2 * k, 5)) / 0.55) ** 2)
    weft_rise = np.exp(-(to_nearest(cols / p - 0.5, np.mod(3 * m, 5)) / 0.55) ** 2)
    prof_warp = np.sqrt(np.clip(1.0 - (2.0 * u / warp_w[k]) ** 2, 0.0, 1.0))
    prof_weft = np.sqrt(np.clip(1.0 - (2.0 * v / 0.9) ** 2, 0.0, 1.0))
    grooves = 0.06 * radius * np.cos(2.0 * math.pi * 4.0 * u)
    h_warp = np.where(prof_warp > 0, lift * (1.0 - warp_dip) + radius * prof_warp + grooves * prof_warp
                      + 0.03 * radius * fibre, -lift)
    h_weft = np.where(prof_weft > 0, lift * (weft_rise - 0.4) + radius * prof_weft, -lift)
    on_warp = h_warp >= h_weft
    height = np.maximum(np.maximum(h_warp, h_weft), -lift)

    col_warp = warp_dye * warp_lum[k][..., None] * (1.0 + 0.08 * fibre[..., None])
    prof = np.where(on_warp, prof_warp, prof_weft)[..., None]
    albedo = np.where(on_warp[..., None], col_warp, weft_dye * 0.9) * (0.6 + 0.4 * prof)
    specular = np.where(on_warp, 0.05, 0.03)
    roughness = np.where(on_warp, 0.1, 0.4)
    return _pack("satin_weave", n, height, albedo, specular, roughness, 0.2)


#: name -> fn(size, seed) -> Material
PRESETS: dict[str, Callable[[int, int], Material]] = {
    "pebbles": _pebbles,
    "ridged_fabric": _ridged_fabric,
    "fuzzy_moss": _fuzzy_moss,
    "crevice_stones": _crevice_stones,
    "metal_flakes": _metal_flakes,
    "velvet": _velvet,
    "satin_weave": _satin_weave,
}


def make_material(preset: str, size: int = 128, seed: int = 0) -> Material:
    """The procedural material ``preset`` at ``size`` x ``size`` texels.

    Feature sizes and heights scale with ``size`` (a fixed number of stones / threads
    per tile), so a larger size is a finer sampling of a similar sample.  Seeded with
    ``numpy.random.default_rng(seed)``: the same arguments give bit-identical arrays.
    """
    try:
        fn = PRESETS[preset]
    except KeyError:
        raise ValueError(f"unknown material preset {preset!r}; choose from {', '.join(PRESETS)}") from None
    size = int(size)
    if size < 8:
        raise ValueError(f"size must be >= 8 texels, got {size}")
    return fn(size, int(seed))


# ---------------------------------------------------------------- sampling helpers


def _direction(deg) -> tuple[np.ndarray, tuple[float, float]]:
    """(theta, phi) degrees -> (unit vector (3,) float64, canonical cache key).

    Theta is clamped to MAX_THETA_DEG; phi is reduced modulo 360 and ignored at the
    pole, so equal directions share a cache entry.  Same formula as
    :func:`usdbtf.sampling.to_vectors`, in scalar math because this runs per image.
    """
    if isinstance(deg, np.ndarray) and deg.shape == (2,):
        theta, phi = float(deg[0]), float(deg[1])
    else:
        theta, phi = (float(a) for a in np.asarray(deg, dtype=np.float64).reshape(2))
    if not (math.isfinite(theta) and math.isfinite(phi)):
        raise ValueError(f"direction must be finite, got {(theta, phi)}")
    if theta < 0 or theta > 90:
        raise ValueError(f"theta must be in [0, 90] degrees, got {theta}")
    theta = min(theta, MAX_THETA_DEG)
    phi = phi % 360.0
    if theta == 0.0:
        phi = 0.0
    t, p = math.radians(theta), math.radians(phi)
    st = math.sin(t)
    vec = np.array([st * math.cos(p), st * math.sin(p), math.cos(t)])
    return vec, (round(theta, 9), round(phi, 9))


def _bilinear_setup(rows: np.ndarray, cols: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (4, M) intp into a flattened (n*n) map and weights (4, M) float32 for
    bilinear lookup with wrap-around at texel coordinates (rows, cols), any shape."""
    rows = np.asarray(rows, dtype=np.float64).ravel()
    cols = np.asarray(cols, dtype=np.float64).ravel()
    r0 = np.floor(rows)
    c0 = np.floor(cols)
    fr = (rows - r0).astype(_F32)
    fc = (cols - c0).astype(_F32)
    r0 = r0.astype(np.intp) % n
    c0 = c0.astype(np.intp) % n
    r1 = (r0 + 1) % n
    c1 = (c0 + 1) % n
    idx = np.stack([r0 * n + c0, r0 * n + c1, r1 * n + c0, r1 * n + c1])
    gr, gc = 1.0 - fr, 1.0 - fc
    w = np.stack([gr * gc, gr * fc, fr * gc, fr * fc])
    return idx, w


def _gather(flat: np.ndarray, idx: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Bilinear lookup: flat (..., n*n) maps -> (..., M) using _bilinear_setup's output."""
    return (
        flat[..., idx[0]] * w[0]
        + flat[..., idx[1]] * w[1]
        + flat[..., idx[2]] * w[2]
        + flat[..., idx[3]] * w[3]
    )


def _shift(padded: np.ndarray, n: int, drow: float, dcol: float) -> np.ndarray:
    """The (n, n) map sampled at every texel + (drow, dcol), bilinear, wrapping.

    ``padded`` is the map wrap-padded to (2n + 1, 2n + 1).  A constant offset on a
    torus is the same as the offset modulo n, so four slices of the padded map do it
    without any per-texel index arithmetic (the marches below are all constant
    offsets per step, which is what makes them cheap).
    """
    fr0 = math.floor(drow)
    fc0 = math.floor(dcol)
    fr = _F32(drow - fr0)
    fc = _F32(dcol - fc0)
    a = fr0 % n
    b = fc0 % n
    top = padded[a : a + n, b : b + n]
    if fc:
        top = top + fc * (padded[a : a + n, b + 1 : b + n + 1] - top)
    if not fr:
        return top
    bot = padded[a + 1 : a + n + 1, b : b + n]
    if fc:
        bot = bot + fc * (padded[a + 1 : a + n + 1, b + 1 : b + n + 1] - bot)
    return top + fr * (bot - top)


# ------------------------------------------------------------------- caches / views


@dataclass(frozen=True, eq=False)
class ViewHits:
    """Where each rectified texel's viewing ray first meets the heightfield.

    Attributes
    ----------
    row, col : (N, N) float32 texel coordinates of the hit, *unwrapped* (texel
        ``(i, j)``'s hit is at ``(i + drow, j + dcol)``; take modulo N to index).
    height : (N, N) float32 hit height above the reference plane (mean height).
    direction : (3,) float64 unit view vector (towards the camera).

    The hit lies on the ray, so ``(dcol, -drow) = height * tan(theta_v) * (cos phi_v,
    sin phi_v)``: hits above the mean plane are displaced towards the camera's azimuth
    (the surface content appears shifted away from the camera in the image).
    """

    row: np.ndarray
    col: np.ndarray
    height: np.ndarray
    direction: np.ndarray


class _ViewData:
    """Per-view quantities that do not depend on the light (flattened, (M,) = N*N)."""

    __slots__ = ("hits", "v", "idx", "w", "n", "nv", "kd", "f0", "a2", "lam_v", "sheen", "retro")

    def __init__(self, hits: ViewHits, v, idx, w, n, nv, kd, f0, a2, lam_v, sheen, retro):
        self.hits, self.v, self.idx, self.w = hits, v, idx, w
        self.n, self.nv, self.kd, self.f0, self.a2, self.lam_v, self.sheen = n, nv, kd, f0, a2, lam_v, sheen
        self.retro = retro


class RenderCache:
    """Per-material precomputation plus LRU caches of per-view hit maps and
    per-light shadow maps, so a sampling of V views x L lights does V ray marches
    and L shadow marches rather than V * L of each.

    Parameters
    ----------
    material : the Material every lookup refers to (a cache is bound to one material).
    max_views : view entries kept (least recently used dropped).  An entry holds
        about 28 * N * N * 4 bytes (1.8 MB at N = 128).
    max_lights : shadow maps kept (N * N * 4 bytes each); None = unbounded.
    """

    def __init__(self, material: Material, *, max_views: int = 8, max_lights: int | None = None):
        if not isinstance(material, Material):
            raise TypeError(f"expected a Material, got {type(material).__name__}")
        if max_views < 1 or (max_lights is not None and max_lights < 1):
            raise ValueError("cache sizes must be >= 1")
        self.material = material
        self.max_views = int(max_views)
        self.max_lights = None if max_lights is None else int(max_lights)
        self._views: OrderedDict = OrderedDict()
        self._lights: OrderedDict = OrderedDict()

        n = material.size
        h = material.height.astype(np.float64)
        h = (h - h.mean()).astype(_F32)  # reference plane z = 0 at the mean height
        self._n = n
        self._h = h
        self._h_flat = h.ravel()
        self._hmin = float(h.min())
        self._hmax = float(h.max())
        self._hpad = np.pad(h, ((0, n + 1), (0, n + 1)), mode="wrap")
        # Slopes in the tangent frame by central differences with wrap.  x = +col;
        # y = -row, so the +y neighbour of row i is row i - 1.
        gx = 0.5 * (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1))
        gy = 0.5 * (np.roll(h, 1, axis=0) - np.roll(h, -1, axis=0))
        if material.slope is not None:
            gx = gx + material.slope[..., 0]
            gy = gy + material.slope[..., 1]
        alpha = np.maximum(material.roughness, _F32(MIN_ALPHA))
        # Maps gathered at the hit points, one row per channel: (7, N*N).
        self._attrs = np.ascontiguousarray(
            np.concatenate(
                [
                    gx.reshape(1, -1),
                    gy.reshape(1, -1),
                    material.albedo.reshape(-1, 3).T,
                    material.specular.reshape(1, -1),
                    alpha.reshape(1, -1),
                ]
            ),
            dtype=_F32,
        )

    # -- views -------------------------------------------------------------------

    def hits(self, view_deg) -> ViewHits:
        """The (cached) hit map for ``view_deg`` = (theta, phi) degrees."""
        return self._view(view_deg).hits

    def _view(self, view_deg) -> _ViewData:
        v, key = _direction(view_deg)
        entry = self._views.get(key)
        if entry is not None:
            self._views.move_to_end(key)
            return entry
        entry = self._make_view(v)
        self._views[key] = entry
        if len(self._views) > self.max_views:
            self._views.popitem(last=False)
        return entry

    def _trace(self, v: np.ndarray) -> ViewHits:
        """Ray march from above the heightfield down the viewing ray of every texel."""
        n = self._n
        vx, vy, vz = (float(c) for c in v)
        sin_t = math.hypot(vx, vy)
        rows0, cols0 = _grid(n)
        if self._hmax - self._hmin <= 0.0 or sin_t < 1e-9:
            # Flat field or head-on view: the hit is the texel itself.
            t = self._h.astype(np.float64) / vz
        else:
            # Ray of texel p: P(t) = p + t * v (texel units, t = distance along v);
            # t_hi puts the ray above every height, t_lo below every height.  f(t) =
            # z(t) - h(P(t)) is >= 0 at t_hi and <= 0 at t_lo; the first hit is the
            # first sign change marching down from t_hi.  Steps are <= 1/2 texel
            # horizontally and vertically; every step is one constant offset for all
            # texels (see _shift).
            t_hi, t_lo = self._hmax / vz, self._hmin / vz
            dt = 0.5 / max(sin_t, vz)
            steps = max(1, math.ceil((t_hi - t_lo) / dt))
            ts = np.linspace(t_hi, t_lo, steps + 1)
            h = self._hpad
            prev_f = (self._hmax - _shift(h, n, -vy * t_hi, vx * t_hi)).astype(np.float64)
            t_a = np.full((n, n), t_hi)  # bracket: f(t_a) >= 0 (above) ...
            f_a = prev_f.copy()
            t_b = np.full((n, n), t_lo)  # ... f(t_b) <= 0 (below)
            f_b = np.zeros((n, n))
            found = np.zeros((n, n), dtype=bool)
            for k in range(1, steps + 1):
                t = ts[k]
                f = vz * t - _shift(h, n, -vy * t, vx * t)
                if k == steps:
                    f = np.minimum(f, 0.0)  # at t_lo the ray is below everything
                new = (f <= 0) & ~found
                if new.any():
                    t_a[new] = ts[k - 1]
                    f_a[new] = prev_f[new]
                    t_b[new] = t
                    f_b[new] = f[new]
                    found |= new
                    if found.all():
                        break
                prev_f = f
            # Refine within the bracket: Illinois-style regula falsi (the end kept
            # twice in a row has its f halved, which avoids regula falsi's slow
            # one-sided convergence), then a final secant.  Hit heights then match
            # the bilinear heightfield to ~1e-3 texel.
            kept = np.zeros((n, n), dtype=np.int8)  # +1: a was replaced last, -1: b
            for _ in range(4):
                t_m = self._secant(t_a, f_a, t_b, f_b)
                f_m = vz * t_m - self._height_at(rows0 - vy * t_m, cols0 + vx * t_m)
                above = f_m > 0
                f_b = np.where(above & (kept == 1), 0.5 * f_b, f_b)
                f_a = np.where(~above & (kept == -1), 0.5 * f_a, f_a)
                t_a = np.where(above, t_m, t_a)
                f_a = np.where(above, f_m, f_a)
                t_b = np.where(above, t_b, t_m)
                f_b = np.where(above, f_b, f_m)
                kept = np.where(above, 1, -1).astype(np.int8)
            t = self._secant(t_a, f_a, t_b, f_b)
        return ViewHits(
            row=(rows0 - vy * t).astype(_F32),
            col=(cols0 + vx * t).astype(_F32),
            height=(vz * t).astype(_F32),
            direction=v.copy(),
        )

    @staticmethod
    def _secant(t_a, f_a, t_b, f_b):
        denom = f_a - f_b  # >= 0 by construction
        safe = denom > 1e-12
        return np.where(safe, t_a + f_a * (t_b - t_a) / np.where(safe, denom, 1.0), t_b)

    def _height_at(self, rows, cols) -> np.ndarray:
        idx, w = _bilinear_setup(rows, cols, self._n)
        return _gather(self._h_flat, idx, w).reshape(np.shape(rows)).astype(np.float64)

    def _make_view(self, v: np.ndarray) -> _ViewData:
        hits = self._trace(v)
        idx, w = _bilinear_setup(hits.row, hits.col, self._n)
        a = _gather(self._attrs, idx, w)  # (7, M)
        nrm = np.stack([-a[0], -a[1], np.ones_like(a[0])])
        nrm /= np.sqrt((nrm * nrm).sum(axis=0))
        nv = nrm[0] * _F32(v[0]) + nrm[1] * _F32(v[1]) + nrm[2] * _F32(v[2])
        # Hits on faces turned from the camera only occur at grazing silhouettes
        # (discrete normals); clamping keeps the specular terms finite there.
        nv = np.maximum(nv, _F32(1e-3))
        kd = np.ascontiguousarray(a[2:5].T) * _F32(1.0 / math.pi)  # (M, 3)
        a2 = a[6] * a[6]
        lam_v = np.sqrt(nv * nv * (1 - a2) + a2)
        sheen = retro = None
        if self.material.sheen > 0:
            sheen = np.ascontiguousarray(a[2:5].T) * _F32(self.material.sheen)
        if self.material.retro > 0:
            norm = (RETRO_EXPONENT + 2.0) / (2.0 * math.pi)
            retro = np.ascontiguousarray(a[2:5].T) * _F32(self.material.retro * norm)
        return _ViewData(hits, v, idx, w, nrm, nv, kd, a[5].copy(), a2, lam_v, sheen, retro)

    # -- lights ------------------------------------------------------------------

    def shadow(self, light_deg) -> np.ndarray:
        """The (cached, read-only) (N, N) float32 visibility in [0, 1] of the light
        ``light_deg`` = (theta, phi) degrees at each heightfield texel."""
        l, key = _direction(light_deg)
        vis = self._lights.get(key)
        if vis is not None:
            self._lights.move_to_end(key)
            return vis
        vis = self._shadow(l)
        vis.flags.writeable = False
        self._lights[key] = vis
        if self.max_lights is not None and len(self._lights) > self.max_lights:
            self._lights.popitem(last=False)
        return vis

    def _shadow(self, l: np.ndarray) -> np.ndarray:
        """Horizon test: march from each texel towards the light's azimuth and compare
        the steepest elevation of the heightfield with the light's elevation."""
        n = self._n
        lx, ly, lz = (float(c) for c in l)
        sin_t = math.hypot(lx, ly)
        rng = self._hmax - self._hmin
        if rng <= 0.0 or sin_t < 1e-9:
            return np.ones((n, n), dtype=_F32)
        soft = math.radians(SHADOW_SOFTNESS_DEG)
        elev = math.atan2(lz, sin_t)
        # Beyond this horizontal distance nothing can rise above the lowest light
        # elevation that still counts (elev - soft); capped at two tile widths.
        reach = rng / math.tan(max(elev - soft, math.radians(0.5)))
        reach = min(reach, 2.0 * n)
        dcol, drow = lx / sin_t, -ly / sin_t  # unit step towards the light, texels
        h = self._h
        steepest = np.full((n, n), -np.inf, dtype=_F32)
        for s in np.arange(0.5, reach + 0.5, 0.5):
            rise = _shift(self._hpad, n, drow * s, dcol * s) - h
            np.maximum(steepest, rise * _F32(1.0 / s), out=steepest)
        horizon = np.arctan(steepest)
        x = np.clip((elev - horizon) / (2 * soft) + 0.5, 0.0, 1.0)
        return (x * x * (3.0 - 2.0 * x)).astype(_F32)  # smoothstep(-soft, soft, .)


def trace_view(material: Material, view_deg, *, cache: RenderCache | None = None) -> ViewHits:
    """The hit map (masking / parallax) of ``material`` seen from ``view_deg`` = (theta, phi)."""
    return _cache_for(material, cache).hits(view_deg)


def shadow_map(material: Material, light_deg, *, cache: RenderCache | None = None) -> np.ndarray:
    """(N, N) float32 light visibility in [0, 1] on the heightfield texels (not the
    rectified image: look it up at :func:`trace_view` hits for that)."""
    return _cache_for(material, cache).shadow(light_deg)


def _cache_for(material: Material, cache: RenderCache | None) -> RenderCache:
    if cache is None:
        return RenderCache(material)
    if cache.material is not material:
        raise ValueError("this RenderCache was made for a different Material")
    return cache


# ------------------------------------------------------------------------- shading


def _shade(vd: _ViewData, lights: np.ndarray, vis: np.ndarray, n: int) -> np.ndarray:
    """Rectified images for view data ``vd`` and a batch of B lights.

    lights : (B, 3) unit light vectors; vis : (B, N*N) float32 shadow maps (on the
    heightfield texels).  Returns (B, n, n, 3) float32 radiance

    L = E * vis * max(n.l, 0) * (albedo / pi + F * D * V + sheen * albedo * D_s * V_s
                                 + retro * albedo * (p + 2) / (2 pi) * max(v.l, 0)^p * (1 - n.v))

    with GGX D, height-correlated Smith V, F = min(1, F0 * (1 + 24 (1 - v.h)^5))
    (Schlick's curve for F0 = 0.04, scaled; F0 = ``specular``); the sheen
    lobe is the Charlie distribution (sheen roughness 0.5) with Neubelt's visibility;
    the retro lobe's exponent p is RETRO_EXPONENT (distant light, orthographic camera:
    v.l is one number per image).
    """
    f32 = _F32
    one = f32(1.0)
    vis = _gather(vis, vd.idx, vd.w)  # (B, M): visibility at this view's hit points
    lights = np.asarray(lights, dtype=np.float64).reshape(-1, 3)
    nx, ny, nz = vd.n
    lc = lights.astype(f32)[:, :, None]  # (B, 3, 1)
    nl = np.maximum(nx * lc[:, 0] + ny * lc[:, 1] + nz * lc[:, 2], f32(0.0))
    weight = nl * vis
    weight *= f32(IRRADIANCE)
    # Distant light and orthographic camera: one half vector per image.
    hv = vd.v[None, :] + lights
    hv /= np.linalg.norm(hv, axis=1, keepdims=True)
    hc = hv.astype(f32)[:, :, None]
    nh = np.clip(nx * hc[:, 0] + ny * hc[:, 1] + nz * hc[:, 2], f32(0.0), one)
    vh = np.clip(hv @ vd.v, 0.0, 1.0)
    a2 = vd.a2
    nh2 = nh * nh
    d = nh2 * (a2 - one) + one
    spec = a2 / (f32(math.pi) * d * d)  # GGX D
    nlc = np.maximum(nl, f32(1e-4))
    lam_l = np.sqrt(nlc * nlc * (one - a2) + a2)
    spec *= f32(0.5) / (nlc * vd.lam_v + vd.nv * lam_l)  # Smith V = G / (4 nl nv)
    # Fresnel: Schlick's curve for F0 = 0.04 (IOR 1.5), scaled by F0 / 0.04 so that
    # F(0) = F0 exactly and F0 = 0 switches the lobe off; capped at 1.
    fres = (1.0 + (1.0 / 0.04 - 1.0) * (1.0 - vh) ** 5).astype(f32)[:, None]
    spec *= np.minimum(vd.f0 * fres, one)
    spec *= weight
    out = vd.kd * weight[:, :, None]
    out += spec[:, :, None]
    if vd.sheen is not None:
        # Charlie D with r = 0.5: (2 + 1/r) sin^(1/r)(theta_h) / (2 pi) = 2 sin^2 / pi
        fs = (one - nh2) * f32(2.0 / math.pi)
        fs /= f32(4.0) * (nlc + vd.nv - nlc * vd.nv)
        fs *= weight
        out += vd.sheen * fs[:, :, None]
    if vd.retro is not None:
        back = np.maximum(lights @ vd.v, 0.0) ** RETRO_EXPONENT               # (B,)
        out += vd.retro * (weight * back.astype(f32)[:, None] * (one - vd.nv))[:, :, None]
    return out.reshape(-1, n, n, 3)


def render_sample(material: Material, view_deg, light_deg, *, cache: RenderCache | None = None) -> np.ndarray:
    """One rectified image, (N, N, 3) float32 linear Rec.709 radiance.

    view_deg, light_deg : (theta, phi) in degrees.  Pass a :class:`RenderCache` made
    for ``material`` to reuse hit maps and shadow maps across calls.
    """
    cache = _cache_for(material, cache)
    vd = cache._view(view_deg)
    l, _ = _direction(light_deg)
    vis = cache.shadow(light_deg)
    return _shade(vd, l[None, :], vis.reshape(1, -1), material.size)[0]


def render_samples(material: Material, sampling: Sampling, *, chunk: int | None = None) -> Iterator[np.ndarray]:
    """Yield one (N, N, 3) float32 image per sample of ``sampling``, in order.

    Each yielded array is new (callers may keep or modify it).  Within the call, hit
    maps are cached per distinct view and shadow maps per distinct light, so the cost
    is one ray march per distinct view + one shadow march per distinct light + one
    shading pass per sample (about 0.4 ms per image at N = 128 on one core).

    chunk : upper bound on the number of per-view entries kept at once (each about
        28 * N * N * 4 bytes, 1.8 MB at N = 128).  By default: 1 when samples sharing
        a view are consecutive (the view-major order of :mod:`usdbtf.sampling`),
        otherwise as many as fit in about 256 MB.  Images are always produced one at
        a time; ``chunk`` only trades memory for repeated ray marches.
    """
    if not isinstance(sampling, Sampling):
        raise TypeError(f"expected a usdbtf.sampling.Sampling, got {type(sampling).__name__}")
    if not isinstance(material, Material):
        raise TypeError(f"expected a Material, got {type(material).__name__}")
    n = material.size
    views = sampling.view
    if chunk is not None:
        max_views = max(1, int(chunk))
    elif len(views) == 0:
        max_views = 1
    else:
        runs = 1 + int(np.count_nonzero(np.any(views[1:] != views[:-1], axis=1)))
        distinct = len(np.unique(views, axis=0))
        max_views = 1 if runs == distinct else min(distinct, max(1, (256 << 20) // (28 * 4 * n * n)))
    cache = RenderCache(material, max_views=max_views)
    # A separate generator so that bad arguments raise here, not at the first next().
    return _render_iter(material, cache, views, sampling.light)


def _render_iter(material, cache, views, lights) -> Iterator[np.ndarray]:
    for view_deg, light_deg in zip(views, lights):
        yield render_sample(material, view_deg, light_deg, cache=cache)


def render_all(material: Material, sampling: Sampling) -> np.ndarray:
    """All images of ``sampling`` as one (S, N, N, 3) float32 array (small samplings:
    S * N * N * 12 bytes)."""
    n = material.size
    out = np.empty((len(sampling), n, n, 3), dtype=_F32)
    for k, img in enumerate(render_samples(material, sampling)):
        out[k] = img
    return out


# --------------------------------------------------------------------------- the stage
#: The OCIO space synthesised radiance is in (linear Rec.709 primaries, see the module docstring).
RADIANCE_SPACE = "Linear Rec.709 (sRGB)"


@dataclass(frozen=True)
class SynthOptions:
    """What ``usdbtf synth`` makes and how :func:`write_synth` stores it.

    size : texels per side (>= 8); seed : the only source of randomness; sampling : a
    :data:`usdbtf.sampling.PRESETS` name; physical_size : edge of the tile in metres.
    ext, bit_depth, color_space : the manifest's image files (``color_space`` None: sRGB for
    integer depths, linear Rec.709 for float ones).
    """

    size: int = 128
    seed: int = 0
    sampling: str = "small"
    physical_size: float = 0.05
    ext: str = "png"
    bit_depth: str = "uint8"
    color_space: str | None = None

    @property
    def file_space(self) -> str:
        """The OCIO space the image files are encoded in."""
        if self.color_space:
            return self.color_space
        return "sRGB Encoded Rec.709 (sRGB)" if self.bit_depth in ("uint8", "uint16") else RADIANCE_SPACE


@dataclass
class SynthResult:
    """A synthetic BTF, evaluated lazily: :meth:`images` renders the samples one at a time
    (a whole BTF may not fit in memory; :meth:`to_btf` holds it all for small ones).

    preset : the material's name; material : its :class:`Material`; sampling : the directions;
    options : the :class:`SynthOptions`; metadata : the manifest's extra keys
    (``physical_size_m``, ``synthetic``: preset, size, seed, sampling, version).
    """

    preset: str
    material: Material
    sampling: Sampling
    options: SynthOptions
    metadata: dict

    def images(self) -> Iterator[np.ndarray]:
        """One (N, N, 3) float32 image per sample, in sampling order, radiance in
        :data:`RADIANCE_SPACE`."""
        return render_samples(self.material, self.sampling)

    def to_btf(self):
        """The samples as an in-memory :class:`usdbtf.model.ArrayBTF` in the working space
        (S x N x N x 12 bytes)."""
        from . import color
        from .model import ArrayBTF

        data = color.processor(RADIANCE_SPACE, color.WORKING_SPACE).apply(render_all(self.material, self.sampling))
        btf = ArrayBTF.from_linear(self.sampling, data)
        btf.metadata.update(self.metadata)
        return btf


@single_blas_thread
def synth(preset: str, options: SynthOptions | None = None) -> SynthResult:
    """The procedural material ``preset`` (a :data:`PRESETS` name) over ``options.sampling``.

    Nothing is rendered yet: :meth:`SynthResult.images` renders on demand and
    :func:`write_synth` streams the images into a manifest folder.  ValueError for an
    unknown preset, sampling or size.
    """
    from . import __version__
    from .sampling import preset as sampling_preset

    options = options or SynthOptions()
    sampling = sampling_preset(options.sampling)
    material = make_material(preset, options.size, options.seed)
    size = options.physical_size
    metadata = {"physical_size_m": [size, size],
                "synthetic": {"preset": preset, "size": options.size, "seed": options.seed,
                              "sampling": options.sampling, "usdbtf_version": __version__}}
    return SynthResult(preset, material, sampling, options, metadata)


def write_synth(result: SynthResult, path) -> None:
    """Render ``result`` into the manifest folder ``path`` (atomically, one image at a time,
    with a progress bar), encoded as its options say."""
    from .manifest import write_manifest
    from .progress import track

    opts = result.options
    images = track(result.images(), "synth", len(result.sampling))
    write_manifest(path, result.sampling, images, color_space=opts.file_space, bit_depth=opts.bit_depth,
                   ext=opts.ext, array_space=RADIANCE_SPACE, metadata=result.metadata)
