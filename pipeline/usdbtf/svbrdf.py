"""A spatially varying UsdPreviewSurface fitted to a BTF: what renderers without BTF support show.

:func:`fit_svbrdf` is a pure function, compressed BTF -> :class:`SvbrdfMaps`: per texel a
diffuse colour, a specular colour (F0), a roughness and a tangent-space normal, for
UsdPreviewSurface's specular workflow.  :func:`evaluate` is that surface's direct lighting
(previewSurface.glslfx: Lambert diffuse scaled by 1 - F, GGX D, Schlick-Smith G with
k = alpha / 2, Schlick Fresnel between F0 and 1, alpha = roughness^2), so the error of a fit
against the BTF is measured with the model a renderer evaluates.

Units (:mod:`usdbtf.photometry`, the convention every path follows): a BTF value is
``I = W * pi * f(v, l) * (n . l)``, with W the source's white level (what a white Lambertian
lit head-on reads; 1 unless recorded), i.e. the capture's light has irradiance ``pi * W``.  Directions are in the sample's tangent frame (x = image right,
y = image up, z = normal); maps are (H, W, ...) arrays in the BTF's texel order.

The fit, streamed over blocks of texels (the reconstruction of a block over the fit
samples is all that is held; ``chunk_bytes`` bounds it):

1. **Samples**: at most ``max_samples`` measured samples for the reflectance fit, half of
   them the nearest to the mirror configuration, half evenly spread (:func:`fit_samples`);
   every sample at the views nearest the normal with lights up to 60 degrees for the normals.
2. **Normal** (photometric stereo): at near-normal views a diffuse surface's luminance is
   ``rho (n . l)``, linear in ``g = rho n``; least squares over the lights, then again
   without the samples whose residual is beyond 2.5 median absolute deviations (cast
   shadows, highlights).  Tilt is limited to 60 degrees.
3. **Reflectance**: with ``a = rho (1 - F0)`` the model is linear in (a, F0) per colour
   channel: ``Y = a (1 - w) (n.l) / pi + F0 S (1 - w) (n.l) + S w (n.l)`` with
   ``w = (1 - v.h)^5`` and ``S = D G / (4 (n.l)(n.v) + eps)``.  For every roughness on a
   grid (0.2 to 1, :data:`ROUGHNESS_GRID`), least squares with a >= 0, 0 <= F0 <= 1, from
   2x2 normal equations summed over samples; each texel keeps the roughness with the
   smallest residual.  The samples at the views nearest the normal with lights up to
   :data:`POLE_MAX_LIGHT_DEG` (:func:`pole_samples`: what a swatch seen head-on shows) enter
   once more, as one sample per :data:`POLE_BAND_DEG`-wide band of light elevation, the
   band's mean, weighted :data:`POLE_WEIGHT` times the fit samples' count: a least-squares fit
   over all samples is otherwise free to trade brightness at near-normal views for grazing
   ones (measured: 6-32 % too bright at pole views on pebbles, satin_weave, metal_flakes),
   and near-normal views are what a swatch, a thumbnail and most shots show.
   This is done with the flat normal (0, 0, 1), with the photometric one and, for texels
   with a sharp highlight, with the normal at their highlight's peak (:func:`_peak_normals`,
   roughness down to :data:`PEAK_ROUGHNESS`); a texel keeps a tilted normal only where that
   fit predicts :data:`VALIDATION_SAMPLES` other measured samples better (a tilted normal with
   a sharp lobe can fit the fit samples and still flash at directions they do not cover).
   Why the third: a mirror-like flake's own tilt is invisible to photometric stereo (its
   diffuse albedo is low, its highlights are discarded as outliers); on metal_flakes its
   normals were 17 degrees off (median) and 87 % of the fallback's error came from the flakes.
4. **Brightness** (:func:`keep_brightness`): the pole samples' weight in step 3 pulls the fit
   towards the BTF's brightness there but does not pin it (measured, issue 40: the model's
   swatch 3-13 % brighter than the BTF's at pole lights).  One factor per colour channel for
   the whole material scales both lobes (diffuse albedo times (1 - F0), and F0) so that the
   swatch's mean over the BTF's, averaged over the pole lights, is one.  Per material, not
   per texel: a per-texel factor chases shadows and interreflections the model cannot show
   (pebbles 16^2: error over all samples +19 %); one factor moves it by -0.7 to +1.9 %
   (``benchmarks/bench_fallback.py --before-brightness``, four presets).

:func:`flat_fallback` is the fallback usdbtf shipped before (median albedo, one roughness,
no normal map), kept as the baseline ``benchmarks/bench_fallback.py`` measures against.
"""
from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, replace

import numpy as np

from .compress import parallel
from .compress.format import CompressedBTF, working_coefficient_texels
from .numeric import single_blas_thread
from .photometry import capture_irradiance, radiance_per_irradiance
from .progress import bar
from .sampling import to_vectors

__all__ = ["SvbrdfMaps", "fit_svbrdf", "flat_fallback", "median_albedo", "fit_flat_roughness", "evaluate",
           "fit_samples", "normal_samples", "validation_samples", "keep_brightness", "brightness_scale",
           "pole_swatch_sums", "pole_ratio", "pole_ratio_weights", "pole_block_texels", "texel_weights_of",
           "BRIGHTNESS_SCALE",
           "ROUGHNESS_GRID", "MIN_ROUGHNESS",
           "VALIDATION_SAMPLES"]

log = logging.getLogger(__name__)

#: The roughness candidates.  None below 0.2: previewSurface.glslfx adds EPSILON = 0.001 to
#: alpha^2 = roughness^4 in D's numerator, which dominates below roughness ~0.18 and makes
#: the peak grow as 1 / roughness^8 -- fireflies at mirror directions the fit never saw.
ROUGHNESS_GRID = np.array([0.2, 0.25, 0.3, 0.36, 0.43, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0], np.float32)
MIN_ROUGHNESS = 0.001
_EPS = 0.001                 # previewSurface.glslfx's EPSILON in D's numerator and the specular denominator
_MAX_TILT_DEG = 60.0
_NORMAL_VIEW_TOL_DEG = 1e-3
_NORMAL_MAX_LIGHT_DEG = 60.0
#: Samples (not fitted to) on which each texel's normal map must beat the flat normal.
VALIDATION_SAMPLES = 1024
#: The near-normal views' lights up to this elevation are the "pole" samples whose mean the fit keeps.
POLE_MAX_LIGHT_DEG = 70.0
#: Weight of the pole samples' mean in the fit, in units of the fit samples' count.
POLE_WEIGHT = 1.0
#: The pole samples' mean is kept per band of light elevation this wide (degrees).
POLE_BAND_DEG = 20.0
#: Bounds of step 4's factor on the lobes (a fit further off than this is not a brightness slip).
BRIGHTNESS_SCALE = (0.5, 2.0)


@dataclass
class SvbrdfMaps:
    """Per-texel UsdPreviewSurface parameters (specular workflow).

    diffuse : (H, W, 3) float32 diffuseColor, linear, in ``working_space``, [0, 1].
    specular : (H, W, 3) float32 specularColor (F0 at normal incidence), same space, [0, 1].
    roughness : (H, W) float32, [MIN_ROUGHNESS, 1].
    normal : (H, W, 3) float32 unit tangent-space normals (x right, y up, z out), z > 0.
    white_level : the BTF value a white Lambertian lit head-on reads (see module docstring).
    """

    diffuse: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    normal: np.ndarray
    working_space: str
    white_level: float = 1.0

    @property
    def shape(self) -> tuple[int, int]:
        return self.roughness.shape

    def gathered(self, gather) -> "SvbrdfMaps":
        """These maps with every per-texel array passed through ``gather`` ((H, W, ...) ->
        (H', W', ...), e.g. :meth:`usdbtf.quilt.texels.QuiltTexels.gather`)."""
        return replace(self, diffuse=gather(self.diffuse), specular=gather(self.specular),
                       roughness=gather(self.roughness), normal=gather(self.normal))


def fit_samples(cbtf: CompressedBTF, most: int = 1536) -> np.ndarray:
    """Indices of the samples the reflectance is fitted to: all, or ``most`` of them.  Half
    are near the mirror configuration (the 4x as many samples with the smallest half-vector
    angle, thinned evenly in view order so grazing views are among them): they pin the
    highlight's height, and at grazing angles UsdPreviewSurface's Fresnel goes to 1 whatever
    F0 is, so only samples there keep the roughness honest.  The other half is an even spread
    (in sample order, which interleaves views and lights) of the rest."""
    n = cbtf.n_samples
    if n <= most:
        return np.arange(n)
    v, l = to_vectors(cbtf.sampling.view), to_vectors(cbtf.sampling.light)
    h = v + l
    cos_h = h[:, 2] / np.maximum(np.linalg.norm(h, axis=1), 1e-12)
    half = most // 2
    near = np.sort(np.argsort(-cos_h, kind="stable")[: 4 * half])       # sample order = view order
    specular = near[np.unique(np.linspace(0, len(near) - 1, half).round().astype(int))]
    rest = np.setdiff1d(np.arange(n), specular)
    spread = rest[np.unique(np.linspace(0, len(rest) - 1, most - len(specular)).round().astype(int))]
    return np.union1d(specular, spread)


def pole_samples(cbtf: CompressedBTF) -> np.ndarray:
    """Samples whose mean the fit keeps: the views nearest the normal, lights up to
    :data:`POLE_MAX_LIGHT_DEG` (what a swatch seen head-on shows)."""
    vt, lt = cbtf.sampling.view[:, 0], cbtf.sampling.light[:, 0]
    near = vt <= vt.min() + _NORMAL_VIEW_TOL_DEG
    sel = np.flatnonzero(near & (lt <= POLE_MAX_LIGHT_DEG))
    return sel if len(sel) else np.flatnonzero(near)


def normal_samples(cbtf: CompressedBTF) -> np.ndarray:
    """Samples for photometric stereo: the views nearest the normal, lights up to 60 degrees."""
    vt, lt = cbtf.sampling.view[:, 0], cbtf.sampling.light[:, 0]
    near = vt <= vt.min() + _NORMAL_VIEW_TOL_DEG
    sel = np.flatnonzero(near & (lt <= _NORMAL_MAX_LIGHT_DEG))
    return sel if len(sel) >= 3 else np.flatnonzero(near)


# ------------------------------------------------------------------ the model
class _Geometry:
    """Dot products of texel normals (T, 3) with sample directions (S, 3), each (S, T)
    float32 and clamped at 0 as previewSurface.glslfx does; ``w`` = (1 - v.h)^5 is (S, 1)."""

    def __init__(self, n: np.ndarray, v: np.ndarray, l: np.ndarray):
        h = v + l
        h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
        self.w = ((1.0 - np.clip(np.einsum("ij,ij->i", v, h), 0.0, 1.0)) ** 5).astype(np.float32)[:, None]
        n = np.ascontiguousarray(n, np.float32).T
        self.nl = np.maximum(l.astype(np.float32) @ n, 0.0)
        self.nv = np.maximum(v.astype(np.float32) @ n, 0.0)
        nh = np.maximum(h.astype(np.float32) @ n, 0.0)
        self._nh2 = nh * nh
        # n.l / (4 n.l n.v + eps): the roughness-independent part of the specular term times n.l
        self._nl_over_q = self.nl / (4 * self.nl * self.nv + np.float32(_EPS))
        self._tmp = np.empty_like(self.nl)
        # One normal for every texel (the flat-normal fits): where the matrix products gave
        # every texel the same column, bit for bit, specular_nl works on one column and copies
        # it (element-wise float32 arithmetic, so the same bits as the full (S, T) pass).
        self._one = (n.shape[1] > 1 and bool(np.all(n == n[:, :1]))
                     and all(bool(np.all(a == a[:, :1])) for a in (self.nl, self.nv, self._nh2)))

    def specular_nl(self, roughness: float) -> np.ndarray:
        """(S, T) n.l D G / (4 n.l n.v + eps) at ``roughness`` (alpha = roughness^2): the
        specular term times n.l, without F.  In place, on scratch buffers (the fit's hot loop)."""
        if self._one:
            col = self._specular_nl(roughness, self._nh2[:, :1], self.nv[:, :1], self.nl[:, :1],
                                    self._nl_over_q[:, :1], np.empty_like(self.nl[:, :1]))
            out = np.empty_like(self.nl)
            out[...] = col
            return out
        return self._specular_nl(roughness, self._nh2, self.nv, self.nl, self._nl_over_q, self._tmp)

    @staticmethod
    def _specular_nl(roughness, nh2, nv, nl, nl_over_q, tmp):
        r = max(float(roughness), MIN_ROUGHNESS)
        alpha = np.float32(r * r)
        a2, k = alpha * alpha, alpha * np.float32(0.5)
        out = np.empty_like(nl)
        np.multiply(nh2, a2 - 1, out=out)                  # D = (a2 + eps) / (pi (nh^2 (a2 - 1) + 1)^2)
        out += 1
        np.multiply(out, out, out=out)
        np.divide((a2 + np.float32(_EPS)) / np.float32(np.pi), out, out=out)
        for dot in (nv, nl):                               # G = G1(n.v) G1(n.l), G1(x) = x / (x (1 - k) + k)
            np.multiply(dot, 1 - k, out=tmp)
            tmp += k
            np.divide(dot, tmp, out=tmp)
            out *= tmp
        out *= nl_over_q
        return out


def evaluate(maps: SvbrdfMaps, view_deg: np.ndarray, light_deg: np.ndarray, texels=slice(None)) -> np.ndarray:
    """(S, T, 3) float32 BTF values the surface predicts for samples (view, light) in degrees
    (S, 2 each) at ``texels`` (a slice or index array into the H*W texels, row-major)."""
    v, l = to_vectors(np.asarray(view_deg, float)), to_vectors(np.asarray(light_deg, float))
    n = maps.normal.reshape(-1, 3)[texels].astype(np.float32)
    rho = maps.diffuse.reshape(-1, 3)[texels].astype(np.float32)
    f0 = maps.specular.reshape(-1, 3)[texels].astype(np.float32)
    rough = maps.roughness.reshape(-1)[texels].astype(np.float32)
    out = np.zeros((len(v), len(n), 3), np.float32)
    for r in np.unique(rough):               # the GGX terms depend on roughness only through its value
        sel = np.flatnonzero(rough == r)
        geo = _Geometry(n[sel], v, l)
        fres = f0[sel][None] * (1.0 - geo.w)[..., None] + geo.w[..., None]           # F = mix(F0, 1, w)
        diffuse = rho[sel][None] / np.pi * (1.0 - fres) * geo.nl[..., None]
        out[:, sel] = diffuse + geo.specular_nl(float(r))[..., None] * fres
    return out * np.float32(capture_irradiance(maps.white_level))      # f (n.l) -> value: usdbtf.photometry


# ------------------------------------------------------------------ the fit
def _chunk_texels(n_samples: int, chunk_bytes: float) -> int:
    # ~12 float32 (S, T) arrays live at once in the reflectance fit.
    return int(max(256, chunk_bytes // (n_samples * 4 * 12)))


#: Texel blocks fitted at once, at most (each holds about ``chunk_bytes``).  The blocks are cut
#: by ``chunk_bytes`` alone and each runs on one BLAS thread, so no bit of a fit depends on how
#: many run beside it or on the machine's CPUs (issue 42: the fits ran on one core, 86 of a
#: paper-scale ``--max-bytes`` compress's 152 s).
FIT_THREADS = 2


def fit_blocks(fit_block, texels: int, step: int, label: str, logger: logging.Logger) -> list:
    """``[fit_block(slice of texels) for each block of step texels]``, in block order, on up to
    :data:`FIT_THREADS` threads (no more than the CPUs), with a progress bar of the blocks done.
    ``fit_block`` writes its own texels' rows of the caller's maps (disjoint for every block)."""
    progress = bar(label, -(-texels // step), logger=logger)
    lock = threading.Lock()

    def one(t0: int):
        done = fit_block(slice(t0, min(t0 + step, texels)))
        with lock:
            progress.update()
        return done

    try:
        return parallel.in_threads(one, range(0, texels, step), threads=min(FIT_THREADS, parallel.cpu_count()))
    finally:
        progress.finish()


def _reconstruct(cbtf: CompressedBTF, rows: np.ndarray, texels: slice) -> np.ndarray:
    """(S, T, 3) float32 working-space values of samples with basis rows ``rows`` (S, k)."""
    return _block_values(cbtf, texels)(rows)


def _same_samples(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two sample index arrays are the same samples in the same order (then their
    reconstructions are one product, the same bits)."""
    return bool(np.array_equal(a, b))


def _block_values(cbtf: CompressedBTF, texels: slice):
    """``values(rows)`` = :func:`_reconstruct` (cbtf, rows, texels), the texels' coefficients
    read and widened once for every set of rows a fit reconstructs them at (the fit, pole,
    normal and validation samples: issue 42)."""
    c = working_coefficient_texels(cbtf, texels).reshape(cbtf.k, -1).astype(np.float64)    # (k, T 3)

    def values(rows: np.ndarray) -> np.ndarray:
        # The product in float64, rounded once: a float32 GEMM rounds a column by where it sits
        # in the block (the kernels' edge loops), and a quilt's texels are fitted once per source
        # texel in other blocks than a per-texel fit would put them in: their maps must agree.
        d = (rows.astype(np.float64) @ c).astype(np.float32)
        return cbtf.domain.inverse(d).reshape(len(rows), -1, 3)

    return values


def _photometric_normals(y_lum: np.ndarray, light: np.ndarray) -> np.ndarray:
    """(T, 3) unit normals from luminance ``y_lum`` (S, T) under unit lights (S, 3)."""
    outer = (light[:, :, None] * light[:, None, :]).reshape(len(light), 9)        # l l^T per sample

    def solve(weights):
        a = (weights.T @ outer).reshape(-1, 3, 3) + np.eye(3, dtype=np.float32) * 1e-6
        b = (weights * y_lum).T @ light
        return np.linalg.solve(a, b[..., None])[..., 0]                           # (T, 3) = rho n

    g = solve(np.ones_like(y_lum))
    # Again without the outliers (cast shadows, highlights): residuals beyond 2.5 MADs.
    resid = y_lum - light @ g.T
    resid -= np.median(resid, axis=0)
    mad = np.median(np.abs(resid), axis=0) + 1e-12
    g = solve((np.abs(resid) <= 2.5 * 1.4826 * mad).astype(np.float32))
    norm = np.linalg.norm(g, axis=1, keepdims=True)
    n = np.where((norm > 1e-12) & (g[:, 2:3] > 0), g / np.maximum(norm, 1e-30), [0.0, 0.0, 1.0])
    # Limit the tilt: beyond ~60 degrees photometric stereo at 13-odd lights is noise.
    max_xy = np.sin(np.radians(_MAX_TILT_DEG))
    xy = np.linalg.norm(n[:, :2], axis=1, keepdims=True)
    scale = np.where(xy > max_xy, max_xy / np.maximum(xy, 1e-30), 1.0)
    n[:, :2] *= scale
    n[:, 2] = np.sqrt(np.maximum(1.0 - (n[:, :2] ** 2).sum(axis=1), 0.0))
    return n.astype(np.float32)


#: Roughness tried with a texel's specular-peak normal (:func:`_peak_normals`): the grid's values
#: up to 0.5 (a sharp highlight's lobe) and two below it, for mirror-like flakes (alpha = r^2 of
#: 0.02-0.03) whose lobe the grid's 0.2 is too wide for.
PEAK_ROUGHNESS = np.array([0.14, 0.17], np.float32)
PEAK_MAX_ROUGHNESS = 0.5
#: A texel has a sharp highlight where its brightest fit sample is this many times its
#: median fit sample (luminance).  metal_flakes, paper sampling: the flakes' ratios are 13-41
#: (5th-95th percentile) at 32² (k 64) and 9-35 at 128² (k 242), its glossy base coat's
#: 6-11 and 7-12: the candidate is tried where it can matter and its cost stays off the rest.
PEAK_RATIO = 12.0
#: Fit samples within this fraction of the peak's luminance place the peak normal.
PEAK_FRACTION = 0.5
#: Samples above this fraction of the peak (over the median) refine it as a paraboloid's vertex
#: (:func:`_peak_normals`); 0 keeps the weighted mean half vector.
PEAK_QUADRATIC = 0.05


def _peak_normals(y: np.ndarray, luma: np.ndarray, h: np.ndarray) -> np.ndarray:
    """(T, 3) normals: per texel with a sharp highlight (:data:`PEAK_RATIO`) the
    luminance-weighted mean half vector of its fit samples above :data:`PEAK_FRACTION` of its
    brightest, NaN elsewhere.

    Why: a mirror-like flake's lobe is a few degrees wide and its own tilt (tens of degrees)
    is not what photometric stereo sees (its diffuse albedo is low and its highlights are
    discarded as outliers): metal_flakes' flakes got normals 17 degrees off (median) and
    roughness 0.7, and 87 % of the fallback's error came from them.  A lobe peaks where the
    half vector meets the normal, and the half vectors of the fit samples lie within about a
    degree of any normal up to 45 degrees (paper sampling), so the brightest samples' half
    vectors place it.

    y : (3, S, T) values of the fit samples; luma : (3,) luminance weights; h : (S, 3) unit
    half vectors of the fit samples.
    """
    lum = np.einsum("c,cst->st", luma, y)
    top = lum.max(axis=0)
    floor = np.median(lum, axis=0)
    sharp = top > PEAK_RATIO * np.maximum(floor, 1e-12)
    w = np.maximum(lum - PEAK_FRACTION * top, 0.0)
    # einsum, not a GEMM: a texel's sums must not depend on where it sits in the block (a
    # quilt's source texels are fitted in other blocks than the swatch's, and their maps agree).
    n = np.einsum("st,si->ti", w.astype(np.float64), h.astype(np.float64))
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    ok = sharp & (norm[:, 0] > 0) & (n[:, 2] > 0)
    n = np.where(ok[:, None], n / np.maximum(norm, 1e-30), 0.0)
    if PEAK_QUADRATIC:
        # GGX near its peak: D ~ a^2 / (pi (a^2 + theta_h^2)^2), so (L - floor)^(-1/2) is a
        # paraboloid in the half vector's (x, y) whose vertex is the normal's (x, y):
        # weighted least squares of c0 + c1 x + c2 y + c3 (x^2 + y^2) over the samples above
        # PEAK_QUADRATIC of the peak (above the floor).
        spec = lum - floor
        m = (spec >= PEAK_QUADRATIC * (top - floor)) & ok
        q = np.where(m, 1.0 / np.sqrt(np.maximum(spec, 1e-30)), 0.0)
        x, yh = h[:, 0].astype(np.float64), h[:, 1].astype(np.float64)
        phi = np.stack([np.ones_like(x), x, yh, x * x + yh * yh], axis=1)          # (S, 4)
        wts = np.where(m, spec, 0.0)                                                # (S, T)
        A = np.einsum("st,si,sj->tij", wts, phi, phi) + 1e-12 * np.eye(4)
        b = np.einsum("st,si->ti", wts * q, phi)
        enough = m.sum(axis=0) >= 6
        c = np.zeros((len(top), 4))
        c[enough] = np.linalg.solve(A[enough], b[enough][..., None])[..., 0]
        good = enough & (c[:, 3] > 0)
        cx, cy = -c[:, 1] / np.where(good, 2 * c[:, 3], 1.0), -c[:, 2] / np.where(good, 2 * c[:, 3], 1.0)
        near = good & (np.hypot(cx - n[:, 0], cy - n[:, 1]) < np.sin(np.radians(5.0))) & (cx * cx + cy * cy < 0.9)
        n[near, 0], n[near, 1] = cx[near], cy[near]
        n[near, 2] = np.sqrt(1.0 - cx[near] ** 2 - cy[near] ** 2)
    out = np.full((y.shape[2], 3), np.nan, np.float32)
    out[ok] = n[ok]
    return out


def _solve_channel(s11, s12, s22, b1, b2):
    """Least squares of (a, F0) from sums, with a >= 0 and 0 <= F0 <= 1 (all (T,) arrays)."""
    det = s11 * s22 - s12 * s12
    ok = det > 1e-12 * (s11 * s22 + 1e-30)
    a = np.where(ok, (b1 * s22 - b2 * s12) / np.where(ok, det, 1.0), 0.0)
    f = np.where(ok, (b2 * s11 - b1 * s12) / np.where(ok, det, 1.0), 0.0)
    # Active set: a parameter out of bounds is fixed at the bound, the other refitted.
    f_only = np.clip(b2 / np.maximum(s22, 1e-30), 0.0, 1.0)
    a_only = np.maximum(b1 / np.maximum(s11, 1e-30), 0.0)
    bad_a, bad_f = (a < 0) | ~ok, (f < 0) | (f > 1)
    f = np.where(bad_a, f_only, np.clip(f, 0.0, 1.0))
    a = np.where(bad_a, 0.0, np.where(bad_f, np.maximum((b1 - f * s12) / np.maximum(s11, 1e-30), 0.0), a))
    a = np.where(bad_a & bad_f & (f_only == 0), a_only, a)
    return a, f


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sum over samples of a * b: (S, T) x (S, T) -> (T,), or (S, T) x (3, S, T) -> (T, 3);
    float32 sums (a few hundred terms) returned as float64 for the residual expansion."""
    if a.ndim == b.ndim:
        return np.einsum("st,st->t", a, b).astype(np.float64)
    return np.stack([np.einsum("st,st->t", a, bc) for bc in b], axis=1).astype(np.float64)


def _fit_reflectance(y: np.ndarray, n: np.ndarray, v: np.ndarray, l: np.ndarray, grid: np.ndarray, pole=None):
    """Best (a, F0, roughness, residual) per texel for normals ``n`` (T, 3) and values
    ``y`` (3, S, T) already divided by pi W.  Residuals are expanded from sums over
    samples, so each roughness costs a few passes over (S, T) arrays.

    ``pole`` = (yp (3, P, T), vp (P, 3), lp (P, 3), weight): the mean over these samples (the
    views nearest the normal, :func:`pole_samples`) enters as one more sample of that
    ``weight``, so that the fit's mean there stays the BTF's (module docstring, step 3)."""
    t = y.shape[2]
    geo = _Geometry(n, v, l)
    x1 = (1 - geo.w) * geo.nl * np.float32(1 / np.pi)
    s11, y1, y_sq = _dot(x1, x1), _dot(x1, y), sum(_dot(yc, yc) for yc in y)
    rows = []
    if pole is not None:
        # One more sample per band of light elevation: the mean over the band's samples.
        yp, vp, lp, bands, lam = pole
        geo_p = _Geometry(n, vp, lp)
        x1p = (1 - geo_p.w) * geo_p.nl * np.float32(1 / np.pi)
        for band in np.unique(bands):
            sel = np.flatnonzero(bands == band)
            weight = lam * len(sel) / len(bands)
            m1 = x1p[sel].mean(axis=0, dtype=np.float64)                              # (T,)
            my = yp[:, sel].mean(axis=1, dtype=np.float64).T                          # (T, 3)
            s11, y1 = s11 + weight * m1 * m1, y1 + weight * m1[:, None] * my
            y_sq = y_sq + weight * (my * my).sum(axis=1)
            rows.append((sel, weight, m1, my))
    best_res = np.full(t, np.inf)
    best_a, best_f = np.zeros((t, 3), np.float32), np.zeros((t, 3), np.float32)
    best_r = np.ones(t, np.float32)
    for r in grid:
        x3 = geo.specular_nl(float(r))
        x2 = x3 * (1 - geo.w)
        x3 *= geo.w
        s12, s22, e13, e23, e33 = _dot(x1, x2), _dot(x2, x2), _dot(x1, x3), _dot(x2, x3), _dot(x3, x3)
        y2, y3 = _dot(x2, y), _dot(x3, y)
        if rows:
            sp = geo_p.specular_nl(float(r))
            x2p, x3p = sp * (1 - geo_p.w), sp * geo_p.w
            for sel, weight, m1, my in rows:
                m2, m3 = x2p[sel].mean(axis=0, dtype=np.float64), x3p[sel].mean(axis=0, dtype=np.float64)
                s12, s22 = s12 + weight * m1 * m2, s22 + weight * m2 * m2
                e13, e23, e33 = e13 + weight * m1 * m3, e23 + weight * m2 * m3, e33 + weight * m3 * m3
                y2, y3 = y2 + weight * m2[:, None] * my, y3 + weight * m3[:, None] * my
        res = 3 * e33 + y_sq - 2 * y3.sum(axis=1)                  # sum_c |y_c - x3|^2
        b1, b2 = y1 - e13[:, None], y2 - e23[:, None]
        a, f = _solve_channel(s11[:, None], s12[:, None], s22[:, None], b1, b2)
        res += (-2 * (a * b1 + f * b2) + a * a * s11[:, None] + 2 * a * f * s12[:, None]
                + f * f * s22[:, None]).sum(axis=1)
        better = res < best_res
        best_res = np.where(better, res, best_res)
        best_a[better], best_f[better], best_r[better] = a[better], f[better], r
    return best_a, best_f, best_r, best_res


def _validation_residual(y: np.ndarray, n: np.ndarray, v: np.ndarray, l: np.ndarray, a, f, r) -> np.ndarray:
    """(T,) sum over samples and channels of the squared error of the fitted (a, F0, roughness)
    with normals ``n`` against ``y`` (3, S, T) (already divided by pi W)."""
    geo = _Geometry(n, v, l)
    out = np.zeros(y.shape[2])
    x1 = (1 - geo.w) * geo.nl * np.float32(1 / np.pi)
    for rv in np.unique(r):
        sel = np.flatnonzero(r == rv)
        spec = geo.specular_nl(float(rv))[:, sel]
        x1s, w = x1[:, sel], geo.w
        for c in range(3):
            pred = a[sel, c] * x1s + f[sel, c] * spec * (1 - w) + spec * w
            out[sel] += ((y[c][:, sel] - pred) ** 2).sum(axis=0, dtype=np.float64)
    return out


def validation_samples(cbtf: CompressedBTF, fit: np.ndarray, most: int = 1024) -> np.ndarray:
    """Samples not fitted to, evenly spread: they decide whether a texel's normal map helps."""
    rest = np.setdiff1d(np.arange(cbtf.n_samples), fit)
    if len(rest) <= most:
        return rest if len(rest) else fit
    return rest[np.unique(np.linspace(0, len(rest) - 1, most).round().astype(int))]


@single_blas_thread
def fit_svbrdf(cbtf: CompressedBTF, *, white_level: float = 1.0, max_samples: int = 1536,
               roughness_grid=ROUGHNESS_GRID, normals: bool = True, chunk_bytes: float = 64e6,
               pole_weight: float = POLE_WEIGHT, brightness: bool = True, texel_weights=None) -> SvbrdfMaps:
    """Fit per-texel UsdPreviewSurface parameters to ``cbtf``'s reconstruction over its
    measured samples (module docstring), streamed over blocks of texels.  ``normals=False``
    fits no normal map (every texel keeps the flat normal); ``brightness=False`` skips step 4
    (:func:`keep_brightness`; the benchmarks' before); ``texel_weights`` (H*W,): how many
    texels of the material each texel stands for, for step 4 (a quilt's source texels)."""
    if not white_level > 0:
        raise ValueError(f"white_level must be positive, got {white_level}")
    fit = fit_samples(cbtf, max_samples)
    val = validation_samples(cbtf, fit, VALIDATION_SAMPLES)
    vv, vl = to_vectors(cbtf.sampling.view[val]), to_vectors(cbtf.sampling.light[val])
    ps = normal_samples(cbtf)
    v, l = to_vectors(cbtf.sampling.view[fit]), to_vectors(cbtf.sampling.light[fit])
    ps_light = to_vectors(cbtf.sampling.light[ps]).astype(np.float32)
    pole = pole_samples(cbtf)
    pv, pl = to_vectors(cbtf.sampling.view[pole]), to_vectors(cbtf.sampling.light[pole])
    lam = float(pole_weight) * len(fit)
    bands = np.floor(cbtf.sampling.light[pole, 0] / POLE_BAND_DEG).astype(int)
    basis = cbtf.basis_values()
    fit_rows, ps_rows, val_rows, pole_rows = basis[fit], basis[ps], basis[val], basis[pole]
    # The photometric-stereo samples are the pole samples where no light lies between their
    # elevation limits (the paper sampling: 1,728 each): their values are reconstructed once a
    # block (the same rows into the same product: the same bits; issue 42).
    ps_is_pole = normals and _same_samples(ps, pole)
    h_fit = v + l
    h_fit /= np.maximum(np.linalg.norm(h_fit, axis=1, keepdims=True), 1e-12)
    luma = _luminance_weights(cbtf)
    grid = np.asarray(roughness_grid, np.float32)
    peak_grid = np.union1d(PEAK_ROUGHNESS, grid[grid <= PEAK_MAX_ROUGHNESS]).astype(np.float32)
    texels = cbtf.width * cbtf.height
    diffuse, specular = np.zeros((texels, 3), np.float32), np.zeros((texels, 3), np.float32)
    rough, normal = np.ones(texels, np.float32), np.zeros((texels, 3), np.float32)
    step = _chunk_texels(max(len(fit), len(ps)), chunk_bytes)
    scale = np.float32(radiance_per_irradiance(white_level))     # value -> f (n.l): usdbtf.photometry
    flat = np.array([0.0, 0.0, 1.0], np.float32)

    def fit_block(block: slice) -> None:        # one block's texels, written into the maps
        values = _block_values(cbtf, block)
        y = np.ascontiguousarray((values(fit_rows) * scale).transpose(2, 0, 1))
        n_flat = np.broadcast_to(flat, (y.shape[2], 3))
        kept = shared = None
        if lam > 0:
            pole_values = values(pole_rows)
            yp = np.ascontiguousarray((pole_values * scale).transpose(2, 0, 1))
            kept = (yp, pv, pl, bands, lam)
            shared = pole_values if ps_is_pole else None
            del pole_values
        a, f, r, res = _fit_reflectance(y, n_flat, v, l, grid, kept)
        n_ps = n_flat.copy()
        if normals:
            n_fit = _photometric_normals((values(ps_rows) if shared is None else shared) @ luma, ps_light)
            shared = None
            yv = np.ascontiguousarray((values(val_rows) * scale).transpose(2, 0, 1))
            best = _validation_residual(yv, n_flat, vv, vl, a, f, r)
            # Candidates for the normal map: the photometric normal (diffuse shading), and for
            # texels with a sharp highlight (the others NaN) the half vector of their specular
            # peak; a texel keeps the candidate that predicts the validation samples best.
            for n_cand, cand_grid in ((n_fit, grid), (_peak_normals(y, luma, h_fit), peak_grid)):
                finite = np.isfinite(n_cand[:, 0])
                if not finite.any():
                    continue
                sel = slice(None) if finite.all() else np.flatnonzero(finite)
                n_c = n_cand[sel]
                kept_c = None if kept is None else (kept[0][:, :, sel], *kept[1:])
                a1, f1, r1, _ = _fit_reflectance(np.ascontiguousarray(y[:, :, sel]), n_c, v, l, cand_grid, kept_c)
                res1 = _validation_residual(np.ascontiguousarray(yv[:, :, sel]), n_c, vv, vl, a1, f1, r1)
                idx = np.arange(len(n_ps))[sel]
                won = res1 < best[idx]
                at = idx[won]
                a[at], f[at], r[at], n_ps[at], best[at] = a1[won], f1[won], r1[won], n_c[won], res1[won]
        diffuse[block] = np.clip(a / np.maximum(1.0 - f, 1e-6), 0.0, 1.0)
        specular[block], rough[block], normal[block] = f, r, n_ps

    fit_blocks(fit_block, texels, step, "fallback fit", log)
    h, w = cbtf.height, cbtf.width
    maps = SvbrdfMaps(diffuse.reshape(h, w, 3), specular.reshape(h, w, 3), rough.reshape(h, w),
                      normal.reshape(h, w, 3), cbtf.working_space, float(white_level))
    return keep_brightness(maps, cbtf, texel_weights, chunk_bytes) if brightness else maps


def pole_swatch_sums(cbtf: CompressedBTF, predicts, texel_weights=None, chunk_bytes: float = 64e6,
                     truth: np.ndarray | None = None) -> tuple[np.ndarray, list]:
    """Swatch sums at the pole samples (:func:`pole_samples`: the views nearest the normal,
    lights up to :data:`POLE_MAX_LIGHT_DEG`): (Y, [M, ...]), each (P, 3) float64, Y the BTF's
    (``truth`` when given: a previous call's), M per ``predicts`` entry, a function
    (view_deg (P, 2), light_deg (P, 2), texels) -> (P, T, 3) BTF values of a model, streamed over
    texel blocks.  ``texel_weights`` (H*W,): how many texels of the material each texel stands
    for (a quilt fitted once per source texel); default one each."""
    pole = pole_samples(cbtf)
    texels = cbtf.width * cbtf.height
    wts = texel_weights_of(cbtf, texel_weights)
    y = np.zeros((len(pole), 3)) if truth is None else truth
    sums = [np.zeros((len(pole), 3)) for _ in predicts]
    view, light = cbtf.sampling.view[pole], cbtf.sampling.light[pole]
    rows = cbtf.basis_values()[pole]
    # What each block adds to: the BTF's sums (unless given) and each model's.
    models = ([] if truth is not None else [lambda v, l, block: _reconstruct(cbtf, rows, block)]) + list(predicts)
    totals = ([] if truth is not None else [y]) + sums

    def block_sums(block: slice) -> list:
        w = wts[block]
        return [np.einsum("ptc,t->pc", model(view, light, block), w) for model in models]

    # The blocks on the fits' threads, their sums added in block order: the bits of one thread.
    for part in fit_blocks(block_sums, texels, pole_block_texels(len(pole), chunk_bytes), "pole sums", log):
        for total, value in zip(totals, part):
            total += value
    return y, sums


def texel_weights_of(cbtf: CompressedBTF, texel_weights=None) -> np.ndarray:
    """(H*W,) float64: ``texel_weights`` (how many texels of the material each texel stands
    for, :func:`pole_swatch_sums`), one each by default."""
    texels = cbtf.width * cbtf.height
    return np.ones(texels) if texel_weights is None else np.asarray(texel_weights, np.float64).reshape(-1)


def pole_block_texels(pole: int, chunk_bytes: float) -> int:
    """Texels a block of the pole sums holds: a model's (P, T, 3) values within about
    ``chunk_bytes`` in float64, at least 256."""
    return int(max(256, chunk_bytes // (pole * 4 * 3 * 8)))


def pole_ratio(y: np.ndarray, model: np.ndarray) -> np.ndarray:
    """(3,) per channel: the mean over the pole lights of the model's swatch over the BTF's
    (sums from :func:`pole_swatch_sums`; a light the BTF is black at has no ratio)."""
    ok = _pole_lit(y)
    return np.where(ok, model / np.where(ok, y, 1.0), 0.0).sum(axis=0) / np.maximum(ok.sum(axis=0), 1)


def pole_ratio_weights(y: np.ndarray) -> np.ndarray:
    """(P, 3) float64 q with ``pole_ratio(y, M)`` = sum_p q[p] M[p] (to rounding): the ratio is
    linear in the model's swatch sums, so a model whose sums are linear in its parameters can
    be weighed once and its ratio read for any of them (``openpbr.keep_brightness``)."""
    ok = _pole_lit(y)
    return np.where(ok, 1.0 / np.where(ok, y, 1.0), 0.0) / np.maximum(ok.sum(axis=0), 1)


def _pole_lit(y: np.ndarray) -> np.ndarray:
    """(P, 3) bool: the pole lights the BTF is not black at, per channel."""
    return y > 1e-12 * max(float(y.max()), 1e-30)


def brightness_scale(maps: SvbrdfMaps, cbtf: CompressedBTF, texel_weights=None,
                     chunk_bytes: float = 64e6) -> np.ndarray:
    """(3,) float64 per colour channel: the factor on both lobes (diffuse and F0) that makes
    the swatch of ``maps`` as bright as ``cbtf``'s at the pole samples (the values already
    carry n.l, the convention's cosine), on average over those lights: what the Storm check
    measures, a swatch under one light at a time (module docstring, step 4).  For sample p and
    channel c, with Y = the BTF's swatch sum, A = the model's lobes' sum and G = the sum of the
    Fresnel term's grazing part (F = mix(F0, 1, w): no parameter scales it), s makes
    ``mean_p (s A + G) / Y`` one (:func:`pole_ratio`), within :data:`BRIGHTNESS_SCALE`;
    ``texel_weights`` as :func:`pole_swatch_sums`."""
    zero = replace(maps, diffuse=np.zeros_like(maps.diffuse), specular=np.zeros_like(maps.specular))
    y, (total, grazing) = pole_swatch_sums(cbtf, [lambda v, l, t: evaluate(maps, v, l, t),
                                                  lambda v, l, t: evaluate(zero, v, l, t)], texel_weights, chunk_bytes)
    lobes, left = pole_ratio(y, total - grazing), 1.0 - pole_ratio(y, grazing)
    lo, hi = BRIGHTNESS_SCALE
    return np.where(lobes > 1e-12, np.clip(left / np.maximum(lobes, 1e-30), lo, hi), 1.0)


def keep_brightness(maps: SvbrdfMaps, cbtf: CompressedBTF, texel_weights=None, chunk_bytes: float = 64e6) -> SvbrdfMaps:
    """``maps`` with diffuse albedo times (1 - F0) and F0 scaled by :func:`brightness_scale`
    per channel (F0 at most 1, the albedo in [0, 1]): step 4 of the fit."""
    s = brightness_scale(maps, cbtf, texel_weights, chunk_bytes).astype(np.float32)
    f0 = maps.specular.astype(np.float32)
    a = maps.diffuse * (1.0 - f0) * s
    spec = np.clip(f0 * s, 0.0, 1.0)
    diffuse = np.clip(a / np.maximum(1.0 - spec, 1e-6), 0.0, 1.0)
    return replace(maps, diffuse=diffuse.astype(np.float32), specular=spec.astype(np.float32))


# ------------------------------------------------------------------ the flat fallback (the baseline)
def flat_fallback(cbtf: CompressedBTF, *, white_level: float = 1.0) -> SvbrdfMaps:
    """The fallback usdbtf shipped before the fit, kept as the benchmark's baseline: per-texel
    albedo (:func:`median_albedo`), one roughness for the whole material
    (:func:`fit_flat_roughness`), no normal map, and UsdPreviewSurface's metallic-workflow
    specular at metallic 0 (F0 = 0.04 from ior 1.5)."""
    albedo = median_albedo(cbtf, white_level=white_level)
    roughness, _ = fit_flat_roughness(cbtf)
    h, w = albedo.shape[:2]
    return SvbrdfMaps(albedo, np.full((h, w, 3), 0.04, np.float32), np.full((h, w), roughness, np.float32),
                      np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3)).copy(), cbtf.working_space,
                      float(white_level))


def albedo_samples(cbtf: CompressedBTF, max_light_theta: float = 60.0, most: int = 48) -> np.ndarray:
    """Samples :func:`median_albedo` uses: the view ring nearest the normal, lights no lower
    than ``max_light_theta`` degrees; at most ``most`` of them, evenly spread."""
    view_theta = cbtf.sampling.view[:, 0]
    near = view_theta <= view_theta.min() + 1e-6
    sel = np.flatnonzero(near & (cbtf.sampling.light[:, 0] <= max_light_theta))
    sel = sel if len(sel) else np.flatnonzero(near)
    if len(sel) > most:
        sel = sel[np.linspace(0, len(sel) - 1, most).round().astype(int)]
    return sel


def median_albedo(cbtf: CompressedBTF, *, white_level: float = 1.0, rows_per_chunk: int = 64) -> np.ndarray:
    """(H, W, 3) float32 working-space albedo: per texel the median over lights of
    ``I / cos(theta_l)`` at the views nearest the normal, divided by ``white_level``, in
    [0, 1]; streamed over texel rows.  The median ignores highlights and cast shadows."""
    sel = albedo_samples(cbtf)
    cos_l = np.maximum(np.cos(np.radians(cbtf.sampling.light[sel, 0])), 0.1).astype(np.float32)
    dom = cbtf.domain
    # Linear domain: 1 / cos folded into the rows (exact); else after the inverse curve.
    rows = (cbtf.basis_values()[sel] / (cos_l[:, None] if dom.is_linear else 1.0)).T       # (k, n)
    out = np.empty((cbtf.height, cbtf.width, 3), np.float32)
    for y0 in range(0, cbtf.height, rows_per_chunk):
        y1 = min(y0 + rows_per_chunk, cbtf.height)
        c = working_coefficient_texels(cbtf, slice(y0 * cbtf.width, y1 * cbtf.width))   # (k, h*W, 3)
        per_texel = c.reshape(cbtf.k, -1).T @ rows                           # (h*W*3, n)
        if not dom.is_linear:
            per_texel = dom.inverse(per_texel) / cos_l
        out[y0:y1] = np.median(per_texel, axis=1).reshape(y1 - y0, cbtf.width, 3)
    return np.clip(out / white_level, 0.0, 1.0)


_FLAT_ROUGHNESS_GRID = np.round(np.linspace(0.05, 1.0, 39), 4)


def _flat_ggx_lobe(view: np.ndarray, light: np.ndarray, roughness: float) -> np.ndarray:
    """(S,) GGX specular times cos(theta_l) for unit (S, 3) directions (F and G folded into the scale)."""
    alpha2 = max(roughness, 0.02) ** 4
    h = view + light
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    nh = np.clip(h[:, 2], 0.0, 1.0)
    d = alpha2 / (np.pi * (nh * nh * (alpha2 - 1.0) + 1.0) ** 2)
    return d / (4.0 * np.maximum(view[:, 2], 0.1))


def fit_flat_roughness(cbtf: CompressedBTF) -> tuple[float, float]:
    """(roughness, relative residual) of the best diffuse + GGX fit to the texel-mean
    apparent BRDF (non-negative least squares per roughness on a grid)."""
    mean_c = np.stack([st.values().reshape(-1, 3).mean(axis=0) for st in cbtf.coefficients])   # (k, 3)
    mean_c = mean_c @ np.asarray(cbtf.color_matrix).T
    # In a curve's domain the inverse of the mean texel's values (close to the mean apparent BRDF).
    brdf = cbtf.domain.inverse(cbtf.basis_values().astype(np.float64) @ mean_c).astype(np.float64).mean(axis=1)
    view, light = to_vectors(cbtf.sampling.view), to_vectors(cbtf.sampling.light)
    keep = (cbtf.sampling.view[:, 0] <= 70) & (cbtf.sampling.light[:, 0] <= 75)
    if keep.sum() < 3:
        keep[:] = True
    cos_l = np.maximum(light[keep, 2], 0.0)
    norm = float(np.linalg.norm(brdf[keep])) or 1.0
    best = (1.0, np.inf)
    for r in _FLAT_ROUGHNESS_GRID:
        design = np.stack([cos_l, _flat_ggx_lobe(view[keep], light[keep], float(r)) * cos_l], axis=1)
        coef, *_ = np.linalg.lstsq(design, brdf[keep], rcond=None)
        coef = np.maximum(coef, 0.0)   # a negative specular weight is not a surface
        resid = float(np.linalg.norm(design @ coef - brdf[keep])) / norm
        if resid < best[1] - 1e-12:
            best = (float(r), resid)
    return best


#: Rec.709 luminance weights (ITU-R BT.709).
_REC709_Y = np.array([0.2126, 0.7152, 0.0722])
REC709_LINEAR = "Linear Rec.709 (sRGB)"


def _luminance_weights(cbtf: CompressedBTF) -> np.ndarray:
    """(3,) float32 luminance weights of the working space: Rec.709's Y row composed with
    OCIO's (linear) working -> linear Rec.709 transform."""
    from .color import processor

    to_709 = processor(cbtf.working_space, REC709_LINEAR, cbtf.ocio_config).apply(np.eye(3, dtype=np.float32))
    return (to_709 @ _REC709_Y).astype(np.float32)
