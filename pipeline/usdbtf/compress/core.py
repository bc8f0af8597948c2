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

import shutil
import time
from dataclasses import dataclass, field

import numpy as np

from .. import __version__, colour
from ..atomic import atomic_dir
from ..errors import BTFError
from ..model import BTF
from . import ratedist
from .codecs import Stored, get_codec, quantize_half, quantize_minmax, quantize_uniform
from .curve import curve_samples, error_curve, write_curve
from .format import (CompressedBTF, truncate_written, working_coefficient_texels, working_coefficients, write_basis,
                     write_metadata, write_textures)
from .linalg import exact_basis, randomized_basis
from .source import choose_source
from .metrics import ErrorSums

__all__ = ["Options", "compress", "compress_to_folder", "SOLVERS"]

SOLVERS = ("rsvd", "paper")
_DEFAULT_K = 150
# With a byte or error target, rate-distortion may keep more components than the paper's
# 150: low-energy coefficients cost few bits once entropy coded (measured: at the paper's
# bytes, pebbles 9.1 % error at k <= 150, 8.0 % at k <= 300).
_BUDGET_K = 300
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
    fit_texels: int | None = None         # rsvd: texels sampled for the basis fit (default below)
    power_iterations: int = 1
    oversample: int = 16
    region: int | None = None             # paper: side of the central square region (texels)
    memory_budget: float = 1.0e9          # hold stored values in memory up to this many bytes, else stream
    chunk_bytes: float = 64e6             # streaming: stored bytes per chunk (rounded to whole projection tiles)
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


_RUN = 64  # texels per contiguous run of the rsvd fitting sample (whole cache lines, cheap to gather)


def _default_fit_texels(opts: Options) -> int:
    """2048 texels for a plain k; 4096 when a byte or error target lets quality pay for time
    (measured on paper-scale pebbles at the paper's bytes: 8.22 % -> 7.96 % error)."""
    if opts.fit_texels:
        return opts.fit_texels
    return 4096 if (opts.max_bytes is not None or opts.target_error is not None) else 2048


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
    n_runs = min(runs, max(1, _default_fit_texels(opts) // _RUN))
    if runs == 0 or n_runs == runs:
        return np.arange(btf.n_pixels)
    return _runs(btf.n_pixels, n_runs, np.random.default_rng(opts.seed))


def _runs(n_pixels: int, count: int, rng, exclude: np.ndarray | None = None) -> np.ndarray:
    """Sorted texel indices of ``count`` random runs of _RUN texels (whole runs only),
    avoiding runs listed in ``exclude`` (run indices)."""
    runs = np.arange(n_pixels // _RUN)
    if exclude is not None:
        runs = np.setdiff1d(runs, exclude)
    pick = np.sort(rng.choice(runs, size=min(count, len(runs)), replace=False)) * _RUN
    return (pick[:, None] + np.arange(_RUN)[None, :]).ravel()


def _eval_texels(btf: BTF, fit: np.ndarray, opts: Options) -> np.ndarray:
    """Held-out texels for error estimates: random runs disjoint from the fitting runs
    (all texels when the image is too small to hold any out)."""
    runs = btf.n_pixels // _RUN
    used = np.unique(fit // _RUN)
    free = runs - len(used)
    if free <= 0 or len(fit) == btf.n_pixels:
        return np.arange(btf.n_pixels)
    return _runs(btf.n_pixels, max(1, opts.eval_texels // _RUN), np.random.default_rng(opts.seed + 1), exclude=used)


#: Fitted texels whose norms span more than this get equalising fit weights: an energy-
#: weighted float32 fit cannot see a region below ~1e-6 of the brightest (its singular
#: values fall under the rank cut, and its terms under float32 rounding of the sums).
_HDR_NORM_RANGE = 1e6


def _fit_weights(x: np.ndarray) -> np.ndarray | None:
    """Column weights (3 n,) float32 for the fit of ``x`` (S, 3 n): ||x_t||^-1/2 per texel
    when the nonzero texel norms span more than _HDR_NORM_RANGE, else None.

    The square root halves the dynamic range in log terms (1e-4..1e4 data: 1e8 -> 1e4 in
    norm): a dark region with a BRDF of its own then gets basis directions, while bright
    texels still weigh more, as the paper's absolute error metric wants.
    """
    norms = np.sqrt(_column_energy(x).reshape(-1, 3).sum(axis=1))
    pos = norms[norms > 0]
    if len(pos) == 0 or pos.max() <= _HDR_NORM_RANGE * pos.min():
        return None
    w = np.where(norms > 0, 1.0 / np.sqrt(np.maximum(norms, pos.min())), 1.0)
    return np.repeat(w, 3).astype(np.float32)


def _column_energy(x: np.ndarray, rows: int = 256) -> np.ndarray:
    """(n,) float64 sum of squares of each column of ``x`` (S, n) float32: float32 dot
    products over blocks of ``rows`` samples, summed in float64 (an einsum with
    dtype=float64 casts every element and is ~10x slower on a 10800 x 6144 fit matrix)."""
    acc = np.zeros(x.shape[1])
    for a in range(0, x.shape[0], rows):
        part = x[a:a + rows]
        acc += np.einsum("st,st->t", part, part)
    return acc


def _colour_gram(coeff: np.ndarray) -> np.ndarray:
    """3x3 float64 sum of c c^T over every texel and component of ``coeff`` (k, P, 3),
    one component at a time (a float64 copy of the whole array would be 2x its size)."""
    gram = np.zeros((3, 3))
    for plane in coeff:
        flat = plane.astype(np.float64)
        gram += flat.T @ flat
    return gram


def _apply_colour(coeff: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``coeff @ m`` for (k, P, 3) coefficients, in place, one component at a time."""
    for i in range(len(coeff)):
        coeff[i] = colour.mix_rgb(coeff[i], m.T)
    return coeff


def _colour_decorrelation(coeff: np.ndarray) -> np.ndarray:
    """Orthonormal 3x3 R (columns = colour principal axes, largest first, signs fixed)."""
    cov = _colour_gram(coeff)
    evals, vecs = np.linalg.eigh(cov)
    vecs = vecs[:, np.argsort(evals)[::-1]]
    vecs *= np.sign(vecs[np.argmax(np.abs(vecs), axis=0), [0, 1, 2]])
    return vecs


#: A colour plane's component is projected while zeroing it would add more than this
#: fraction of one component's quantisation noise (n step^2 / 12), estimated on the sample.
_PLANE_TOLERANCE = 0.01


def _planes_in_use(sampled: np.ndarray, step: float) -> tuple[int, int, int]:
    """Per decorrelated colour plane, how many leading components to project.

    A coefficient c rounds to zero when |c| < step / 2; zeroing one that would round away
    adds step (2 |c| - step) to the squared error.  Plane j keeps components up to the last
    one where that excess, averaged over the sampled texels (k, n, 3), passes
    _PLANE_TOLERANCE step^2 / 12; later ones are (almost) all zero once quantised.
    """
    excess = np.maximum(2.0 * np.abs(sampled) / step - 1.0, 0.0).mean(axis=1)      # (k, 3), in step^2
    used = excess > _PLANE_TOLERANCE / 12.0
    ks = [int(np.flatnonzero(used[:, j])[-1]) + 1 if used[:, j].any() else 0 for j in range(3)]
    ks[0] = max(ks[0], 1)
    return tuple(ks)


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
    # A column whose coefficients are all zero needs no precision: cap its step at its span.
    colspan = u.max(axis=0) - u.min(axis=0)
    steps = np.minimum(step / sigma, np.where(colspan > 0, colspan, 1.0))
    # Keep every column within 16 bits (only binds for huge dynamic range).
    span = (u.max(axis=0) - u.min(axis=0)) / steps
    return np.where(span >= 2**16 - 2, (u.max(axis=0) - u.min(axis=0)) / (2**16 - 2), steps)


def _build(data, u, coeff, k, step, opts, codec_name, color_matrix) -> CompressedBTF:
    """Quantise the first k components for ``codec_name``: half floats for exr, the paper's
    min-max 8-bit scaling for the paper solver or jpeg, else the uniform step ``step``."""
    btf = data.btf
    textures = [coeff[i].reshape(btf.height, btf.width, 3) for i in range(k)]
    if codec_name == "exr":
        st = quantize_half(u[None, :, :k])                                # channels = basis columns
        basis = Stored(st.pixels[0][:, :, None], st.scale, st.bias)
        coeffs = [quantize_half(t) for t in textures]
    elif opts.solver == "paper" or codec_name == "jpeg":
        basis = _quantize_basis_minmax(u[:, :k])
        coeffs = [quantize_minmax(t, per_channel=False) for t in textures]
    else:
        energy = np.einsum("kpc,kpc->k", coeff[:k], coeff[:k], dtype=np.float64)
        basis = _quantize_basis_columns(u[:, :k], _basis_steps(step, energy, u[:, :k]))
        coeffs = [quantize_uniform(t, step) for t in textures]
    return CompressedBTF(
        sampling=btf.sampling, width=btf.width, height=btf.height, basis=basis, coefficients=coeffs,
        color_matrix=color_matrix, codec=codec_name,
        working_space=colour.resolve_space(btf.working_space, btf.ocio_config),
        source={"color_space": btf.color_space, "bit_depth": btf.bit_depth,
                "path": str(btf.metadata.get("_path", ""))},
        interpolated=btf.interpolated, ocio_config=btf.ocio_config)


def _evaluate(cbtf: CompressedBTF, truth: np.ndarray, texels: np.ndarray, k: int | None = None) -> ErrorSums:
    """Error of the stored representation on held-out texels, working space.
    truth : (S, n, 3) working-space values at ``texels``."""
    k = cbtf.k if k is None else k
    coeff = working_coefficient_texels(cbtf, texels, k)                     # (k, n, 3)
    rec = (cbtf.basis_values(k) @ coeff.reshape(k, -1)).reshape(truth.shape)
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

    fit = _fit_texels(btf, opts)
    evalt = _eval_texels(btf, fit, opts)
    data = choose_source(btf, [fit, evalt], curve_samples(btf.n_samples), memory_budget=opts.memory_budget,
                         workers=opts.workers, chunk_bytes=opts.chunk_bytes)
    timings["load_s"] = time.perf_counter() - t0
    say(f"loaded {btf.n_samples} samples of {btf.width}x{btf.height} ({data.kind}, {data.nbytes / 2**20:.0f} MiB) "
        f"in {timings['load_s']:.2f} s")

    S, P = btf.n_samples, btf.n_pixels
    k_cap = min(S, 3 * P)
    budgeted = opts.max_bytes is not None or opts.target_error is not None
    k_fit = min(opts.k or (_BUDGET_K if budgeted and opts.solver == "rsvd" else _DEFAULT_K), k_cap)
    t = time.perf_counter()
    x_fit = data.columns(fit)
    if opts.solver == "paper":
        u, sv = exact_basis(x_fit, k_fit)
    else:
        weights = _fit_weights(x_fit)
        u, sv, c_fit = randomized_basis(x_fit if weights is None else x_fit * weights, min(k_fit, x_fit.shape[1]),
                                        oversample=opts.oversample, power_iterations=opts.power_iterations,
                                        seed=opts.seed, return_coefficients=True)
        if weights is not None:
            c_fit /= weights             # U^T (X W) = (U^T X) W
            say(f"texel norms span more than {_HDR_NORM_RANGE:g}: basis fitted with weights ||x_t||^-1/2")
    if len(sv) == 0 or not sv[0] > 0:
        where = btf.metadata.get("_path") or "input BTF"
        if len(fit) < btf.n_pixels:
            raise BTFError(f"{where}: the {len(fit)} texels the basis is fitted on are all zero "
                           f"({'central region: try --region' if opts.solver == 'paper' else 'try --fit-texels'})")
        raise BTFError(f"{where}: every pixel is zero; there is nothing to compress")
    rank = int(np.count_nonzero(sv > sv[0] * 1e-6))  # drop directions that carry no signal
    u, sv = u[:, :rank], sv[:rank]
    c_fit = None if opts.solver == "paper" else c_fit[:rank]     # (k, 3 n) curve space; the paper needs none
    del x_fit
    k_fit = u.shape[1]
    timings["fit_s"] = time.perf_counter() - t
    say(f"basis: {k_fit} vectors from {len(fit)} texels ({opts.solver}) in {timings['fit_s']:.2f} s")

    # Colour and (for a plain k) the quantisation step, from the sampled texels' coefficients,
    # before the projection: then the projection can skip what the step would zero out.
    held_out = not np.isin(evalt, fit).any()
    truth = data.to_working(data.columns(evalt)).reshape(S, len(evalt), 3)
    c_eval = (u.T @ truth.reshape(S, -1)).reshape(k_fit, len(evalt), 3)
    sampled = c_eval if c_fit is None else np.concatenate([data.to_working(c_fit).reshape(k_fit, -1, 3), c_eval], axis=1)
    # Energy outside the basis, estimated on the held-out texels.
    outside = float(np.einsum("ij,ij->", truth.reshape(S, -1), truth.reshape(S, -1), dtype=np.float64)
                    - np.einsum("kpc,kpc->", c_eval, c_eval, dtype=np.float64))
    outside = max(outside, 0.0) * P / len(evalt)
    color_matrix = np.eye(3) if opts.solver == "paper" else _colour_decorrelation(sampled)
    _apply_colour(sampled, color_matrix)
    step = None
    ks = (k_fit,) * 3
    if not budgeted and opts.solver != "paper" and codec_name not in ("exr", "jpeg"):
        k = min(opts.k or _DEFAULT_K, k_fit)
        inside = float(np.einsum("kpc,kpc->", sampled, sampled, dtype=np.float64)) * P / sampled.shape[1]
        table = ratedist.rd_table(sampled[:k], u[:, :k], inside + outside, n_texels=P, seed=opts.seed, rates=False)
        step = ratedist.choose_for_k(table, k)
        ks = _planes_in_use(sampled[:k], step)
    del sampled, c_fit, c_eval

    t = time.perf_counter()
    coeff, total_energy = data.project(u, data.working_mix(color_matrix.T), ks, energy=opts.target_error is not None)
    timings["project_s"] = time.perf_counter() - t
    if total_energy is None:
        total_energy = float(np.einsum("kpc,kpc->", coeff, coeff, dtype=np.float64)) + outside

    t = time.perf_counter()
    with atomic_dir(out) as tmp:
        cbtf, choice = _choose_and_store(data, u, coeff, total_energy, truth, evalt, opts, codec_name,
                                         color_matrix, tmp, say, step)
        choice["planes"] = list(ks)
        timings["store_s"] = time.perf_counter() - t
        sums = _evaluate(cbtf, truth, evalt)
        curve = error_curve(cbtf, data, opts.seed)
        timings["total_s"] = time.perf_counter() - t0
        cbtf.info.update({
            "solver": opts.solver,
            "choice": choice,
            "singular_values": [float(s) for s in sv],
            "estimated_error": {"linear": sums.report(), "texels": int(len(evalt)),
                                "note": ("held-out texels (not used in the fit)" if held_out else
                                         "all texels (the image is smaller than the fitting sample: in-sample)")
                                + ", all samples, working space"},
            "error_curve": {"file": "error_curve.csv", "plot": "error_curve.png"},
            "provenance": {"tool": "usdbtf", "version": __version__, "solver": opts.solver, "seed": opts.seed,
                           "source": str(btf.metadata.get("_path", "")), "options": _opts_dict(opts)},
        })
        cbtf.info.update(opts.extra)
        write_metadata(cbtf, tmp)
        write_curve(curve, tmp)
    # Timings stay out of the files: same inputs and seed give byte-identical folders.
    cbtf.info["timings"] = {k_: round(v, 4) for k_, v in timings.items()}
    say(f"k = {cbtf.k}, {cbtf.info['bytes']['payload']} bytes, estimated error {sums.percent:.3f} % "
        f"({timings['total_s']:.2f} s: " + ", ".join(f"{k_[:-2]} {v:.2f}" for k_, v in timings.items()
                                                      if k_ != "total_s") + ")")
    return cbtf


def _opts_dict(opts: Options) -> dict:
    return {k: v for k, v in opts.__dict__.items() if k not in ("extra", "workers")}


def _encode(data, u, coeff, k, step, opts, codec_name, color_matrix, tmp):
    """Quantise the first k components at ``step`` and write them into ``tmp`` (replacing
    any earlier attempt).  Returns (CompressedBTF, byte counts)."""
    cbtf = _build(data, u, coeff, k, step, opts, codec_name, color_matrix)
    if (tmp / "coeff").exists():
        for old in (tmp / "coeff").glob("*"):
            old.unlink()
    return cbtf, write_textures(cbtf, tmp)


def _fit_k_to_budget(sizes: dict, k: int, budget: int, margin: float = 0.995) -> int:
    """Largest k' <= k whose measured textures fit ``margin * budget`` (basis bytes pro rata);
    0 when not even one does.  The margin leaves room for the basis re-encode's rounding."""
    per = np.cumsum(sizes["per_coefficient"]) + sizes["basis"] * np.arange(1, k + 1) / k
    fits = np.flatnonzero(per <= margin * budget)
    return int(fits[-1]) + 1 if len(fits) else 0


def _probe_codec_factors(table, data, u, coeff, k, step, opts, codec_name, color_matrix, tmp) -> tuple[float, float]:
    """Measured bytes / entropy-model bytes for coefficient textures and for the basis,
    from encoding ~12 textures spread over the first k and the k-column basis."""
    j = list(table.steps).index(step)
    probe = np.unique(np.linspace(0, k - 1, min(k, 12)).round().astype(int))
    cbtf = _build(data, u, coeff, k, step, opts, codec_name, color_matrix)
    codec = get_codec(codec_name)
    folder = tmp / "probe"
    folder.mkdir(exist_ok=True)
    try:
        coeff_bytes = sum(codec.write(folder / f"p{i}.{codec.ext}", cbtf.coefficients[i], "data") for i in probe)
        basis_bytes = write_basis(cbtf, folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    overhead = len(probe) * ratedist.FILE_OVERHEAD_BYTES  # the model adds it unscaled
    fc = max(coeff_bytes - overhead, 1.0) / max(float(table.coeff_bytes[probe, j].sum()), 1.0)
    fb = basis_bytes / max(float(table.basis_bytes[:k, j].sum()), 1.0)
    return float(fc), float(fb)


def _choose_and_store(data, u, coeff, total_energy, truth, evalt, opts, codec_name, color_matrix, tmp, say,
                      step=None):
    """Pick (k, step) by rate-distortion, write textures into ``tmp``; returns (CompressedBTF, choice).
    ``step``: already chosen (a plain k, from the sampled texels)."""
    btf = data.btf
    k_fit = u.shape[1]
    if opts.solver == "paper" or codec_name in ("exr", "jpeg"):
        return _choose_by_k_only(data, u, coeff, truth, evalt, opts, codec_name, color_matrix, tmp)
    if step is not None:
        # Components no colour plane was projected on are all zero: not worth a file.
        in_use = np.flatnonzero(np.abs(coeff).max(axis=(1, 2)) > 0)
        k = min(opts.k or _DEFAULT_K, k_fit, int(in_use[-1]) + 1 if len(in_use) else 1)
        cbtf, sizes = _encode(data, u, coeff, k, step, opts, codec_name, color_matrix, tmp)
        say(f"  k = {k}, step = {step:.4g}, {sizes['payload']} bytes")
        return cbtf, {"mode": "k", "k": k, "step": step, "bytes": sizes["payload"]}
    table = ratedist.rd_table(coeff, u, total_energy, seed=opts.seed)

    last = {}

    def encode(k, step, attempt):
        cbtf, sizes = _encode(data, u, coeff, k, step, opts, codec_name, color_matrix, tmp)
        say(f"  try {attempt}: k = {k}, step = {step:.4g}, {sizes['payload']} bytes")
        last.update(k=k, step=step)
        return cbtf, sizes

    if opts.max_bytes is not None:
        budget = opts.max_bytes
        k, step = ratedist.choose_for_bytes(table, budget, 1.0)
        # Calibrate the entropy model on a probe encode (a dozen textures + the basis),
        # then encode once; if still over budget, drop trailing components (energy order:
        # only the basis image is rewritten).
        fc, fb = _probe_codec_factors(table, data, u, coeff, min(k, opts.k or k), step, opts, codec_name,
                                      color_matrix, tmp)
        k, step = ratedist.choose_for_bytes(table, 0.995 * budget, fc, fb)
        k = min(k, opts.k or k)
        cbtf, sizes = encode(k, step, 1)
        while sizes["payload"] > budget:
            k2 = _fit_k_to_budget(sizes, k, budget)
            if k2 == 0 or k2 == k:
                k2 = k - 1
            if k2 < 1:
                raise BTFError(f"cannot meet --max-bytes {budget}: even one basis vector does not fit")
            cbtf, sizes = truncate_written(cbtf, k2, tmp)
            say(f"  trimmed to k = {k2}: {sizes['payload']} bytes")
            k = k2
        choice = {"mode": "max_bytes", "k": k, "step": step, "bytes": sizes["payload"],
                  "codec_factor": {"coefficients": fc, "basis": fb}}
    elif opts.target_error is not None:
        N = truth.size * btf.n_pixels / len(evalt)
        rms_target = opts.target_error / 100.0 * float(truth.mean()) / _GAUSS_L1_OVER_RMS
        scale, factor = 1.0, 1.0
        for attempt in range(1, 4):
            k, step = ratedist.choose_for_error(table, rms_target**2 * N * scale, factor)
            cbtf, sizes = encode(k, step, attempt)
            err = _evaluate(cbtf, truth, evalt).percent
            if err <= opts.target_error:
                break
            scale *= (opts.target_error / err) ** 2   # the L1/RMS ratio of these errors differs from Gaussian
        choice = {"mode": "target_error", "k": k, "step": step, "bytes": sizes["payload"],
                  "estimated_percent": err}
    return cbtf, choice


def _choose_by_k_only(data, u, coeff, truth, evalt, opts, codec_name, color_matrix, tmp):
    """Solvers/codecs without a quantisation step to tune: k alone meets the request."""
    k_fit = u.shape[1]
    k = min(opts.k or _DEFAULT_K, k_fit)
    cbtf = _build(data, u, coeff, k, 0.0, opts, codec_name, color_matrix)
    sizes = write_textures(cbtf, tmp)
    choice = {"k": k}
    if opts.max_bytes is not None:
        # Min-max storage does not depend on k: dropping trailing components is exact here.
        k = _fit_k_to_budget(sizes, k, opts.max_bytes, margin=1.0)
        if k == 0:
            one = sizes["per_coefficient"][0] + sizes["basis"] / cbtf.k
            raise BTFError(f"cannot meet --max-bytes {opts.max_bytes}: one basis vector already needs {one:.0f} bytes")
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
        cbtf, _ = truncate_written(cbtf, k, tmp)
        choice["k"] = k
    return cbtf, choice


def compress(btf: BTF, out, **options) -> CompressedBTF:
    """Convenience: ``compress(btf, "out_dir", solver="paper", k=150)``."""
    return compress_to_folder(btf, out, Options(**options))
