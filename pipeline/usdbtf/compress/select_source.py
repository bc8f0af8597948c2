"""The load step: which source answers compress's questions about one input.

Three kinds answer them the same way, bit for bit: the images decoded in this process
(:mod:`.source`: in memory or streamed), a Dask cluster decoding them (:mod:`.distributed`),
or a factorised input's own factors (:mod:`.factored`).  This module only chooses; it sits
above all three so that none of them imports another's chooser.
"""
from __future__ import annotations

import logging
from ..model import BTF
from .curve import curve_samples
from .factored import FactoredSource, uses_factors
from .fit import every_texel, every_texel_panel_bytes
from .options import CompressOptions
from .source import choose_source
from .texels import Texels

log = logging.getLogger(__name__)

__all__ = ["load_source"]


def load_source(btf: BTF, texels: Texels, options: CompressOptions):
    """The load step: where one compress reads its data from (:func:`choose_source`, or a
    Dask cluster when ``options.dask`` names one: :mod:`.distributed`).

    Parameters
    ----------
    btf : the BTF; its files are decoded (all at once, or streamed in chunks).
    texels : the fitting and evaluation texels, whose columns a streaming source keeps on its
        first pass (with the error curve's sample rows, :func:`.curve.curve_samples`).
    options : ``memory_budget`` (bytes of stored values and the fit's working set held in
        memory, else the values are streamed),
        ``chunk_bytes``, ``workers``, ``spill``, ``dask``, ``progress``.

    Returns
    -------
    A source (a context manager: close it, or use ``with``) that answers ``columns``
    (S, 3 n), ``project`` and ``working_samples`` (r, P, 3) the same way, bit for bit.  An
    input that exposes a factorisation gets a :class:`~.factored.FactoredSource` instead
    (unless ``options.expand_factors``): the same questions, answered from the factors, in
    this process even with ``options.dask`` (the factors are small and the transcoding
    decodes no images; the bytes are those of a run without ``--dask``).
    """
    if uses_factors(btf, options) and options.domain in ("auto", "linear"):   # the algebra is linear-only
        if options.dask:
            log.info("transcoding from the input's factors in this process (--dask is for decoding images)")
        return FactoredSource(btf, options)
    keep = [texels.fit, texels.evaluation] + ([] if texels.in_sample is None else [texels.in_sample])
    rows = curve_samples(btf.n_samples)
    if options.dask:
        from .distributed import DaskSource

        return DaskSource(btf, keep, rows, options)
    # The fit's columns as float32, and its float64 panels (S + 3n) x (k + oversample), two at
    # once, are held beside the stored values: a budget's 4096 fitting texels and 500 vectors
    # (paper scale: 0.53 + 0.27 GB) stream the input where a plain k's 2048 texels and 150
    # vectors (0.27 + 0.05 GB) keep it in memory (issue 27: no mode holds more than --k does).
    S, n = btf.n_samples, len(texels.fit)
    panel = options.fit_k(S, btf.n_pixels) + options.oversample
    fit_columns = S * 3 * n * 4 + 2 * (S + 3 * n) * panel * 8
    if every_texel(options, n, btf.n_pixels, S):
        # A fit over every texel (.fit.streamed_fit) holds no columns, but panels of every texel.
        fit_columns = every_texel_panel_bytes(options, S, btf.n_pixels)
    return choose_source(btf, keep, rows, memory_budget=options.memory_budget, workers=options.workers,
                         chunk_bytes=options.chunk_bytes, spill=options.spill, beside=fit_columns)
