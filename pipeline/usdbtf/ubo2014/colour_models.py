"""The decorrelated colour models of Bonn's BTF files, and their inverses.

A DFMF file factorises each channel of a *decorrelated* colour model rather than RGB
(``color_model`` in the file).  Decoding multiplies the factors out per channel, then
inverts the model here, then (FMF with dynamic-range reduction) undoes the logarithm.

The inverses follow cgbonn/btflib's ``undecorrelate.m`` (the format's authors):

====  ===================  ============================================================
id    name                 inverse, per texel (c0, c1, c2 the decoded channels)
====  ===================  ============================================================
0     RGB                  none
1     YUV                  RGB = M_yuv (c0, c1, c2)
2     CIELAB               not supported: btflib hands it to MATLAB's ``makecform``,
                           whose white point and output encoding the file does not say
3     PCA                  RGB = (c0, c1, c2) @ T + mean  (T, mean from the file)
4     YCoCg                RGB = M_ycocg (c0, c1, c2)
5     spectral             btflib's ratio model (first channel the sum)
6     spectral linear      btflib's linear ratio model
9     log Y, U, V          Y = exp(c0) - eps, then YUV
10    log Y, log U, log V  Y = exp(c0) - eps, U/V = sign(c) exp(|c| + log eps), then YUV
11    log Y, U/Y, V/Y      Y = exp(c0) - eps, U = c1 (Y + eps), V = c2 (Y + eps), then YUV
12    log RGB              RGB = exp(c) - eps
====  ===================  ============================================================

``eps`` is btflib's ``drr_eps`` default, 1e-5 (no file stores it).  M_yuv is the
analogue YUV -> RGB matrix btflib uses (rows (1, 0, 1.13983), (1, -0.39465, -0.5806),
(1, 2.03211, 0)).

Where the references disagree (model 11): zeroeffects/btf (and btf-extractor, which
embeds it) computes U = c1 Y + eps instead of c1 (Y + eps) and clamps RGB to [0, 1].
The two differ by eps (c1 - 1) in U and V before the matrix -- at most a few 1e-5 in RGB
for chroma ratios of order one -- and by the clamp, which would cut every value above 1 of
this HDR data.  usdbtf follows btflib and does not clamp here (the reader clamps
negative radiance to 0 afterwards, see :mod:`usdbtf.ubo2014`).
"""
from __future__ import annotations

import numpy as np

from ..errors import BTFError

__all__ = ["MODEL_NAMES", "DRR_EPS", "YUV_TO_RGB", "YCOCG_TO_RGB", "undecorrelate", "restore_dynamic_range",
           "check_model"]

#: btflib's default ``drr_eps`` (the offset added before the logarithm when encoding).
DRR_EPS = 1e-5

YUV_TO_RGB = np.array([[1.0, 0.0, 1.13983], [1.0, -0.39465, -0.5806], [1.0, 2.03211, 0.0]])
YCOCG_TO_RGB = np.array([[1.0, 1.0, -1.0], [1.0, 0.0, 1.0], [1.0, -1.0, -1.0]])

MODEL_NAMES = {
    0: "RGB", 1: "YUV", 2: "CIELAB", 3: "PCA", 4: "YCoCg", 5: "spectral", 6: "spectral linear",
    9: "log Y, U, V", 10: "log Y, log U, log V", 11: "log Y, U/Y, V/Y", 12: "log RGB",
}
_SUPPORTED = set(MODEL_NAMES) - {2}


def check_model(model: int, where: str) -> None:
    """Raise BTFError unless ``model`` is a colour model this module inverts."""
    if model == 2:
        raise BTFError(f"{where}: colour model 2 (CIELAB) is not supported: btflib converts it with MATLAB's "
                       "makecform('lab2srgb'), whose white point and output encoding the file does not record")
    if model not in _SUPPORTED:
        raise BTFError(f"{where}: unknown colour model {model} (known: "
                       f"{', '.join(f'{k} {v}' for k, v in MODEL_NAMES.items())})")


def undecorrelate(values: np.ndarray, model: int, *, mean=None, matrix=None, eps: float = DRR_EPS) -> np.ndarray:
    """Decoded channels -> RGB, btflib's ``undecorrelate``.

    Parameters
    ----------
    values : (..., 3) float32 decoded channel values (modified in place where possible).
    model : int, the file's ``color_model``.
    mean : (3,) the file's ``color_mean`` (model 3 only).
    matrix : (3, 3) the file's colour transformation matrix as stored, row-major (model 3 only).

    Returns
    -------
    (..., 3) float32 linear RGB (not clamped).
    """
    check_model(model, "colour model")
    v = np.asarray(values, np.float32)
    if model == 0:
        return v
    if model == 3:
        # btflib: values * T (a row vector times the stored matrix), then + mean.
        out = _mix(v, np.asarray(matrix, np.float64).T)
        out += np.asarray(mean, np.float32)
        return out
    if model == 4:
        return _mix(v, YCOCG_TO_RGB)
    if model in (5, 6):
        return _spectral(v, linear=model == 6)
    if model == 12:
        np.exp(v, out=v)
        v -= np.float32(eps)
        return v
    if model in (9, 10, 11):
        y = v[..., 0]
        np.exp(y, out=y)
        y -= np.float32(eps)
        if model == 10:
            chroma = v[..., 1:]
            chroma[...] = np.sign(chroma) * np.exp(np.abs(chroma) + np.float32(np.log(eps)))
        elif model == 11:
            v[..., 1:] *= (y + np.float32(eps))[..., None]
    return _mix(v, YUV_TO_RGB)


def _mix(v: np.ndarray, matrix) -> np.ndarray:
    """``matrix @ rgb`` per texel, as separate float32 multiplies and adds in a fixed order.

    Not OpenCV's ``transform``: its SIMD body and scalar tail round differently, so a
    texel's value would depend on how many texels were converted with it."""
    m = np.asarray(matrix, np.float32)
    out = np.empty(v.shape, np.float32)
    for i in range(3):
        acc = v[..., 0] * m[i, 0]
        acc += v[..., 1] * m[i, 1]
        acc += v[..., 2] * m[i, 2]
        out[..., i] = acc
    return out


def _spectral(v: np.ndarray, *, linear: bool) -> np.ndarray:
    """btflib's models 5 and 6, literally (channel 0 carries the sum, the others ratios)."""
    v = v.copy()
    n = v.shape[-1]
    if not linear:
        first = np.ones(v.shape[:-1], np.float32)
        total = v[..., 0].copy()
        for c in range(1, n):
            first -= v[..., c]
            v[..., c] *= total
        v[..., 0] = first * total
        return v
    div = np.float32(1.0 / n)
    total = v[..., 0] / div
    v[..., 0] = total
    for c in range(1, n):
        v[..., 0] -= v[..., c] * div
        v[..., c] = total + v[..., c] * total
    return v


def restore_dynamic_range(values: np.ndarray, method: int, eps: float = DRR_EPS) -> np.ndarray:
    """btflib's ``restore_dynamic_range``: exp(x) - eps when the file's method is non-zero."""
    if not method:
        return values
    np.exp(values, out=values)
    values -= np.float32(eps)
    return values
