"""Which working domain (:mod:`.domain`) one compress uses: ``--domain auto|linear|srgb|gamma:G``.

``auto`` chooses per material, cheaply (issue 16's research, ``methods.domain_scores``):
for each candidate curve (:data:`.domain.AUTO_CANDIDATES`) a basis is fitted as the
compress fits it, on a subsample of the fitting texels and of the samples (the scored ones);
the evaluation texels (disjoint from the fitting ones) are projected onto it over those
samples, and the **unquantised** error of that basis is measured there, both on the
input's encoded values and in scene-linear.  The candidate with the lowest
``log(encoded %) + log(linear %)`` wins: both errors at once, since a comparison against
any fixed method (the paper's) divides each by a constant per material.  The compress then
fits its basis in the winner's domain on every fitting texel and sample.

Two passes (issue 27).  The **coarse** pass scores every candidate on every fourth sample,
every fourth fitting texel and every other evaluation texel (:data:`COARSE`: a quarter to a
third of the fine pass's cost).  Its scores sit at another level than the fine pass's, but
the gaps to the best agree for the candidates near it (fine gap <= 0.15): at paper scale
(seven presets, the plain and the budget probe: 14 cases) to within 0.021 in 12 cases, 0.037
once (pebbles, budget: x^(1/2.2) further behind in the coarse pass) and 0.058 once, where two
curves are in a near tie (ridged_fabric, budget: linear 0.044 behind x^(1/1.6) in the fine
pass, 0.014 ahead in the coarse one).  Candidates within :data:`TIE_MARGIN` of the coarse best are therefore
scored again by the **fine** pass (:data:`FINE`: every other sample and fitting texel, every
evaluation texel: the scorer of issue 16) and the best of them wins.  The choice was the fine
pass's in all 14 cases (``benchmarks/RESULTS.md``, "Compression speed against its floor").
Inputs too small for the coarse subsample (fewer than :data:`COARSE_MIN_SAMPLES` samples or
:data:`COARSE_MIN_TEXELS` fitting texels) are scored by the fine pass alone.  (Fitting the
candidates on every sample instead of every other chose the same curve on all seven presets
and two UBO2014-sized inputs, at 1.6x the cost.)

No curve: ``--solver paper`` with ``auto`` fits the input's own encoding (sRGB for
sRGB-encoded files, as the paper factorised the camera's 8-bit values; else linear), and an
input compressed from its factors (UBO2014 DFMF/FMF) stays linear, since the transcoding's
algebra holds for linear decodes only.
"""
from __future__ import annotations

import logging

import numpy as np

from ..imageio import numpy_dtype
from .code_table import file_codes
from .domain import AUTO_CANDIDATES, LINEAR, Domain, parse_domain
from .fit import BasisFit, fit_basis
from .parallel import in_threads, rows_apply

__all__ = ["choose_domain", "resolve_domain", "score_domains", "encoding_domain"]

log = logging.getLogger(__name__)

#: (sample stride, fitting-texel stride, evaluation-texel stride) of the scored subsample.
FINE = (2, 2, 1)
COARSE = (4, 4, 2)
#: Candidates whose coarse score is within this of the best are scored again by the fine pass
#: (scores are natural logs: 0.04 is 4 % of error; see the module docstring for the evidence).
TIE_MARGIN = 0.04
#: The coarse pass needs this many samples and fitting texels (else the fine pass alone).
COARSE_MIN_SAMPLES = 4096
COARSE_MIN_TEXELS = 2048
#: The score truncates the basis to at most S / this many vectors: a basis of nearly S
#: vectors reconstructs anything, whatever the curve.
_PROBE_FRACTION = 4
#: ... and to at most this many (the research scored 300 components).
_PROBE_K = 300
#: Samples per block of the scorer's streamed products and error sums (fixed: the sums do
#: not depend on the number of CPUs).
_SCORE_BLOCK = 256


def encoding_domain(btf) -> Domain:
    """The curve of the input's own encoding: sRGB for an sRGB-encoded colour space, else linear."""
    space = (btf.color_space or "").lower()
    srgb = space.startswith("srgb encoded") or space in ("srgb", "srgb texture", "srgb - texture")
    return Domain("srgb") if srgb else LINEAR


def choose_domain(source, texels, k: int, options) -> tuple[Domain, BasisFit | None, dict | None]:
    """The domain step: resolve ``options.domain`` (:func:`resolve_domain`) and switch
    ``source`` to it (every later answer -- columns, projection, rows -- is in the domain).

    Returns (domain, the basis already fitted in it or None, scores or None).
    """
    domain, fit, scores = resolve_domain(source, texels, k, options)
    if scores is not None:
        log.info("domain: " + ", ".join(f"{n} {s['encoded']:.2f} % enc / {s['linear']:.2f} % lin"
                                        + (f" (fine {s['fine']['score']:.3f})" if "fine" in s else "")
                                        for n, s in scores.items()) + f" -> {domain.name}")
    if not domain.is_linear:
        source.set_domain(domain)
    return domain, fit, scores


def resolve_domain(source, texels, k: int, options) -> tuple[Domain, BasisFit | None, dict | None]:
    """The working domain of one compress, with the basis fitted in it when choosing did so.

    Parameters
    ----------
    source : a source from :func:`.source.load_source`, still linear.
    texels : the fitting and evaluation texels (:class:`.texels.Texels`).
    k : basis vectors to fit (``options.fit_k``).
    options : ``domain`` ("auto", "linear", "srgb", "gamma:G"), ``solver``.

    Returns
    -------
    domain : the chosen :class:`~.domain.Domain`.
    fit : the basis fitted in it (auto only; else None: fit as usual after ``set_domain``).
    scores : {name: {"encoded", "linear", "score"}} for auto, else None.
    """
    asked = parse_domain(options.domain)
    factored = not hasattr(source, "set_domain")       # a FactoredSource: linear algebra on the factors
    if asked is not None:
        return asked, None, None
    if factored:
        return LINEAR, None, None
    if options.solver == "paper":
        return encoding_domain(source.btf), None, None
    return choose_by_scores(source, texels, k, options)


def choose_by_scores(source, texels, k: int, options, candidates=AUTO_CANDIDATES) -> tuple[Domain, None, dict]:
    """The coarse pass over ``candidates``, then the fine pass over those within
    :data:`TIE_MARGIN` of the coarse best (see the module docstring).

    Returns (the winner, None, scores): {name: {"encoded", "linear", "score"}} of the first pass
    for every candidate (the coarse one, or the fine one for a small input), and under
    ``"fine"`` the fine pass's for the candidates it scored again (the winner is the best of
    those when there are any).
    """
    coarse = source.btf.n_samples >= COARSE_MIN_SAMPLES and len(texels.fit) >= COARSE_MIN_TEXELS
    scores, fits = score_domains(source, texels, k, options, candidates, strides=COARSE if coarse else FINE)
    best = min(scores, key=lambda name: scores[name]["score"])
    close = [dom for dom, _ in fits.values() if scores[dom.name]["score"] <= scores[best]["score"] + TIE_MARGIN]
    if coarse and len(close) > 1:
        fine, _ = score_domains(source, texels, k, options, close, strides=FINE)
        best = min(fine, key=lambda name: fine[name]["score"])
        scores = {name: dict(entry, fine=fine[name]) if name in fine else entry for name, entry in scores.items()}
    return fits[best][0], None, scores


def score_domains(source, texels, k: int, options, candidates=AUTO_CANDIDATES, *,
                  strides: tuple = FINE) -> tuple[dict, dict]:
    """Unquantised held-out error of each candidate's basis (see the module docstring), on
    every ``strides[0]``-th sample, ``strides[1]``-th fitting texel and ``strides[2]``-th
    evaluation texel.

    Streams over blocks of samples (``_SCORE_BLOCK`` rows, on one thread each): the scorer
    holds the fitting columns in the candidate's domain and the evaluation texels' file
    codes, never a reconstruction of every scored sample at once (at UBO2014's size that
    would be ~0.6 GB more).

    Returns
    -------
    scores : {name: {"encoded": %, "linear": %, "score": log(enc) + log(lin)}}.
    fits : {name: (Domain, BasisFit)}.
    """
    btf = source.btf
    S = btf.n_samples
    # The columns as the source stores them, converted to each candidate's domain block by
    # block (one table lookup per value for integer files: :meth:`~.source._Source.curves_in`).
    x_raw = source.raw_columns(texels.fit)                                       # (S, 3 n) stored
    y_raw = source.raw_columns(texels.evaluation)                                # (S, 3 m) stored
    sample_stride, texel_stride, eval_stride = strides
    if eval_stride > 1:
        y_raw = np.ascontiguousarray(y_raw.reshape(S, -1, 3)[:, ::eval_stride]).reshape(S, -1)
    linear = source.curves_in(LINEAR)
    codes = _Codes(btf)
    scored = np.arange(0, S, sample_stride)
    blocks = [scored[a:a + _SCORE_BLOCK] for a in range(0, len(scored), _SCORE_BLOCK)]
    truth = in_threads(lambda rows: linear(y_raw[rows]), blocks)                # scored rows, working space
    # An integer file's stored values are its codes: the encoded truth as it is (no OpenColorIO
    # pass to convert them back); other inputs are encoded from the working-space truth.
    integer_codes = codes.dtype.kind == "u" and y_raw.dtype == codes.dtype
    truth_codes = [y_raw[rows] for rows in blocks] if integer_codes else in_threads(codes, truth)
    lin_total = sum(float(np.abs(t).sum(dtype=np.float64)) for t in truth)
    enc_total = sum(codes.total(c) for c in truth_codes)
    del truth
    scores, fits = {}, {}
    # The candidates are fitted on the scored samples only and a subsample of the fitting
    # texels (fine: a quarter of the columns the compress fits, so four candidates cost
    # about one fit; coarse: a sixteenth); the compress then fits the winner's basis on all of
    # them.  One buffer holds the candidate's columns (fine: 0.14 GB at UBO2014's size).
    half = x_raw[scored].reshape(len(scored), -1, 3)[:, ::texel_stride]
    x_dom = np.empty((len(scored), 3 * half.shape[1]), np.float32)
    local = np.cumsum([0] + [len(rows) for rows in blocks])              # block b: rows local[b]..local[b + 1]
    # Only the first probe_k vectors are scored: fitting more (a budget's 500) costs ~1.7x
    # as much and changes no score's use of them (the research fitted and scored 300).
    probe_k = max(1, min(k, _PROBE_K, S // _PROBE_FRACTION))
    for dom in candidates:
        forward = source.curves_in(dom)
        fit = fit_basis(rows_apply(lambda b, out: forward(np.ascontiguousarray(b), out=out.reshape(b.shape)), half,
                                   x_dom, into=True), probe_k, options)
        u = fit.basis[:, :max(1, min(fit.k, probe_k))]
        # Coefficients of the evaluation texels: U^T f(Y) over the scored samples, summed over
        # their blocks in order.
        c = sum(in_threads(lambda b: (u[local[b]:local[b + 1]].T @ forward(y_raw[blocks[b]])).astype(np.float64),
                           range(len(blocks))))
        c = c.astype(np.float32)

        def errors(b: int) -> tuple[float, float]:
            rec = dom.inverse(u[local[b]:local[b + 1]] @ c)
            return (float(np.abs(rec - linear(y_raw[blocks[b]])).sum(dtype=np.float64)),
                    codes.distance(codes(rec), truth_codes[b]))

        sums = in_threads(errors, range(len(blocks)))
        e_lin = 100.0 * sum(e for e, _ in sums) / max(lin_total, 1e-30)
        e_enc = 100.0 * sum(e for _, e in sums) / max(enc_total, 1e-30)
        score = float(np.log(max(e_enc, 1e-9)) + np.log(max(e_lin, 1e-9)))
        scores[dom.name] = {"encoded": e_enc, "linear": e_lin, "score": score}
        fits[dom.name] = (dom, fit)
    return scores, fits


class _Codes:
    """Working-space values (rows, 3 m) -> ``btf``'s file codes (rows, 3 m) in their own dtype
    (uint8/uint16 codes clipped and rounded as a file holds them, by table where one serves:
    :func:`.code_table.file_codes`; float files as floats), and L1 sums of codes normalised to
    [0, 1]."""

    def __init__(self, btf):
        self.encode = file_codes(btf)
        self.top = {"uint8": 255.0, "uint16": 65535.0}.get(btf.bit_depth, 1.0)
        #: The file's numpy type (integer codes for uint8/uint16 files).
        self.dtype = np.dtype(numpy_dtype(btf.bit_depth))

    def __call__(self, lin: np.ndarray) -> np.ndarray:
        return self.encode(lin)

    def total(self, codes: np.ndarray) -> float:
        return float(np.abs(codes).sum(dtype=np.float64)) / self.top

    def distance(self, a: np.ndarray, b: np.ndarray) -> float:
        diff = a.astype(np.int32) - b if a.dtype.kind == "u" else a.astype(np.float64) - b
        return float(np.abs(diff).sum(dtype=np.float64)) / self.top
