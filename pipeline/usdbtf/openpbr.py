"""An OpenPBR Surface fitted per texel to a BTF: the fallback MaterialX renderers show.

:func:`evaluate_openpbr` is the direct lighting of MaterialX 1.39's ``open_pbr_surface``
(``libraries/bxdf/open_pbr_surface.mtlx`` and its genglsl lobes) for the inputs this fit
uses, one directional light of irradiance 1, written from MaterialX's GLSL so that the fit
and the renderers agree (``tests/test_openpbr.py`` renders MaterialX's generated shader and
compares):

- **base** (``oren_nayar_diffuse_bsdf`` with ``energy_compensation``, weight ``base_weight`` = 1):
  Fujii's Oren-Nayar single scattering ``c A (1 + sigma s / max(n.l, n.v))`` plus the
  multiple-scattering lobe ``c^2 E_avg / (1 - c (1 - E_avg)) (1 - E(n.v)) (1 - E(n.l)) / (1 - E_avg)``,
  times ``n.l / pi``; ``sigma`` = ``base_diffuse_roughness`` (0 is Lambert);
- **specular** (``dielectric_bsdf``, reflection, layered over the base): anisotropic GGX
  ``D`` with ``alpha`` from ``open_pbr_anisotropy`` (``alpha_x = r^2 sqrt(2 / (1 + (1 - a)^2))``,
  ``alpha_y = (1 - a) alpha_x``), height-correlated Smith ``G2`` at ``sqrt(alpha_x alpha_y)``,
  the exact dielectric Fresnel at the IOR that ``specular_weight`` modulates
  (``F0' = min(specular_weight F0(ior), 0.99999)``), Turquin's energy compensation from the
  analytic GGX albedo fit, tinted by ``specular_color``; the base under it is scaled by
  ``1 - E_spec(n.v)`` (MaterialX's ``layer``: ``top + base * top.throughput``);
- **fuzz** (``sheen_bsdf`` mode ``zeltner``, layered over everything): Zeltner et al.'s LTC
  sheen times its directional albedo, ``fuzz_weight`` and ``fuzz_color``; the layers under it
  are scaled by ``1 - fuzz_weight E_fuzz(n.v)``.

Coat, metalness, transmission, subsurface, thin film and emission stay at the definition's
defaults (weight 0), which contribute nothing to the direct light.

Units and frames follow :mod:`usdbtf.svbrdf`: a BTF value is ``W pi f (n . l)`` (the
capture light has irradiance ``pi W``); directions are in the sample's tangent frame.  The
anisotropy's direction is the tangent ``(cos phi, sin phi, 0)`` (``phi`` in [0, pi), from
image right towards image up), projected onto the texel's normal as MaterialX does.

:func:`fit_openpbr` fits the maps per texel, streamed over texel blocks like
:func:`usdbtf.svbrdf.fit_svbrdf` and on the same samples, keeping its normals (the two
fallbacks share one normal map).  The model is linear in the three colours (base,
specular tint, fuzz) once the other inputs are fixed, so every candidate of those is a
box-constrained least squares per channel (three unknowns in [0, 1]) from sums over the
samples; the other inputs are searched per texel, a stage at a time:

1. specular roughness x specular weight (F0 0.04, 0.2 or ~1), no fuzz, Lambert base: the
   family of the UsdPreviewSurface fit;
2. anisotropy (0.4, 0.7, 0.9) x direction (0, 45, 90, 135 degrees) x roughness around stage 1's;
3. fuzz weight x fuzz roughness;
4. base diffuse roughness (0.5, 1);
5. specular roughness again, one grid step either side.

Each stage keeps a candidate only where it lowers the fit samples' residual.  Last, every
texel keeps stage 1's parameters unless the final ones predict the held-out samples
(:func:`usdbtf.svbrdf.validation_samples`) better: a richer lobe that fits the fit samples
must not flash elsewhere.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np

from .compress.format import CompressedBTF
from .numeric import single_blas_thread
from .progress import track
from .sampling import to_vectors
from .svbrdf import (SvbrdfMaps, VALIDATION_SAMPLES, fit_samples, fit_svbrdf, validation_samples,
                     _reconstruct)

__all__ = ["OpenPbrMaps", "evaluate_openpbr", "evaluate", "fit_openpbr", "SPECULAR_IOR",
           "SPECULAR_ROUGHNESS_GRID", "SPECULAR_WEIGHTS", "FUZZ_WEIGHTS", "FUZZ_ROUGHNESS_GRID"]

log = logging.getLogger(__name__)

M_FLOAT_EPS = 1e-8                     # MaterialX's M_FLOAT_EPS (mx_microfacet.glsl)
#: The dielectric IOR the fit authors (the definition's default); ``specular_weight`` scales its F0.
SPECULAR_IOR = 1.5
SPECULAR_ROUGHNESS_GRID = np.array([0.12, 0.16, 0.2, 0.25, 0.3, 0.36, 0.43, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0],
                                   np.float32)
#: specular_weight candidates: F0 = 0.04 w (clamped at 0.99999): 0.04, 0.2, ~1.
SPECULAR_WEIGHTS = np.array([1.0, 5.0, 25.0], np.float32)
ANISOTROPY_GRID = np.array([0.4, 0.7, 0.9], np.float32)
ROTATION_GRID = np.radians(np.array([0.0, 45.0, 90.0, 135.0])).astype(np.float32)
FUZZ_WEIGHTS = np.array([0.3, 0.6, 1.0], np.float32)
FUZZ_ROUGHNESS_GRID = np.array([0.2, 0.35, 0.5, 0.7, 1.0], np.float32)
DIFFUSE_ROUGHNESS_GRID = np.array([0.5, 1.0], np.float32)
_FUJII_1 = 0.5 - 2.0 / (3.0 * np.pi)
_FUJII_2 = 2.0 / 3.0 - 28.0 / (15.0 * np.pi)


@dataclass
class OpenPbrMaps:
    """Per-texel ``open_pbr_surface`` inputs (the ones the fit sets; the rest stay at their
    defaults, ``specular_ior`` = :data:`SPECULAR_IOR`).

    base_color, specular_color, fuzz_color : (H, W, 3) float32, linear ``working_space``, [0, 1].
    base_diffuse_roughness, specular_weight, specular_roughness, specular_anisotropy,
    fuzz_weight, fuzz_roughness : (H, W) float32 (``specular_weight`` in [0, 25], the rest [0, 1]).
    specular_rotation : (H, W) float32 radians in [0, pi): the anisotropy's tangent
    ``(cos, sin, 0)`` in the texel's frame (x image right, y image up).
    normal : (H, W, 3) float32 unit tangent-space normals (the UsdPreviewSurface fit's).
    white_level : the BTF value a white Lambertian lit head-on reads (:mod:`usdbtf.svbrdf`).
    """

    base_color: np.ndarray
    base_diffuse_roughness: np.ndarray
    specular_weight: np.ndarray
    specular_color: np.ndarray
    specular_roughness: np.ndarray
    specular_anisotropy: np.ndarray
    specular_rotation: np.ndarray
    fuzz_weight: np.ndarray
    fuzz_color: np.ndarray
    fuzz_roughness: np.ndarray
    normal: np.ndarray
    working_space: str
    white_level: float = 1.0

    COLOURS = ("base_color", "specular_color", "fuzz_color")
    SCALARS = ("base_diffuse_roughness", "specular_weight", "specular_roughness", "specular_anisotropy",
               "specular_rotation", "fuzz_weight", "fuzz_roughness")

    @property
    def shape(self) -> tuple[int, int]:
        return self.specular_roughness.shape

    def gathered(self, gather) -> "OpenPbrMaps":
        """These maps with every per-texel array passed through ``gather`` ((H, W, ...) -> (H', W', ...))."""
        return replace(self, **{name: gather(getattr(self, name))
                                for name in (*self.COLOURS, *self.SCALARS, "normal")})

    def params(self, texels=slice(None)) -> dict:
        """{input: (T,) or (T, 3) float32} of ``texels`` (row-major), for :func:`evaluate_openpbr`."""
        out = {name: getattr(self, name).reshape(-1, 3)[texels].astype(np.float32) for name in self.COLOURS}
        out.update({name: getattr(self, name).reshape(-1)[texels].astype(np.float32) for name in self.SCALARS})
        out["normal"] = self.normal.reshape(-1, 3)[texels].astype(np.float32)
        return out


# ------------------------------------------------------------------ MaterialX's lobes
def _sq(x):
    return x * x


def ggx_dir_albedo(ndv, alpha, f0, f90):
    """mx_ggx_dir_albedo_analytic: the rational fit of GGX's directional albedo."""
    x, y = ndv, alpha
    x2, y2 = x * x, y * y
    c = np.array([[0.1003, 0.9345, 1.0, 1.0], [-0.6303, -2.323, -1.765, 0.2281], [9.748, 2.229, 8.263, 15.94],
                  [-2.038, -3.748, 11.53, -55.83], [29.34, 1.424, 28.96, 13.08], [-8.245, -0.7684, -7.507, 41.26],
                  [-26.44, 1.436, -36.11, 54.9], [19.99, 0.2913, 15.86, 300.2], [-5.448, 0.6286, 33.37, -285.1]],
                 dtype=np.float32)
    terms = (1.0, x, y, x * y, x2, y2, x2 * y, x * y2, x2 * y2)
    r = [sum(c[i, j] * t for i, t in enumerate(terms)) for j in range(4)]
    a = np.clip(r[0] / r[2], 0.0, 1.0)
    b = np.clip(r[1] / r[3], 0.0, 1.0)
    return f0 * a + f90 * b


def fresnel_dielectric(cos_theta, ior):
    """mx_fresnel_dielectric (total internal reflection -> 1)."""
    c = cos_theta
    g2 = ior * ior + c * c - 1.0
    g = np.sqrt(np.maximum(g2, 0.0))
    f = 0.5 * _sq((g - c) / (g + c)) * (1.0 + _sq(((g + c) * c - 1.0) / ((g - c) * c + 1.0)))
    return np.where(g2 < 0.0, 1.0, f)


def specular_alpha(roughness, anisotropy):
    """(alpha_x, alpha_y) of open_pbr_anisotropy, clamped as dielectric_bsdf does."""
    inv = 1.0 - anisotropy
    ax = roughness * roughness * np.sqrt(2.0 / (inv * inv + 1.0))
    return np.clip(ax, M_FLOAT_EPS, 1.0), np.clip(inv * ax, M_FLOAT_EPS, 1.0)


def modulated_ior(specular_weight, ior=SPECULAR_IOR):
    """The IOR open_pbr_surface gives dielectric_bsdf: F0 scaled by specular_weight (no coat)."""
    f0 = np.clip(specular_weight * _sq((ior - 1.0) / (ior + 1.0)), 0.0, 0.99999)
    s = np.sign(ior - 1.0) * np.sqrt(f0)
    return (1.0 + s) / (1.0 - s)


def zeltner_dir_albedo(x, y):
    """mx_zeltner_sheen_dir_albedo (x = n.v, y = roughness)."""
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    return np.exp(-0.5 * _sq((x - m) / s)) / (s * np.sqrt(2.0 * np.pi)) + o


def _zeltner_ltc(wx, wy, wz, ndv, roughness):
    """mx_zeltner_sheen_brdf from the light in the LTC frame (w = (x, y, z))."""
    a_inv = (2.58126 * ndv + 0.813703 * roughness) * roughness / (1.0 + 0.310327 * ndv * ndv + 2.60994 * ndv * roughness)
    b_inv = np.sqrt(1.0 - ndv) * (roughness - 1.0) * roughness ** 3 / (
        0.0000254053 + 1.71228 * ndv - 1.71506 * ndv * roughness + 1.34174 * roughness * roughness)
    ox, oy = a_inv * wx + b_inv * wz, a_inv * wy
    len2 = ox * ox + oy * oy + wz * wz
    return np.maximum(wz, 0.0) / np.pi * _sq(a_inv / len2)


def fujii_dir_albedo(cos_theta, sigma):
    """mx_oren_nayar_fujii_diffuse_dir_albedo."""
    a = 1.0 / (1.0 + _FUJII_1 * sigma)
    b = sigma * a
    si = np.sqrt(np.maximum(0.0, 1.0 - cos_theta * cos_theta))
    g = si * (np.arccos(np.clip(cos_theta, -1.0, 1.0)) - si * cos_theta) + \
        2.0 * ((si / cos_theta) * (1.0 - si * si * si) - si) / 3.0
    return a + b * g / np.pi


def fujii_avg_albedo(sigma):
    a = 1.0 / (1.0 + _FUJII_1 * sigma)
    return a * (1.0 + _FUJII_2 * sigma)


class _Frame:
    """Per (sample, texel) dot products of MaterialX's direct lighting: normals (T, 3) and
    unit directions (S, 3); every array (S, T) in the dtype of ``dtype``."""

    def __init__(self, n, v, l, dtype=np.float32):
        n = np.asarray(n, dtype)
        v, l = np.asarray(v, dtype), np.asarray(l, dtype)
        nv_raw = v @ n.T
        # mx_forward_facing_normal: a normal facing away from the view is flipped.
        self.flip = np.where(nv_raw < 0.0, -1.0, 1.0).astype(dtype)
        self.nv = np.clip(nv_raw * self.flip, M_FLOAT_EPS, 1.0)
        self.nl = np.clip((l @ n.T) * self.flip, M_FLOAT_EPS, 1.0)
        self.nl_raw = (l @ n.T) * self.flip
        h = v + l
        h = h / np.linalg.norm(h, axis=1, keepdims=True)
        self.h, self.v, self.l, self.n = h, v, l, n
        self.nh = (h @ n.T) * self.flip
        self.vh = np.clip(np.einsum("ij,ij->i", v, h), M_FLOAT_EPS, 1.0)[:, None].astype(dtype)
        self.lv = np.clip(np.einsum("ij,ij->i", l, v), M_FLOAT_EPS, 1.0)[:, None].astype(dtype)
        self.dtype = dtype
        self._tangent = {}

    def tangent_dots(self, rotation):
        """(H.X, H.Y) (S, T) for tangents at ``rotation`` (T,) radians, projected as dielectric_bsdf does."""
        n = self.n * self.flip[..., None]                                  # (S, T, 3) forward-facing normals
        t = np.stack([np.cos(rotation), np.sin(rotation), np.zeros_like(rotation)], axis=-1).astype(self.dtype)
        x = t[None] - np.sum(t[None] * n, axis=-1, keepdims=True) * n
        x /= np.linalg.norm(x, axis=-1, keepdims=True)
        y = np.cross(n, x)
        return np.einsum("sk,stk->st", self.h, x), np.einsum("sk,stk->st", self.h, y)

    def specular(self, roughness, anisotropy, rotation, weight):
        """(response without tint, throughput) of dielectric_bsdf, each (S, T), for per-texel
        (T,) inputs (rotation None: isotropic, where D does not need the tangent)."""
        ax, ay = specular_alpha(roughness, anisotropy)
        avg = np.sqrt(ax * ay)
        ior = modulated_ior(weight)
        if rotation is None:
            hz2 = self.nh * self.nh
            denom = (1.0 - hz2) / (ax * ax) + hz2                          # |H_t.xy / alpha|^2 + H_t.z^2 (ax == ay)
        else:
            hx, hy = self.tangent_dots(rotation)
            denom = _sq(hx / ax) + _sq(hy / ay) + self.nh * self.nh
        d = 1.0 / (np.pi * ax * ay * denom * denom)
        f = fresnel_dielectric(self.vh, ior)
        a2 = avg * avg
        lam_l = np.sqrt(a2 + (1.0 - a2) * self.nl * self.nl)
        lam_v = np.sqrt(a2 + (1.0 - a2) * self.nv * self.nv)
        g = 2.0 * self.nl * self.nv / (lam_l * self.nv + lam_v * self.nl)
        ess = ggx_dir_albedo(self.nv, avg, 1.0, 1.0)
        comp = 1.0 + f * (1.0 - ess) / ess
        f0 = _sq((ior - 1.0) / (ior + 1.0))
        throughput = 1.0 - ggx_dir_albedo(self.nv, avg, f0, 1.0) * comp
        return d * f * g * comp / (4.0 * self.nv), throughput

    def fuzz(self, roughness, weight):
        """(response without colour, throughput) of sheen_bsdf (zeltner), each (S, T)."""
        r = np.clip(roughness, 0.01, 1.0)
        n = self.n[None] * self.flip[..., None]                            # (S, T, 3)
        x = self.v[:, None, :] - n * self.nv[..., None]
        len2 = np.sum(x * x, axis=-1, keepdims=True)
        ok = len2 > 0.0
        x = np.where(ok, x / np.sqrt(np.where(ok, len2, 1.0)), _any_tangent(n))
        y = np.cross(n, x)
        lw = self.l[:, None, :]
        wx, wy, wz = np.sum(x * lw, -1), np.sum(y * lw, -1), np.sum(n * lw, -1)
        albedo = zeltner_dir_albedo(self.nv, r)
        return albedo * _zeltner_ltc(wx, wy, wz, self.nv, r) * weight, 1.0 - albedo * weight

    def diffuse(self, sigma):
        """(single-scattering factor, multiple-scattering factor, E_avg): the base's response is
        ``(c * single + ms(c) * multi) n.l / pi`` with ``ms(c) = c^2 E_avg / (1 - c (1 - E_avg))``."""
        s = self.lv - self.nl * self.nv
        stinv = np.where(s > 0.0, s / np.maximum(self.nl, self.nv), s)
        a = 1.0 / (1.0 + _FUJII_1 * sigma)
        single = a * (1.0 + sigma * stinv)
        avg = fujii_avg_albedo(sigma)
        multi = (np.maximum(M_FLOAT_EPS, 1.0 - fujii_dir_albedo(self.nv, sigma))
                 * np.maximum(M_FLOAT_EPS, 1.0 - fujii_dir_albedo(self.nl, sigma))
                 / np.maximum(M_FLOAT_EPS, 1.0 - avg))
        return single * self.nl / np.pi, multi * self.nl / np.pi, avg


def _any_tangent(n):
    """mx_orthonormal_basis's X for normals (..., 3) (used where V == N: the lobe is then symmetric)."""
    sign = np.where(n[..., 2] < 0.0, -1.0, 1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    return np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], axis=-1)


def _multi_colour(c, avg):
    return c * c * avg / (1.0 - c * np.maximum(0.0, 1.0 - avg))


def evaluate_openpbr(params: dict, view: np.ndarray, light: np.ndarray, dtype=np.float32) -> np.ndarray:
    """(S, T, 3) radiance of ``open_pbr_surface`` under a directional light of irradiance 1
    from unit ``light`` (S, 3), seen from unit ``view`` (S, 3), for per-texel inputs
    ``params`` ({input: (T,) or (T, 3)}, :meth:`OpenPbrMaps.params`; missing inputs take the
    fit's neutral values).  This is ``f(v, l) (n . l)`` as MaterialX's GLSL computes it."""
    t = len(params["normal"])
    get = lambda name, default: np.asarray(params.get(name, np.full(t, default)), dtype)  # noqa: E731
    fr = _Frame(params["normal"], view, light, dtype)
    rotation = get("specular_rotation", 0.0)
    aniso = get("specular_anisotropy", 0.0)
    spec, t_spec = fr.specular(get("specular_roughness", 0.3), aniso, rotation, get("specular_weight", 1.0))
    fuzz, t_fuzz = fr.fuzz(get("fuzz_roughness", 0.5), get("fuzz_weight", 0.0))
    single, multi, avg = fr.diffuse(get("base_diffuse_roughness", 0.0))
    base = np.maximum(np.asarray(params["base_color"], dtype), 0.0)
    out = np.empty((len(view), t, 3), dtype)
    for c in range(3):
        diffuse = base[:, c] * single + _multi_colour(base[:, c], avg) * multi
        spec_c = spec * np.maximum(np.asarray(params.get("specular_color", np.ones((t, 3))), dtype)[:, c], 0.0)
        fuzz_c = fuzz * np.asarray(params.get("fuzz_color", np.ones((t, 3))), dtype)[:, c]
        out[..., c] = fuzz_c + t_fuzz * (spec_c + t_spec * diffuse)
    return out


def evaluate(maps: OpenPbrMaps, view_deg: np.ndarray, light_deg: np.ndarray, texels=slice(None)) -> np.ndarray:
    """(S, T, 3) float32 BTF values the fitted surface predicts at samples (view, light) in
    degrees (S, 2 each), ``texels`` a slice or index array (row-major): :func:`evaluate_openpbr`
    times ``pi W`` (module docstring)."""
    v, l = to_vectors(np.asarray(view_deg, float)), to_vectors(np.asarray(light_deg, float))
    return evaluate_openpbr(maps.params(texels), v, l) * np.float32(np.pi * maps.white_level)
