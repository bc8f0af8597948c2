"""Which working domain (:mod:`.domain`) one compress uses: ``--domain auto|linear|srgb|gamma:G``.

``auto`` chooses per material, cheaply (issue 16's research, ``methods.domain_scores``):
for each candidate curve (:data:`.domain.AUTO_CANDIDATES`) the basis is fitted exactly as
the compress will fit it, the evaluation texels (disjoint from the fitting ones) are
projected onto it, and the **unquantised** error of that basis is measured on every second
sample, both on the input's encoded values and in scene-linear.  The candidate with the
lowest ``log(encoded %) + log(linear %)`` wins: both errors at once, since a comparison
against any fixed method (the paper's) divides each by a constant per material.  The
winner's basis is the compress's basis (it was fitted on the same columns with the same
seed), so ``auto`` costs one extra fit per further candidate.

No curve: ``--solver paper`` with ``auto`` fits the input's own encoding (sRGB for
sRGB-encoded files, as the paper factorised the camera's 8-bit values; else linear), and an
input compressed from its factors (UBO2014 DFMF/FMF) stays linear, since the transcoding's
algebra holds for linear decodes only.
"""
from __future__ import annotations

import logging

import numpy as np

from .. import colour
from ..manifest import encode_for_file
from .domain import AUTO_CANDIDATES, LINEAR, Domain, parse_domain
from .fit import BasisFit, fit_basis
from .parallel import rows_apply

__all__ = ["choose_domain", "resolve_domain", "score_domains", "encoding_domain"]

log = logging.getLogger(__name__)

#: Every this-many-th sample is scored (halves the scorer's reconstruction cost).
_SCORE_STRIDE = 2
#: The score truncates the basis to at most S / this many vectors: a basis of nearly S
#: vectors reconstructs anything, whatever the curve.
_PROBE_FRACTION = 4
#: ... and to at most this many (the research scored 300 components).
_PROBE_K = 300


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
    scores, fits = score_domains(source, texels, k, options)
    best = min(scores, key=lambda name: scores[name]["score"])
    return fits[best][0], fits[best][1], scores


def score_domains(source, texels, k: int, options, candidates=AUTO_CANDIDATES) -> tuple[dict, dict]:
    """Unquantised held-out error of each candidate's basis (see the module docstring).

    Returns
    -------
    scores : {name: {"encoded": %, "linear": %, "score": log(enc) + log(lin)}}.
    fits : {name: (Domain, BasisFit)}.
    """
    btf = source.btf
    S = btf.n_samples
    x_lin = source.to_working(source.peek_columns(texels.fit))                  # (S, 3 n)
    ev = texels.evaluation
    y_lin = source.to_working(source.peek_columns(ev))                            # (S, 3 m)
    rows = np.arange(0, S, _SCORE_STRIDE)
    truth = y_lin[rows]
    to_file = colour.processor(btf.working_space, btf.color_space, btf.ocio_config)
    depth = btf.bit_depth
    top = {"uint8": 255.0, "uint16": 65535.0}.get(depth, 1.0)
    truth_enc = _encoded(truth, to_file, depth, top)
    lin_total = float(np.abs(truth).sum(dtype=np.float64))
    enc_total = float(np.abs(truth_enc).sum(dtype=np.float64))
    scores, fits = {}, {}
    # One buffer each for the candidates' fitting and evaluation values (the curves run in
    # threads over rows; the same values as one call).
    x_dom, y_dom = np.empty_like(x_lin), np.empty_like(y_lin)
    for dom in candidates:
        fit = fit_basis(x_lin if dom.is_linear else rows_apply(dom.forward, x_lin, x_dom), k, options)
        u = fit.basis[:, :max(1, min(fit.k, _PROBE_K, S // _PROBE_FRACTION))]
        y = y_lin if dom.is_linear else rows_apply(dom.forward, y_lin, y_dom)
        rec = u[rows] @ (u.T @ y)
        rec = rows_apply(dom.inverse, rec, rec)
        e_lin = 100.0 * float(np.abs(rec - truth).sum(dtype=np.float64)) / max(lin_total, 1e-30)
        e_enc = 100.0 * float(np.abs(_encoded(rec, to_file, depth, top) - truth_enc).sum(dtype=np.float64)) \
            / max(enc_total, 1e-30)
        score = float(np.log(max(e_enc, 1e-9)) + np.log(max(e_lin, 1e-9)))
        scores[dom.name] = {"encoded": e_enc, "linear": e_lin, "score": score}
        fits[dom.name] = (dom, fit)
    return scores, fits


def _encoded(lin: np.ndarray, to_file, depth: str, top: float) -> np.ndarray:
    """(S, 3 m) working-space values -> the file's values normalised to [0, 1] (float32)."""
    shape = lin.shape

    def block(rows: np.ndarray) -> np.ndarray:
        codes = encode_for_file(rows.reshape(rows.shape[0], -1, 3), to_file, depth)
        return (codes.astype(np.float32) / np.float32(top)).reshape(rows.shape)

    return rows_apply(block, lin, np.empty(shape, np.float32))
