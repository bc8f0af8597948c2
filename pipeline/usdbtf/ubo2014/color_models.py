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


def undecorrelate(values: np.ndarray, model: int, *, mean=None, matrix=None, eps: float = DRR_EPS,
                  axis: int = -1) -> np.ndarray:
    """Decoded channels -> RGB, btflib's ``undecorrelate``.

    Parameters
    ----------
    values : float32 decoded channel values, the 3 channels along ``axis`` (modified in place
        where possible).  Planar data (``axis=0``, each channel contiguous) is the fast layout.
    model : int, the file's ``color_model``.
    mean : (3,) the file's ``color_mean`` (model 3 only).
    matrix : (3, 3) the file's colour transformation matrix as stored, row-major (model 3 only).

    Returns
    -------
    float32 linear RGB, same shape and channel axis (not clamped).
    """
    check_model(model, "colour model")
    v = np.moveaxis(np.asarray(values, np.float32), axis, 0)   # v[c]: channel plane c
    if model == 0:
        out = v
    elif model == 3:
        # btflib: values * T (a row vector times the stored matrix), then + mean.
        out = _mix(v, np.asarray(matrix, np.float64).T)
        for c in range(3):
            out[c] += np.float32(mean[c])
    elif model == 4:
        out = _mix(v, YCOCG_TO_RGB)
    elif model in (5, 6):
        out = _spectral(v, linear=model == 6)
    elif model == 12:
        np.exp(v, out=v)
        v -= np.float32(eps)
        out = v
    else:  # 1, 9, 10, 11: YUV after the luminance / chroma transforms
        if model in (9, 10, 11):
            np.exp(v[0], out=v[0])
            v[0] -= np.float32(eps)
        if model == 10:
            for c in (1, 2):
                v[c] = np.sign(v[c]) * np.exp(np.abs(v[c]) + np.float32(np.log(eps)))
        elif model == 11:
            scale = v[0] + np.float32(eps)
            v[1] *= scale
            v[2] *= scale
        out = _mix(v, YUV_TO_RGB)
    return np.moveaxis(out, 0, axis)


def _mix(v: np.ndarray, matrix) -> np.ndarray:
    """``matrix @ rgb`` on channel planes v[0..2], as separate float32 multiplies and adds in
    a fixed order (zero coefficients skipped).

    Not OpenCV's ``transform``: its SIMD body and scalar tail round differently, so a
    texel's value would depend on how many texels were converted with it."""
    m = np.asarray(matrix, np.float32)
    out = np.empty(v.shape, np.float32)
    for i in range(3):
        acc = out[i]
        terms = [j for j in range(3) if m[i, j] != 0]
        if not terms:
            acc[...] = 0
            continue
        np.multiply(v[terms[0]], m[i, terms[0]], out=acc)
        for j in terms[1:]:
            acc += v[j] * m[i, j]
    return out


def _spectral(v: np.ndarray, *, linear: bool) -> np.ndarray:
    """btflib's models 5 and 6, literally (channel 0 carries the sum, the others ratios)."""
    v = v.copy()
    n = v.shape[0]
    if not linear:
        first = np.ones(v.shape[1:], np.float32)
        total = v[0].copy()
        for c in range(1, n):
            first -= v[c]
            v[c] *= total
        v[0] = first * total
        return v
    div = np.float32(1.0 / n)
    total = v[0] / div
    v[0] = total
    for c in range(1, n):
        v[0] -= v[c] * div
        v[c] = total + v[c] * total
    return v


def restore_dynamic_range(values: np.ndarray, method: int, eps: float = DRR_EPS) -> np.ndarray:
    """btflib's ``restore_dynamic_range``: exp(x) - eps when the file's method is non-zero."""
    if not method:
        return values
    np.exp(values, out=values)
    values -= np.float32(eps)
    return values
