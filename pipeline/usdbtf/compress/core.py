"""``compress``: a BTF -> basis + coefficient textures (the apparent-BRDF method).

Two solvers share one pipeline of named steps (read :func:`compress` top to bottom):

``paper``  Koudelka et al. 2003 exactly: exact SVD of a contiguous square region
           (default the central quarter-width square), k vectors shared by R, G, B,
           each coefficient texture min-max scaled to [0, 1] as 8-bit JPEG, the basis
           min-max scaled per vector into one uncompressed 8-bit image.
``rsvd``   (default) randomized SVD with power iterations over a random sample of
           texels from the whole image, every pixel projected, coefficient colour
           channels decorrelated (3x3 PCA), one uniform quantisation step for all
           coefficients with basis steps scaled by 1/sigma_i (reverse water-filling),
           (k, step) chosen by rate-distortion, lossless JPEG XL storage.

:func:`compress` is pure and in memory: it creates no file anywhere (codecs encode into
anonymous in-memory files).  :func:`write_compress` writes its result as a folder.
"""
from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from .. import __version__, numeric
from ..atomic import atomic_dir
from ..model import BTF
from ..outputs import COMPRESSED as COMPRESSED_KIND
from ..resources import release_free_heap
from .coverage import shaped_input
from .curve import curve_truth, write_curve
from .decorrelate import color_decorrelation, rotate_color
from .evaluate import error_curve, held_out_errors, held_out_set
from .domain import parse_domain
from .domain_choice import choose_domain
from .fit import HDR_NORM_RANGE, fit_source, fits_every_texel, require_signal, sampled_coefficients
from .format import CompressedBTF, write_metadata, write_textures
from .options import CompressOptions
from .parallel import one_blas_thread
from .projection import project
from .quantise import Factorisation
from .ratecontrol import PlanCapped, rate_control, step_for_k
from .select_source import load_source
from .texels import sample_texels

log = logging.getLogger(__name__)

__all__ = ["compress", "write_compress"]


def compress(btf: BTF, options: CompressOptions | None = None) -> CompressedBTF:
    """Compress ``btf`` into a basis and coefficient textures, in memory.

    Parameters
    ----------
    btf : the BTF (S samples of W x H texels); its files are read, nothing is written.
    options : what to do (default :class:`CompressOptions`()).

    Returns
    -------
    CompressedBTF : the stored representation (as a reader of its files will see it), with
    its encoded bytes (``encoded``), the error curve (``curve``) and everything the metadata
    records in ``info``.  :func:`write_compress` writes it.
    """
    opts = options or CompressOptions()
    opts.validate()
    clock = _Clock()
    # A scene-shaped build: only the samples and the resolution it needs (.coverage).  The
    # filtered images are floats; the source's record keeps the measured bit depth (what
    # decompress writes).
    measured_depth = btf.bit_depth
    full = btf
    btf, covered = shaped_input(btf, opts.coverage, opts.max_texels)
    if covered is not None:
        log.info(f"coverage: {len(covered['views'])} of {covered['input_views']} views x {len(covered['lights'])} "
                 f"of {covered['input_lights']} lights ({btf.n_samples} of {covered['input_samples']} samples), "
                 f"{btf.width}x{btf.height} texels (factor {covered['resolution_factor']})")
    texels = sample_texels(btf, opts)
    as_full = None
    if covered is not None and parse_domain(opts.domain) is None:
        # A scene-shaped compress works in the domain a full build chooses (issue 41), scored on
        # the whole input as there, so the directions both keep reconstruct alike.
        with one_blas_thread():
            as_full = full_input_domain(full, opts)
        log.info(f"domain: {as_full[0].name}, as a full build of the input chooses it "
                 f"({clock.lap('domain of the full input'):.2f} s)")
    # The source holds the data (and a spill file or a cluster, which closing releases).
    # BLAS on one thread: the steps parallelise themselves, so no byte depends on thread
    # counts (see .parallel).
    with one_blas_thread(), load_source(btf, texels, opts) as source:
        log.info(f"loaded {btf.n_samples} samples of {btf.width}x{btf.height} ({source.kind}, {source.nbytes / 2**20:.0f} MiB) "
            f"in {clock.lap('load'):.2f} s")
        # The working domain first (auto fits each candidate; the winner's fit is kept), then
        # the basis, then the held-out truth: not beside the fit, whose columns are the run's
        # peak of memory (paper scale: the truth's 0.13 GB on top of 1.1 GB).
        k_fit = opts.fit_k(btf.n_samples, btf.n_pixels)
        if as_full is not None:
            domain, chosen, _ = choose_domain(source, texels, k_fit, replace(opts, domain=as_full[0].name))
            scores = as_full[1]
        else:
            domain, chosen, scores = choose_domain(source, texels, k_fit, opts)
        every = chosen is None and fits_every_texel(source, texels.fit, opts)
        fit = chosen or fit_source(source, texels.fit, k_fit, opts)
        held = held_out_set(source, texels)
        if fit.weighted:
            log.info(f"texel norms span more than {HDR_NORM_RANGE:g}: basis fitted with weights ||x_t||^-1/2")
        require_signal(fit, btf, texels, opts)
        log.info(f"basis: {fit.k} vectors from {btf.n_pixels if every else len(texels.fit)} texels "
                 f"({opts.solver}{', streamed' if every else ''}, {domain.name} domain) "
                 f"in {clock.lap('fit'):.2f} s")
        # Colour and (for a plain k) the quantisation step, from the sampled texels' coefficients,
        # before the projection: then the projection can skip what the step would zero out.
        sampled, outside = sampled_coefficients(fit, source.to_working, held.truth, btf.n_pixels)
        color = np.eye(3) if opts.solver == "paper" else color_decorrelation(sampled)
        # --target-error's plan needs the truth's mean (its scale), held out before the fit's
        # coefficients are sampled.  Its model measures error in the working domain: a plan only
        # where that is the target's kind (scene-linear targets in the linear domain, targets
        # on the encoded values in a curve); else the plan is capped (ubo81 metal_flakes with
        # linear-light targets: both fell back to every component, 1.5-2.4 s lost) and every
        # component is projected from the start.
        planned = opts.target_error is not None and (opts.error_domain == "linear") == domain.is_linear
        truth_mean = float(held.truth.mean()) if planned else None
        step, planes = step_for_k(rotate_color(sampled, color), fit.basis, outside, btf.n_pixels, opts, truth_mean)
        del sampled
        clock.lap("color")
        # After the projection no step reads a stored value but the error curve's few samples,
        # except a --target-error whose plan caps its choice (it projects again): the others let
        # the values go before rate control (:func:`_let_go`).
        kept = {}
        early = kept if opts.target_error is None else None
        try:
            chosen = _project_and_choose(source, btf, fit.basis, color, planes, step, domain, outside, opts, held,
                                         clock, early)
        except PlanCapped as capped:
            chosen, why = None, str(capped)   # (out of the handler: its traceback holds the coefficients)
        if chosen is None:
            # The plan capped --target-error's choice: every fitted component on every plane,
            # and rate control again (the choice of a run that never planned).
            clock.lap("capped")
            planes = (fit.basis.shape[1],) * 3
            log.info(f"  {why}: projecting all {planes[0]} components on every colour plane")
            chosen = _project_and_choose(source, btf, fit.basis, color, planes, step, domain, outside, opts, held,
                                         clock)
        cbtf, choice = chosen
        if scores is not None:
            choice["domain_scores"] = scores
        if as_full is not None:
            choice["domain_scored_on"] = "the full input (a scene-shaped compress keeps the full build's domain)"
        clock.lap("encode")
        if every:
            choice["basis_texels"] = int(btf.n_pixels)
        _let_go(source, btf.n_samples, kept)      # (a --target-error run's values go only now)
        # The held-out error and the error curve one after the other (each on every core):
        # side by side their peaks added up, and --k 150 at paper scale peaked at 1.22-1.26 GB.
        result = _described(cbtf, opts, dict(choice, planes=list(planes)), fit.singular_values, held,
                            held_out_errors(cbtf, held), error_curve(cbtf, None, truth=kept["curve"]),
                            getattr(source, "provenance", None), covered)
        result.source = dict(result.source, bit_depth=measured_depth)
        clock.lap("evaluate")
    log.info(f"k = {result.k}, {result.info['bytes']['payload']} bytes, estimated error "
        f"{result.info['estimated_error']['linear']['percent']:.3f} % ({clock})")
    return result


def full_input_domain(btf: BTF, opts: CompressOptions):
    """(the working domain ``--domain auto`` chooses for the whole of ``btf``, its scores or
    None): what a full compress of it would work in (:func:`.domain_choice.resolve_domain`, on
    the full input's fitting and evaluation texels; its coarse pass keeps that cheap)."""
    from .domain_choice import resolve_domain

    texels = sample_texels(btf, opts)
    k_fit = opts.fit_k(btf.n_samples, btf.n_pixels)
    with load_source(btf, texels, opts) as source:
        domain, _, scores = resolve_domain(source, texels, k_fit, opts)
    return domain, scores


def _let_go(source, n_samples: int, kept: dict) -> None:
    """Keep the error curve's samples in ``kept["curve"]`` (:func:`.curve.curve_truth`), then
    release the source's stored values where it can (an in-memory source's: 0.53 GB of a
    paper-scale run's 1.2 GB, issue 42).  Once per ``kept``."""
    if "curve" in kept:
        return
    kept["curve"] = curve_truth(source, n_samples)
    release = getattr(source, "release_values", None)
    if release is not None:
        release()
        release_free_heap()


def _project_and_choose(source, btf: BTF, fit_basis: np.ndarray, color: np.ndarray, planes: tuple, step, domain,
                        outside: float, opts: CompressOptions, held, clock: "_Clock",
                        early: dict | None = None) -> tuple[CompressedBTF, dict]:
    """Project ``planes`` components per colour plane, then rate control (:func:`.ratecontrol.rate_control`,
    which raises :class:`.ratecontrol.PlanCapped` when the plan caps a ``--target-error``
    choice).  ``early``: a dict for :func:`_let_go` between the two (None: keep the source)."""
    # Only the components some plane is projected on (under a budget, what the sampled
    # model could choose: the rest would be zeros for rate control to skip).
    basis = fit_basis[:, :max(planes)]
    coeff, energy = project(source, basis, color, planes, energy=opts.target_error is not None)
    clock.lap("project")
    if energy is None:   # not measured: the coefficients' energy plus the estimate outside the basis
        energy = float(np.einsum("kpc,kpc->", coeff, coeff, dtype=np.float64)) + outside
    f = Factorisation(btf, basis, coeff, color, energy, planes, step, domain)
    del coeff
    if early is not None:
        _let_go(source, btf.n_samples, early)
    # What the fit's and the projection's threads freed, back to the system before rate control
    # allocates its own (a budget's packagings, issue 42): glibc would keep it resident.
    release_free_heap()
    return rate_control(f, opts, held, k_fit=fit_basis.shape[1])


def write_compress(result: CompressedBTF, path, *, force: bool = False) -> dict:
    """Write ``result`` as a ``btf-compressed/1`` folder at ``path``, atomically.

    The textures' bytes come from ``result.encoded`` when it still describes ``result``
    (else they are encoded now); the metadata and, when ``result.curve`` is set, the error
    curve (``error_curve.csv``/``.png``) are written beside them.  ``result`` is not changed.

    Parameters
    ----------
    result : from :func:`compress` (or any CompressedBTF, e.g. read or truncated).
    path : the output folder.
    force : replace an existing ``path`` (only after the new folder is complete).

    Returns
    -------
    dict : bytes written (basis, coefficients, payload, per_coefficient, metadata).
    """
    with atomic_dir(path, kind=COMPRESSED_KIND, overwrite=force) as tmp:
        sizes = write_textures(result, tmp)
        sizes = dict(sizes, metadata=write_metadata(result, tmp, sizes))
        if result.curve is not None:
            write_curve(result.curve, tmp)
    return sizes


def _described(cbtf: CompressedBTF, opts: CompressOptions, choice: dict, singular_values, held, sums,
               curve: dict, transcoded: dict | None = None, covered: dict | None = None) -> CompressedBTF:
    """``cbtf`` with what the metadata records about how it was made (``transcoded``: how a
    factorised input was compressed from its factors; ``covered``: what a partial compress
    kept, :func:`.coverage.coverage_record`), its held-out errors (``sums``: linear, encoded)
    and its error curve."""
    info = dict(cbtf.info)
    info.update({
        "solver": opts.solver,
        "choice": choice,
        "singular_values": [float(s) for s in singular_values],
        "estimated_error": {"linear": sums[0].report(), "encoded": sums[1].report(),
                            "texels": int(len(held.texels)),
                            **({"in_sample_texels": int(len(held.in_sample.texels))} if held.in_sample else {}),
                            "note": ("a sample of the texels outside the fitting sample and one of those in it, "
                                     "weighted by their shares of the image (the basis is fitted on every texel)"
                                     if held.in_sample and "basis_texels" in choice else
                                     "held-out texels (not used in the fit) and a sample of the fitted ones, "
                                     "weighted by their shares of the image" if held.in_sample else
                                     "held-out texels (not used in the fit)" if held.disjoint else
                                     "all texels (the image is smaller than the fitting sample: in-sample)")
                            + ", all samples"},
        "error_curve": {"file": "error_curve.csv", "plot": "error_curve.png"},
        # The numeric platform decides the bits as much as the version does (usdbtf.numeric).
        "provenance": {"tool": "usdbtf", "version": __version__, "solver": opts.solver, "seed": opts.seed,
                       "source": cbtf.source["path"], "options": opts.recorded(), "numeric": numeric.platform()},
    })
    if transcoded is not None:
        info["provenance"]["transcoded"] = transcoded
    if covered is not None:
        info["coverage"] = covered
    info.update(opts.extra)
    return replace(cbtf, info=info, curve=curve)


class _Clock:
    """Seconds per step since the previous lap (timings are logged, never stored: the same
    inputs and seed give byte-identical outputs)."""

    def __init__(self):
        self.start = self.t = time.perf_counter()
        self.seconds: dict[str, float] = {}

    def __str__(self) -> str:
        return f"{self.t - self.start:.2f} s: " + ", ".join(f"{name} {s:.2f}" for name, s in self.seconds.items())

    def lap(self, name: str | None) -> float:
        now = time.perf_counter()
        dt, self.t = now - self.t, now
        if name is not None:
            self.seconds[name] = dt
        return dt
