"""Principled BSDF inputs that reproduce an ``open_pbr_surface`` fit: numpy only (no bpy).

The add-on (``network.build_principled``) reads the asset's OpenPBR maps and gives Blender's
Principled BSDF (Blender 4.x/5.x; with Open Shading Language, as the add-on renders,
Cycles' ``node_principled_bsdf.osl`` and the closures' setup in ``kernel/osl`` and
``kernel/closure``) these per-texel inputs.  Four lobes or layers are computed differently from
MaterialX 1.39's ``open_pbr_surface`` (the model ``usdbtf.openpbr`` fits, checked against
MaterialX's generated GLSL), and are converted here so that both surfaces give the same
response where the fit is seen head-on (``ndv``; the pole view of the swatch checks):

- **Anisotropy**: OpenPBR ``alpha_x = r^2 sqrt(2 / (1 + (1 - a)^2))``, ``alpha_y = (1 - a)
  alpha_x``; Cycles ``alpha_x = r^2 / s``, ``alpha_y = r^2 s`` with ``s = sqrt(1 - 0.9 a)``.
  The same pair of alphas: ``r' = (alpha_x alpha_y)^(1/4)``, ``a' = (1 - alpha_y / alpha_x) / 0.9``
  (``a / 0.9`` unless MaterialX's clamp of the alphas at 1 bites; exact for a <= 0.9, the fit's largest).
- **Specular energy compensation**: MaterialX scales the tinted lobe by ``1 + F (1 - E) / E``
  with the *untinted* Fresnel F (``E`` GGX's directional albedo); Cycles' multiscatter GGX
  by ``1 + F_ms (1 - E) / E`` with Kulla and Conty's multi-bounce Fresnel ``F_ms = F_ss
  E_avg / (1 - F_ss (1 - E_avg))`` of the *tinted* ``F_ss = F0' + (1 - F0') s_avg`` (``F0' =
  F0 x Specular Tint``, ``s_avg`` the dielectric Fresnel's cosine-weighted mean rise above F0).
  Under a dark tint and a large F0 (``specular_weight`` 5..25) Cycles' lobe is up to 2x dimmer
  (measured: 0.51x where the specular roughness is 1).  The Specular Tint is solved per channel
  so that ``F0' (1 + F_ms(F0') (1 - E) / E)`` equals MaterialX's ``F0 tint (1 + F0 (1 - E) / E)``
  (head-on, where the Fresnel is F0), with F0' at most 1.
- **Colour of a layer and what it lets through**: MaterialX attenuates the base by the
  *untinted* albedo, ``1 - (F0 A + B) c`` (``c`` the energy compensation, (A, B) MaterialX's GGX
  albedo fit); Cycles attenuates every channel by the *largest channel* of the tinted layer's
  albedo (its layering weight, ``1 - max_c albedo_c``, with ``albedo_c = (F0'_c A + B) (1 +
  F_ms,c (1 - E) / E)``).  Likewise the fuzz: MaterialX ``1 - w E_fuzz``, Cycles ``1 - w E_fuzz
  max_c tint_c``.  The layers below are rescaled by the ratio of the two throughputs (the
  specular tint by the fuzz's, inside its solve).
- **Base (Diffuse Roughness > 0)**: both are Fujii's Oren-Nayar with OpenPBR's multiple
  scattering ``c^2 E_avg / (1 - c (1 - E_avg))``, but Cycles' closure weight carries the base
  colour as well (``bsdf_oren_nayar_setup``'s term times the weight ``c``): ``c^3`` where
  MaterialX has ``c^2``, up to 5 % darker at diffuse roughness 1 (c 0.44).  The Base Color is
  solved per channel so that the base's directional albedo head-on, ``c E(n.v) + ms(c) (1 -
  E(n.v))``, times the throughput ratio, is the same in both.

Specular weight -> Specular IOR Level ``w / 2`` (Cycles scales F0 by ``2 level``, as
``specular_weight`` does; IOR 1.5).  What stays different: the lobes' angular shapes where the
matches above are made head-on (Cycles' Fresnel tint goes to white at grazing angles where
MaterialX's stays tinted; the multiple scattering's split between lights), Cycles' tables
(GGX albedo, the sheen's LTC and albedo) where MaterialX uses analytic fits.
"""
from __future__ import annotations

import math

import numpy as np

#: F0 of the fit's IOR 1.5, which specular_weight scales.
F0_IOR_15 = 0.04
#: lobes.b x this = specular_weight (usdbtf.usd.asset.openpbr.SPECULAR_WEIGHT_SCALE).
SPECULAR_WEIGHT_SCALE = 25.0
#: MaterialX's rational fit of GGX's directional albedo (mx_ggx_dir_albedo_analytic).
_GGX = [[0.1003, 0.9345, 1.0, 1.0], [-0.6303, -2.323, -1.765, 0.2281], [9.748, 2.229, 8.263, 15.94],
        [-2.038, -3.748, 11.53, -55.83], [29.34, 1.424, 28.96, 13.08], [-8.245, -0.7684, -7.507, 41.26],
        [-26.44, 1.436, -36.11, 54.9], [19.99, 0.2913, 15.86, 300.2], [-5.448, 0.6286, 33.37, -285.1]]


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """The sRGB transfer function's inverse (the colour maps are sRGB-encoded Rec.709)."""
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _ggx_albedo_ab(ndv, alpha):
    r = []
    for j in range(4):
        k0 = _GGX[0][j] + alpha * (_GGX[2][j] + alpha * _GGX[5][j])
        k1 = _GGX[1][j] + alpha * (_GGX[3][j] + alpha * _GGX[7][j])
        k2 = _GGX[4][j] + alpha * (_GGX[6][j] + alpha * _GGX[8][j])
        r.append(k0 + ndv * (k1 + ndv * k2))
    return np.clip(r[0] / r[2], 0.0, 1.0), np.clip(r[1] / r[3], 0.0, 1.0)


def _zeltner_albedo(x, y):
    """mx_zeltner_sheen_dir_albedo (x = n.v, y = roughness)."""
    s = y * (0.0206607 + 1.58491 * y) / (0.0379424 + y * (1.32227 + y))
    m = y * (-0.193854 + y * (-1.14885 + y * (1.7932 - 0.95943 * y * y))) / (0.046391 + y)
    o = y * (0.000654023 + (-0.0207818 + 0.119681 * y) * y) / (1.26264 + y * (-1.92021 + y))
    return np.exp(-0.5 * ((x - m) / s) ** 2) / (s * math.sqrt(2.0 * math.pi)) + o


#: Fujii's Oren-Nayar constants (MaterialX's FUJII_CONSTANT_1, and that of its mean albedo).
_FUJII_1 = 0.5 - 2.0 / (3.0 * math.pi)
_FUJII_2 = 2.0 / 3.0 - 28.0 / (15.0 * math.pi)
#: Cycles' largest F0 for an IOR (ior_from_F0 clamps there), and its Oren-Nayar cut-off (Lambert below).
CYCLES_MAX_F0 = 0.99
CYCLES_WEIGHT_CUTOFF = 1e-5
#: Gauss-Legendre nodes and weights on [0, 1] for the hemispherical means over n.l.
_MU, _MU_WEIGHT = (lambda x, w: ((x + 1.0) / 2.0, w / 2.0))(*np.polynomial.legendre.leggauss(24))


def _fujii_dir_albedo(cos_theta, sigma):
    """mx_oren_nayar_fujii_diffuse_dir_albedo (the single scattering's directional albedo)."""
    a = 1.0 / (1.0 + _FUJII_1 * sigma)
    si = np.sqrt(np.maximum(0.0, 1.0 - cos_theta * cos_theta))
    g = si * (np.arccos(np.clip(cos_theta, -1.0, 1.0)) - si * cos_theta) + \
        2.0 * ((si / cos_theta) * (1.0 - si * si * si) - si) / 3.0
    return a + sigma * a * g / math.pi


def _multi_colour(c, e_avg):
    """OpenPBR's multiple-scattering colour of the base, ``c^2 E_avg / (1 - c (1 - E_avg))``."""
    return c * c * e_avg / (1.0 - c * (1.0 - e_avg))


def _tabulated(f, top: float, points: int = 1025):
    """``f`` (a smooth function of one variable on [0, top]) read from a table of ``points``
    values, linearly interpolated: per texel it costs one lookup, not a quadrature (maps of
    millions of texels)."""
    grid = np.linspace(0.0, top, points)
    table = f(grid)
    return lambda x: np.interp(np.asarray(x, np.float64), grid, table)


def _ggx_avg_albedo_exact(alpha):
    """(...,) GGX's cosine-weighted mean directional albedo ``2 int E(mu) mu dmu`` (E the analytic fit)."""
    a_, b_ = _ggx_albedo_ab(_MU, np.asarray(alpha, np.float64)[..., None])
    return 2.0 * np.sum((a_ + b_) * _MU * _MU_WEIGHT, axis=-1)


def _fresnel_dielectric(c, eta):
    """The exact dielectric Fresnel reflectance (unpolarised) at cos ``c``, IOR ``eta`` > 1."""
    g = np.sqrt(eta * eta + c * c - 1.0)
    return 0.5 * ((g - c) / (g + c)) ** 2 * (1.0 + (((g + c) * c - 1.0) / ((g - c) * c + 1.0)) ** 2)


def _fresnel_rise_exact(f0):
    """(...,) Cycles' ``s_avg`` for a Principled F0: the IOR it renders (``ior_from_F0``, F0 at most
    :data:`CYCLES_MAX_F0`) and the cosine-weighted mean of that IOR's Fresnel, as a fraction of the
    way from its F0 to 1 (the weight of F90 in the lobe's mean Fresnel, ``F_ss``)."""
    root = np.sqrt(np.clip(f0, 0.0, CYCLES_MAX_F0))
    eta = np.maximum((1.0 + root) / (1.0 - root), 1.0 + 1e-6)
    f0_real = ((eta - 1.0) / (eta + 1.0)) ** 2
    mean = 2.0 * np.sum(_fresnel_dielectric(_MU, eta[..., None]) * _MU * _MU_WEIGHT, axis=-1)
    return np.clip((mean - f0_real) / np.maximum(1.0 - f0_real, 1e-12), 0.0, 1.0)


_ggx_avg_albedo = _tabulated(_ggx_avg_albedo_exact, 1.0)
_fresnel_rise = _tabulated(_fresnel_rise_exact, 1.0)


def _cycles_compensation(f0t, s_avg, e_avg, missing):
    """Cycles' multiscatter GGX factor ``1 + F_ms (1 - E) / E`` for the tinted F0 ``f0t`` (...,
    3); ``missing`` = (1 - E) / E, ``s_avg`` and ``e_avg`` (...,)."""
    fss = f0t + (1.0 - f0t) * s_avg[..., None]
    e = e_avg[..., None]
    return 1.0 + fss * e / (1.0 - fss * (1.0 - e)) * missing[..., None]


def _solve_increasing(f, target, hi, iterations: int = 32):
    """The x in [0, hi] with ``f(x) = target`` (elementwise, ``f`` increasing; bisection: the
    largest x where the target is beyond ``f(hi)``)."""
    lo = np.zeros_like(target)
    hi = np.broadcast_to(hi, target.shape).astype(np.float64)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        below = f(mid) < target
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def principled_inputs(base, specular, fuzz, params, lobes, ndv: float = 1.0) -> dict:
    """Per-texel Principled BSDF inputs from the OpenPBR maps as the files hold them.

    base, specular, fuzz : (..., 3) sRGB-encoded values in [0, 1] (the colour files / 255).
    params : (..., 3) (specular_roughness, specular_roughness_anisotropy, base_diffuse_roughness).
    lobes : (..., 3) (fuzz_weight, fuzz_roughness, specular_weight / 25).
    ndv : the n.v at which the responses are matched (1: head-on).
    Returns {"Base Color", "Specular Tint", "Sheen Tint"}: (..., 3) linear Rec.709 (the base
    colour and the specular tint may exceed 1: Cycles clamps neither where they are used here);
    {"Roughness", "Anisotropic", "Diffuse Roughness", "Specular IOR Level", "Sheen Weight",
    "Sheen Roughness"}: (...,) float.
    """
    base, tint, fuzz_c = (srgb_to_linear(c) for c in (base, specular, fuzz))
    params, lobes = np.asarray(params, np.float64), np.asarray(lobes, np.float64)
    r, a, sigma = params[..., 0], params[..., 1], params[..., 2]
    w = lobes[..., 2] * SPECULAR_WEIGHT_SCALE
    f0 = np.clip(w * F0_IOR_15, 0.0, 0.99999)
    inv = 1.0 - a
    ax_raw = r * r * np.sqrt(2.0 / (inv * inv + 1.0))
    ax, ay = np.clip(ax_raw, 1e-8, 1.0), np.clip(inv * ax_raw, 1e-8, 1.0)     # as dielectric_bsdf clamps
    avg = np.sqrt(ax * ay)
    a_, b_ = _ggx_albedo_ab(ndv, avg)
    ess = np.maximum(a_ + b_, 1e-6)
    missing = (1.0 - ess) / ess
    through_mx = 1.0 - (f0 * a_ + b_) * (1.0 + f0 * missing)
    fw, fr = lobes[..., 0], np.clip(lobes[..., 1], 0.01, 1.0)
    e_fuzz = _zeltner_albedo(ndv, fr)
    fuzz_ratio = ((1.0 - fw * e_fuzz) / np.maximum(1.0 - fw * e_fuzz * fuzz_c.max(axis=-1), 1e-6))[..., None]
    # The specular lobe head-on: MaterialX F0 tint (1 + F0 m), Cycles F0' (1 + F_ms(F0') m), the
    # sheen's throughput ratio folded in; F0' = F0 x Specular Tint, at most 1.
    s_avg, e_avg = _fresnel_rise(f0), _ggx_avg_albedo(avg)
    target = f0[..., None] * tint * (1.0 + f0 * missing)[..., None] * fuzz_ratio
    f0t = _solve_increasing(lambda x: x * _cycles_compensation(x, s_avg, e_avg, missing), target, 1.0)
    # Cycles attenuates the layers below by its largest channel: 1 - max_c(albedo_c).
    albedo_cycles = (f0t * a_[..., None] + b_[..., None]) * _cycles_compensation(f0t, s_avg, e_avg, missing)
    # F0 0 is IOR 1, where Cycles leaves the lobe out (MaterialX still dims the base by its F90 part).
    through_cycles = np.where(f0 > 0.0, 1.0 - albedo_cycles.max(axis=-1), 1.0)
    ratio = (through_mx / np.maximum(through_cycles, 1e-6))[..., None] * fuzz_ratio
    # The base head-on: MaterialX c E + ms(c) (1 - E), Cycles' Oren-Nayar c' E + c' ms(min(c', 1)) (1 - E).
    e_v = _fujii_dir_albedo(ndv, sigma)[..., None]
    e_avg_d = (1.0 / (1.0 + _FUJII_1 * sigma) * (1.0 + _FUJII_2 * sigma))[..., None]
    rough = (sigma > CYCLES_WEIGHT_CUTOFF)[..., None]
    target = ratio * (base * e_v + _multi_colour(base, e_avg_d) * (1.0 - e_v))

    def cycles_base(c):
        return c * e_v + np.where(rough, c * _multi_colour(np.minimum(c, 1.0), e_avg_d), 0.0) * (1.0 - e_v)

    base_cycles = _solve_increasing(cycles_base, target, np.maximum(target / np.maximum(e_v, 1e-6), 1e-6) + 1e-6)
    # No specular (F0 0: Cycles leaves the lobe out): the tint as MaterialX's, not 0 / 0.
    spec_tint = np.where((f0 > 1e-6)[..., None], f0t / np.maximum(f0, 1e-6)[..., None], tint * fuzz_ratio)
    return {"Base Color": base_cycles, "Specular Tint": spec_tint,
            "Sheen Tint": fuzz_c,
            "Roughness": np.sqrt(np.sqrt(ax * ay)), "Anisotropic": np.clip((1.0 - ay / ax) / 0.9, 0.0, 1.0),
            "Diffuse Roughness": sigma, "Specular IOR Level": f0 / (2.0 * F0_IOR_15),
            "Sheen Weight": fw, "Sheen Roughness": lobes[..., 1]}
