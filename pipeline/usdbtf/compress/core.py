"""``compress``: a BTF -> basis + coefficient textures (the apparent-BRDF method).

Two solvers share one pipeline (load -> fit basis -> project -> store -> evaluate):

``paper``  Koudelka et al. 2003 exactly: exact SVD of a contiguous square region
           (default the central quarter-width square), k vectors shared by R, G, B,
           each coefficient texture min-max scaled to [0, 1] as 8-bit JPEG, the basis
           min-max scaled per vector into one uncompressed 8-bit image.
``rsvd``   (default) randomized SVD with power iterations over a random sample of
           texels from the whole image, every pixel projected, coefficient colour
           channels decorrelated (3x3 PCA), one uniform quantisation step for all
           coefficients with basis steps scaled by 1/sigma_i (reverse water-filling),
           (k, step) chosen by rate-distortion, lossless JPEG XL storage.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..atomic import atomic_dir
from ..errors import BTFError
from ..model import BTF
from . import ratedist
from .codecs import Stored, get_codec, quantize_minmax, quantize_uniform
from .curve import error_curve, write_curve
from .format import CompressedBTF, reconstruct, write_metadata, write_textures
from .linalg import exact_basis, randomized_basis
from .load import load_encoded
from .metrics import ErrorSums

__all__ = ["Options", "compress", "compress_to_folder", "SOLVERS"]

SOLVERS = ("rsvd", "paper")
_DEFAULT_K = 150
_GAUSS_L1_OVER_RMS = float(np.sqrt(2 / np.pi))  # E|e| / rms(e) for Gaussian errors


@dataclass
class Options:
    """What ``compress`` does.  Units: ``target_error`` percent (paper's metric, scene-linear),
    ``max_bytes`` bytes of stored textures (basis + coefficients)."""

    solver: str = "rsvd"
    k: int | None = None
    target_error: float | None = None
    max_bytes: int | None = None
    codec: str | None = None              # default: jxl (rsvd), jpeg (paper)
    seed: int = 0
    fit_texels: int = 2048                # rsvd: texels sampled for the basis fit
    power_iterations: int = 1
    oversample: int = 16
    region: int | None = None             # paper: side of the central square region (texels)
    chunk_texels: int = 1024              # projection chunk (memory: S * 3 * chunk * 4 bytes)
    eval_texels: int = 1024               # held-out texels for error estimates
    workers: int | None = None
    extra: dict = field(default_factory=dict)

    def validate(self):
        if self.solver not in SOLVERS:
            raise BTFError(f"unknown solver {self.solver!r}; choose from {', '.join(SOLVERS)}")
        if self.k is not None and self.k < 1:
            raise BTFError(f"--k must be at least 1, got {self.k}")
        if self.target_error is not None and not (self.target_error > 0):
            raise BTFError(f"--target-error must be a positive percentage, got {self.target_error}")
        if self.max_bytes is not None and self.max_bytes <= 0:
            raise BTFError(f"--max-bytes must be positive, got {self.max_bytes}")
        get_codec(self.codec or ("jpeg" if self.solver == "paper" else "jxl"))


class _Decoded:
    """Encoded data (S, P, 3) plus the decode split into per-channel curves (applied to
    data chunks) and a 3x3 matrix (applied to the much smaller coefficients instead)."""

    def __init__(self, btf: BTF, encoded: np.ndarray):
        self.btf = btf
        self.enc = encoded.reshape(btf.n_samples, btf.n_pixels, 3)
        self.flat = encoded.reshape(btf.n_samples, -1)          # (S, 3P) view, channels interleaved
        dec = btf.integer_decoder
        if dec is not None and dec.exact:
            self.curves = dec.decode_curves
            self.matrix = dec.matrix
        else:
            self.curves = lambda block: btf.decode(block.reshape(block.shape[0], -1, 3)).reshape(block.shape)
            self.matrix = None

    def block(self, a: int, b: int) -> np.ndarray:
        """Texels a..b of every sample after the curves: (S, 3 (b - a)) float32, no gather."""
        return self.curves(self.flat[:, 3 * a:3 * b])

    def columns(self, texels) -> np.ndarray:
        """(S, n, 3) float32 after the curves, for texel indices or a slice."""
        return self.curves(self.enc[:, texels, :])

    def working(self, texels) -> np.ndarray:
        """(S, n, 3) float32 in the working space."""
        x = self.columns(texels)
        return x @ self.matrix.T if self.matrix is not None else x


_RUN = 64  # texels per contiguous run of the rsvd fitting sample (whole cache lines, cheap to gather)


def _fit_texels(btf: BTF, opts: Options) -> np.ndarray:
    W, H = btf.width, btf.height
    if opts.solver == "paper":
        side = opts.region or max(4, min(W, H) // 4)
        side = min(side, W, H)
        y0, x0 = (H - side) // 2, (W - side) // 2
        yy, xx = np.mgrid[y0:y0 + side, x0:x0 + side]
        return (yy * W + xx).ravel()
    # Random runs of _RUN consecutive texels: spread over the whole image, but each run is
    # one contiguous slice of every sample (a gather of random single texels costs more
    # than the fit itself at paper scale).
    runs = btf.n_pixels // _RUN
    n_runs = min(runs, max(1, opts.fit_texels // _RUN))
    if runs == 0 or n_runs == runs:
        return np.arange(btf.n_pixels)
    rng = np.random.default_rng(opts.seed)
    starts = np.sort(rng.choice(runs, size=n_runs, replace=False)) * _RUN
    return (starts[:, None] + np.arange(_RUN)[None, :]).ravel()


def _gather_columns(data: "_Decoded", texels: np.ndarray) -> np.ndarray:
    """(S, 3 n) float32 after the curves, assembling contiguous runs of ``texels`` blockwise."""
    breaks = np.flatnonzero(np.diff(texels) != 1) + 1
    starts = np.r_[0, breaks]
    ends = np.r_[breaks, len(texels)]
    out = np.empty((data.flat.shape[0], 3 * len(texels)), np.float32)
    for s0, e0 in zip(starts, ends):
        out[:, 3 * s0:3 * e0] = data.block(int(texels[s0]), int(texels[e0 - 1]) + 1)
    return out


def _eval_texels(btf: BTF, fit: np.ndarray, opts: Options) -> np.ndarray:
    rest = np.setdiff1d(np.arange(btf.n_pixels), fit)
    if len(rest) == 0:
        rest = np.arange(btf.n_pixels)
    rng = np.random.default_rng(opts.seed + 1)
    return np.sort(rng.choice(rest, size=min(opts.eval_texels, len(rest)), replace=False))


def _project(data: _Decoded, u: np.ndarray, chunk: int) -> tuple[np.ndarray, float]:
    """Coefficients (k, P, 3) = U^T X over texel chunks, and ||X||^2 (after curves)."""
    S, P, _ = data.enc.shape
    k = u.shape[1]
    coeff = np.empty((k, P, 3), np.float32)
    energy = 0.0
    ut = np.ascontiguousarray(u.T)
    for a in range(0, P, chunk):
        b = min(a + chunk, P)
        x = data.block(a, b)
        coeff[:, a:b, :] = (ut @ x).reshape(k, b - a, 3)
        flat = x.ravel()
        energy += float(np.dot(flat, flat))
    return coeff, energy


def _colour_decorrelation(coeff: np.ndarray) -> np.ndarray:
    """Orthonormal 3x3 R (columns = colour principal axes, largest first, signs fixed)."""
    flat = coeff.reshape(-1, 3).astype(np.float64)
    cov = flat.T @ flat
    evals, vecs = np.linalg.eigh(cov)
    vecs = vecs[:, np.argsort(evals)[::-1]]
    vecs *= np.sign(vecs[np.argmax(np.abs(vecs), axis=0), [0, 1, 2]])
    return vecs


def _quantize_basis_columns(u: np.ndarray, steps: np.ndarray) -> Stored:
    """Uniform per-column steps; 16-bit when any column needs more than 256 levels."""
    q = np.rint(u / steps.astype(np.float32)).astype(np.int64)
    lo = q.min(axis=0)
    span = int((q.max(axis=0) - lo).max())
    dtype = np.uint8 if span < 256 else np.uint16
    return Stored((q - lo).astype(dtype)[:, :, None], steps.astype(np.float64), lo * steps.astype(np.float64))


def _quantize_basis_minmax(u: np.ndarray) -> Stored:
    st = quantize_minmax(u[None, :, :], per_channel=True)      # channels = columns
    return Stored(st.pixels[0][:, :, None], st.scale, st.bias)


def _basis_steps(step: float, energy: np.ndarray, u: np.ndarray) -> np.ndarray:
    sigma = np.sqrt(np.maximum(energy, 1e-300))
    steps = step / sigma
    # Keep every column within 16 bits (only binds for huge dynamic range).
    span = (u.max(axis=0) - u.min(axis=0)) / steps
    return np.where(span >= 2**16 - 2, (u.max(axis=0) - u.min(axis=0)) / (2**16 - 2), steps)


def _build(data, u, coeff, k, step, opts, codec_name, color_matrix) -> CompressedBTF:
    btf = data.btf
    if opts.solver == "paper":
        basis = _quantize_basis_minmax(u[:, :k])
        coeffs = [quantize_minmax(coeff[i].reshape(btf.height, btf.width, 3), per_channel=False) for i in range(k)]
    else:
        energy = np.einsum("kpc,kpc->k", coeff[:k], coeff[:k], dtype=np.float64)
        basis = _quantize_basis_columns(u[:, :k], _basis_steps(step, energy, u[:, :k]))
        coeffs = [quantize_uniform(coeff[i].reshape(btf.height, btf.width, 3), step) for i in range(k)]
        if codec_name == "exr":
            basis = Stored(u[:, :k, None].astype(np.float16), np.ones(k), np.zeros(k))
            coeffs = [Stored(coeff[i].reshape(btf.height, btf.width, 3).astype(np.float16), np.ones(3), np.zeros(3))
                      for i in range(k)]
    return CompressedBTF(
        sampling=btf.sampling, width=btf.width, height=btf.height, basis=basis, coefficients=coeffs,
        color_matrix=color_matrix, codec=codec_name, working_space=btf.working_space,
        source={"color_space": btf.color_space, "bit_depth": btf.bit_depth,
                "path": str(btf.metadata.get("_path", ""))},
        interpolated=btf.interpolated, ocio_config=btf.ocio_config)


def _evaluate(cbtf: CompressedBTF, truth: np.ndarray, texels: np.ndarray, k: int | None = None) -> ErrorSums:
    """Error of the stored representation on held-out texels, working space.
    truth : (S, n, 3) working-space values at ``texels``."""
    k = cbtf.k if k is None else k
    coeff = np.stack([cbtf.coefficients[i].values().reshape(-1, 3)[texels] for i in range(k)])  # (k, n, 3)
    rec = (cbtf.basis_values(k) @ coeff.reshape(k, -1)).reshape(truth.shape)
    m = np.asarray(cbtf.color_matrix, np.float32)
    rec = rec @ m.T
    sums = ErrorSums()
    sums.add(truth, rec)
    return sums


def compress_to_folder(btf: BTF, out, opts: Options | None = None, *, log=None) -> CompressedBTF:
    """Compress ``btf`` and write the folder ``out`` atomically.  Returns the result.

    ``log`` : optional callable(str) for progress lines.
    """
    opts = opts or Options()
    opts.validate()
    say = log or (lambda msg: None)
    t0 = time.perf_counter()
    timings = {}
    codec_name = opts.codec or ("jpeg" if opts.solver == "paper" else "jxl")

    encoded = load_encoded(btf, workers=opts.workers)
    data = _Decoded(btf, encoded)
    timings["load_s"] = time.perf_counter() - t0
    say(f"loaded {btf.n_samples} samples of {btf.width}x{btf.height} ({encoded.nbytes / 2**20:.0f} MiB) "
        f"in {timings['load_s']:.2f} s")

    S, P = btf.n_samples, btf.n_pixels
    k_cap = min(S, 3 * P)
    k_fit = min(opts.k or _DEFAULT_K, k_cap)
    fit = _fit_texels(btf, opts)
    t = time.perf_counter()
    x_fit = _gather_columns(data, fit)
    if opts.solver == "paper":
        u, sv = exact_basis(x_fit, k_fit)
    else:
        u, sv = randomized_basis(x_fit, min(k_fit, x_fit.shape[1]), oversample=opts.oversample,
                                 power_iterations=opts.power_iterations, seed=opts.seed)
    del x_fit
    k_fit = u.shape[1]
    timings["fit_s"] = time.perf_counter() - t
    say(f"basis: {k_fit} vectors from {len(fit)} texels ({opts.solver}) in {timings['fit_s']:.2f} s")

    t = time.perf_counter()
    coeff, total_energy = _project(data, u, opts.chunk_texels)
    if data.matrix is not None:
        coeff = coeff @ data.matrix.T  # curves-space -> working space, exact (linear in the coefficients)
        total_energy = None            # recomputed below in the working space
    timings["project_s"] = time.perf_counter() - t

    evalt = _eval_texels(btf, fit, opts)
    truth = data.working(evalt)
    if total_energy is None:
        # ||X_ws||^2 estimated from the held-out texels (exact energy would need another pass).
        total_energy = float(np.einsum("snc,snc->", truth, truth, dtype=np.float64)) * P / len(evalt)

    if opts.solver == "paper":
        color_matrix = np.eye(3)
    else:
        color_matrix = _colour_decorrelation(coeff)
        coeff = coeff @ color_matrix.astype(np.float32)   # c' = R^T c for each texel

    t = time.perf_counter()
    with atomic_dir(out) as tmp:
        cbtf, choice = _choose_and_store(data, u, coeff, total_energy, truth, evalt, opts, codec_name,
                                         color_matrix, tmp, say)
        timings["store_s"] = time.perf_counter() - t
        sums = _evaluate(cbtf, truth, evalt)
        curve = error_curve(cbtf, data, opts.seed)
        timings["total_s"] = time.perf_counter() - t0
        cbtf.info.update({
            "solver": opts.solver,
            "choice": choice,
            "singular_values": [float(s) for s in sv],
            "estimated_error": {"linear": sums.report(), "texels": int(len(evalt)),
                                "note": "held-out texels (not used in the fit), all samples, working space"},
            "error_curve": {"file": "error_curve.csv", "plot": "error_curve.png"},
            "provenance": {"tool": "usdbtf", "version": __version__, "solver": opts.solver, "seed": opts.seed,
                           "source": str(btf.metadata.get("_path", "")), "options": _opts_dict(opts)},
            "timings": {k_: round(v, 4) for k_, v in timings.items()},
        })
        cbtf.info.update(opts.extra)
        cbtf.info["bytes"]["metadata"] = write_metadata(cbtf, tmp)
        write_curve(curve, tmp)
    say(f"k = {cbtf.k}, {cbtf.info['bytes']['payload']} bytes, held-out error "
        f"{sums.percent:.3f} % ({timings['total_s']:.2f} s)")
    return cbtf


def _opts_dict(opts: Options) -> dict:
    return {k: v for k, v in opts.__dict__.items() if k not in ("extra", "workers")}


def _choose_and_store(data, u, coeff, total_energy, truth, evalt, opts, codec_name, color_matrix, tmp, say):
    """Pick (k, step), write textures into ``tmp``; returns (CompressedBTF, choice dict)."""
    btf = data.btf
    k_fit = u.shape[1]
    if opts.solver == "paper" or codec_name in ("exr", "jpeg"):
        return _choose_by_k_only(data, u, coeff, truth, evalt, opts, codec_name, color_matrix, tmp)
    table = ratedist.rd_table(coeff, u, total_energy, seed=opts.seed)
    N = truth.size * btf.n_pixels / len(evalt)
    mean_x = float(truth.mean())
    factor = 1.0
    choice = {}
    for attempt in range(3):
        if opts.max_bytes is not None:
            k, step = ratedist.choose_for_bytes(table, opts.max_bytes, factor)
            if opts.k:
                k = min(k, opts.k)
        elif opts.target_error is not None:
            rms_target = opts.target_error / 100.0 * mean_x / _GAUSS_L1_OVER_RMS
            k, step = ratedist.choose_for_error(table, rms_target**2 * N * choice.get("error_scale", 1.0), factor)
        else:
            k = min(opts.k or _DEFAULT_K, k_fit)
            step = ratedist.choose_for_k(table, k)
        cbtf = _build(data, u, coeff, k, step, opts, codec_name, color_matrix)
        for old in list((tmp / "coeff").glob("*")) if (tmp / "coeff").exists() else []:
            old.unlink()
        sizes = write_textures(cbtf, tmp)
        predicted = table.curves(factor)[0][k, list(table.steps).index(step)]
        choice = dict(choice, k=k, step=step, predicted_bytes=float(predicted), bytes=sizes["payload"],
                      attempts=attempt + 1)
        say(f"  try {attempt + 1}: k = {k}, step = {step:.4g}, {sizes['payload']} bytes "
            f"(predicted {predicted:.0f})")
        if opts.max_bytes is not None:
            if sizes["payload"] <= opts.max_bytes:
                # Within budget; if well under, one more round with the measured codec factor.
                if sizes["payload"] > 0.95 * opts.max_bytes or attempt >= 2:
                    break
            factor *= sizes["payload"] / max(predicted, 1.0)
            continue
        if opts.target_error is not None:
            err = _evaluate(cbtf, truth, evalt).percent
            choice["estimated_percent"] = err
            if err <= opts.target_error or attempt == 2:
                break
            choice["error_scale"] = choice.get("error_scale", 1.0) * (opts.target_error / err) ** 2
            factor *= sizes["payload"] / max(predicted, 1.0)
            continue
        break
    if opts.max_bytes is not None and cbtf.info["bytes"]["payload"] > opts.max_bytes:
        raise BTFError(f"cannot meet --max-bytes {opts.max_bytes}: smallest result is "
                       f"{cbtf.info['bytes']['payload']} bytes")
    return cbtf, choice


def _choose_by_k_only(data, u, coeff, truth, evalt, opts, codec_name, color_matrix, tmp):
    """Solvers/codecs without a quantisation step to tune: k alone meets the request."""
    k_fit = u.shape[1]
    k = min(opts.k or _DEFAULT_K, k_fit)
    cbtf = _build(data, u, coeff, k, 0.0, opts, codec_name, color_matrix)
    sizes = write_textures(cbtf, tmp)
    choice = {"k": k}
    if opts.max_bytes is not None:
        per = np.asarray(sizes["per_coefficient"])
        basis_per_k = sizes["basis"] / k
        total = np.cumsum(per) + basis_per_k * np.arange(1, k + 1)
        fits = np.flatnonzero(total <= opts.max_bytes)
        if len(fits) == 0:
            raise BTFError(f"cannot meet --max-bytes {opts.max_bytes}: one basis vector already needs {total[0]:.0f} bytes")
        k = int(fits[-1]) + 1
    elif opts.target_error is not None:
        lo, hi = 1, k
        while lo < hi:  # smallest k meeting the target on held-out texels (error falls with k)
            mid = (lo + hi) // 2
            if _evaluate(cbtf, truth, evalt, mid).percent <= opts.target_error:
                hi = mid
            else:
                lo = mid + 1
        k = lo
    if k != cbtf.k:
        for f in (tmp / "coeff").glob("*"):
            f.unlink()
        cbtf = _build(data, u, coeff, k, 0.0, opts, codec_name, color_matrix)
        write_textures(cbtf, tmp)
        choice["k"] = k
    return cbtf, choice


def compress(btf: BTF, out, **options) -> CompressedBTF:
    """Convenience: ``compress(btf, "out_dir", solver="paper", k=150)``."""
    return compress_to_folder(btf, out, Options(**options))
