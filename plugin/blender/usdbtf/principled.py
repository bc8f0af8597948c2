"""Principled BSDF inputs that reproduce an ``open_pbr_surface`` fit: numpy only (no bpy).

The add-on (``network.build_principled``) reads the asset's OpenPBR maps and gives Blender's
Principled BSDF (Blender 4.x/5.x: Cycles' ``svm_node_closure_bsdf``) these per-texel inputs.
Two lobes are parameterised differently from MaterialX 1.39's ``open_pbr_surface`` (the
model ``usdbtf.openpbr`` fits, checked against MaterialX's generated GLSL), and are
converted here so that both surfaces give the same response:

- **Anisotropy**: OpenPBR ``alpha_x = r^2 sqrt(2 / (1 + (1 - a)^2))``, ``alpha_y = (1 - a)
  alpha_x``; Cycles ``alpha_x = r^2 / s``, ``alpha_y = r^2 s`` with ``s = sqrt(1 - 0.9 a)``.
  The same pair of alphas: ``r' = (alpha_x alpha_y)^(1/4)``, ``a' = (1 - alpha_y / alpha_x) / 0.9``
  (``a / 0.9`` unless MaterialX's clamp of the alphas at 1 bites; exact for a <= 0.9, the fit's largest).
- **Colour of a layer and what it lets through**: MaterialX tints the specular reflection with
  ``specular_color`` but attenuates the base by the *untinted* albedo, ``1 - (F0 A + B) c``
  (``c`` the energy compensation, (A, B) MaterialX's GGX albedo fit); Cycles tints ``F0`` and
  attenuates every channel by the *largest channel* of the tinted albedo (its layering weight,
  ``1 - max_c albedo_c``).  Likewise the fuzz: MaterialX ``1 - w E_fuzz``, Cycles
  ``1 - w E_fuzz max_c tint_c``.  The base colour (and, under the fuzz, the specular tint) is scaled by
  the ratio of the two throughputs, evaluated head-on (n.v = 1, the pole view; the ratio drifts
  towards grazing views).

Specular weight -> Specular IOR Level ``w / 2`` (Cycles scales F0 by ``2 level``, as
``specular_weight`` does; IOR 1.5).  What stays different: Blender's Oren-Nayar diffuse (its
``Diffuse Roughness``) is not MaterialX's Fujii model with energy compensation, and Cycles'
Fresnel tint goes to white at grazing angles where MaterialX's stays tinted.
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


def principled_inputs(base, specular, fuzz, params, lobes, ndv: float = 1.0) -> dict:
    """Per-texel Principled BSDF inputs from the OpenPBR maps as the files hold them.

    base, specular, fuzz : (..., 3) sRGB-encoded values in [0, 1] (the colour files / 255).
    params : (..., 3) (specular_roughness, specular_roughness_anisotropy, base_diffuse_roughness).
    lobes : (..., 3) (fuzz_weight, fuzz_roughness, specular_weight / 25).
    ndv : the n.v at which the throughputs are matched (1: head-on).
    Returns {"Base Color", "Specular Tint", "Sheen Tint"}: (..., 3) linear Rec.709;
    {"Roughness", "Anisotropic", "Diffuse Roughness", "Specular IOR Level", "Sheen Weight",
    "Sheen Roughness"}: (...,) float.
    """
    base, tint, fuzz_c = (srgb_to_linear(c) for c in (base, specular, fuzz))
    params, lobes = np.asarray(params, np.float64), np.asarray(lobes, np.float64)
    r, a = params[..., 0], params[..., 1]
    w = lobes[..., 2] * SPECULAR_WEIGHT_SCALE
    f0 = np.clip(w * F0_IOR_15, 0.0, 0.99999)
    inv = 1.0 - a
    ax_raw = r * r * np.sqrt(2.0 / (inv * inv + 1.0))
    ax, ay = np.clip(ax_raw, 1e-8, 1.0), np.clip(inv * ax_raw, 1e-8, 1.0)     # as dielectric_bsdf clamps
    avg = np.sqrt(ax * ay)
    a_, b_ = _ggx_albedo_ab(ndv, avg)
    ess = np.maximum(a_ + b_, 1e-6)
    comp = 1.0 + f0 * (1.0 - ess) / ess
    through_mx = 1.0 - (f0 * a_ + b_) * comp
    f0t = f0[..., None] * tint
    # Cycles attenuates the layers below by its largest channel: 1 - max_c(albedo_c).
    albedo_cycles = (f0t * a_[..., None] + b_[..., None]) * (1.0 + f0t * ((1.0 - ess) / ess)[..., None])
    through_cycles = 1.0 - albedo_cycles.max(axis=-1)
    spec_ratio = (through_mx / np.maximum(through_cycles, 1e-6))[..., None]
    fw, fr = lobes[..., 0], np.clip(lobes[..., 1], 0.01, 1.0)
    e_fuzz = _zeltner_albedo(ndv, fr)
    fuzz_ratio = ((1.0 - fw * e_fuzz) / np.maximum(1.0 - fw * e_fuzz * fuzz_c.max(axis=-1), 1e-6))[..., None]
    return {"Base Color": base * spec_ratio * fuzz_ratio, "Specular Tint": tint * fuzz_ratio,
            "Sheen Tint": fuzz_c,
            "Roughness": np.sqrt(np.sqrt(ax * ay)), "Anisotropic": np.clip((1.0 - ay / ax) / 0.9, 0.0, 1.0),
            "Diffuse Roughness": params[..., 2], "Specular IOR Level": f0 / (2.0 * F0_IOR_15),
            "Sheen Weight": fw, "Sheen Roughness": lobes[..., 1]}
