#!/usr/bin/env python
"""Issue 43: how far the shipped pages are from what an entropy coder tuned to the coefficient
statistics could reach on the same codes (the issue's "entropy coding tuned to coefficient
statistics" direction, measured as a ceiling before anyone builds a codec for it).

For each compressed folder (``usdbtf compress ... --target-error E``: the codes the packaged
asset ships in its pages, bit for bit), the probe counts

- **shipped**: each coefficient pack encoded on its own exactly as the asset encodes a page
  (``packs.shipped_pack_bytes``: 8-bit RGBA PNG, adaptive rows and run-length deflate; 16-bit
  packs OpenEXR zip), and the basis as the asset ships it (``packs.shipped_basis_bytes``);
- the **code length of an adaptive arithmetic coder** on the same integer codes, one plane
  (layer j, colour channel c, H x W) after another in the order a decoder would need them,
  each plane's statistics learnt from scratch (Krichevsky-Trofimov counts with the smallest
  of three pseudo-counts 1/32, 1/8, 1/2 per plane: two bits of side information), plus each
  plane's alphabet (two bytes a symbol).  Models, from the least to the most context:

  - ``order0``: the codes as they are;
  - ``med``: the residual of LOCO-I's median edge predictor (JPEG-LS) from the west, north and
    north-west codes, no context;
  - ``ctx``: the code minus the plane's zero code (the code whose value is 0), conditioned on
    (the summed magnitudes of the causal neighbours W, N, NW, NE in 6 classes) x (the magnitude
    of the same texel in the previous layer of the same channel, 4 classes) x (for channels 1
    and 2: the magnitude of channel 0 of this layer at the texel, 3 classes): 72 contexts;
  - ``med_ctx``: the ``med`` residual in the ``ctx`` contexts (JPEG-LS's way: a prediction,
    and its residual's statistics by the neighbourhood's activity);
  - ``best``: per plane the smallest of the four (a real coder would signal the choice).

  The basis codes get the same models on each vector's views x lights image (view-major rows:
  ``packs.basis_page``'s layout), the previous vector's magnitude as the cross-layer context.

An adaptive coder's code length is achievable to within a few bytes a plane (arithmetic coding),
so ``best`` is what a custom codec could ship for these codes; ``shipped / best`` is the most that
entropy coding alone could take off the pages.  No renderer reads such a codec (Storm reads PNG,
JPEG and EXR): the ceiling says whether building one, with a transcode at load, could matter.

Usage (repository root)::

    .venv/bin/python benchmarks/probes/probe_issue43_code_entropy.py FOLDER [FOLDER ...] [--json OUT]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform)
import numpy as np  # noqa: E402

from common import print_header  # noqa: E402

PSEUDO_COUNTS = (1 / 32, 1 / 8, 1 / 2)
MODELS = ("order0", "med", "ctx", "med_ctx", "best")
ALPHABET_BYTES = 2


def _rank_within_groups(keys: np.ndarray) -> np.ndarray:
    """(N,) int64: for each position, how many earlier positions hold the same key."""
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    starts = np.r_[0, np.flatnonzero(np.diff(sorted_keys)) + 1]
    group_start = np.repeat(starts, np.diff(np.r_[starts, len(keys)]))
    ranks = np.empty(len(keys), np.int64)
    ranks[order] = np.arange(len(keys)) - group_start
    return ranks


def adaptive_bits(symbols: np.ndarray, contexts: np.ndarray | None = None) -> float:
    """Bits an adaptive arithmetic coder spends on ``symbols`` (N,) int in this order, each
    coded with the counts of the earlier symbols in its context (``contexts`` (N,) int, default
    one context): Krichevsky-Trofimov estimate with the best of :data:`PSEUDO_COUNTS`, plus
    the alphabet (:data:`ALPHABET_BYTES` a distinct symbol) and 2 bits for the choice."""
    symbols = np.asarray(symbols).ravel()
    contexts = np.zeros(len(symbols), np.int64) if contexts is None else np.asarray(contexts, np.int64).ravel()
    alphabet, index = np.unique(symbols, return_inverse=True)
    size = len(alphabet)
    seen_pair = _rank_within_groups(contexts * size + index).astype(np.float64)
    seen_context = _rank_within_groups(contexts).astype(np.float64)
    best = min(float(-np.log2((seen_pair + a) / (seen_context + a * size)).sum()) for a in PSEUDO_COUNTS)
    return best + 8 * ALPHABET_BYTES * size + 2


def med_residual(codes: np.ndarray) -> np.ndarray:
    """(H, W) int64: ``codes`` minus LOCO-I's median edge prediction from W, N, NW (0 outside)."""
    x = codes.astype(np.int64)
    pad = np.pad(x, ((1, 0), (1, 0)))
    west, north, northwest = pad[1:, :-1], pad[:-1, 1:], pad[:-1, :-1]
    hi, lo = np.maximum(west, north), np.minimum(west, north)
    pred = np.where(northwest >= hi, lo, np.where(northwest <= lo, hi, west + north - northwest))
    return x - pred


def _classes(values: np.ndarray, edges) -> np.ndarray:
    return np.searchsorted(np.asarray(edges), values, side="right")


def neighbour_magnitude(mag: np.ndarray) -> np.ndarray:
    """(H, W) int64: |W| + |N| + |NW| + |NE| magnitudes of the causal neighbours (0 outside)."""
    pad = np.pad(mag, ((1, 0), (1, 1)))
    return pad[1:, :-2] + pad[:-1, 1:-1] + pad[:-1, :-2] + pad[:-1, 2:]


NEIGHBOUR_EDGES = (0, 2, 4, 8, 16)     # 6 classes: 0, 1-2, 3-4, 5-8, 9-16, 17+
PREVIOUS_EDGES = (0, 1, 3)             # 4 classes: 0, 1, 2-3, 4+
CHANNEL0_EDGES = (0, 2)                # 3 classes: 0, 1-2, 3+


def plane_bits(codes: np.ndarray, zero: int, previous: np.ndarray | None,
               channel0: np.ndarray | None) -> dict:
    """{"order0", "med", "ctx", "med_ctx", "best"} bits of one (H, W) plane of integer codes whose value-0
    code is ``zero``; ``previous`` / ``channel0`` (H, W) magnitudes of the cross-layer and
    cross-channel neighbours (None: that context is absent)."""
    signed = codes.astype(np.int64) - zero
    mag = np.abs(signed)
    ctx = _classes(neighbour_magnitude(mag), NEIGHBOUR_EDGES)
    if previous is not None:
        ctx = ctx * 4 + _classes(previous, PREVIOUS_EDGES)
    if channel0 is not None:
        ctx = ctx * 3 + _classes(channel0, CHANNEL0_EDGES)
    residual = med_residual(codes)
    out = {"order0": adaptive_bits(codes), "med": adaptive_bits(residual),
           "ctx": adaptive_bits(signed, ctx), "med_ctx": adaptive_bits(residual, ctx)}
    out["best"] = min(out.values())
    return out


def coefficient_bits(cbtf) -> dict:
    """Summed :func:`plane_bits` over every coefficient plane, in decoding order."""
    totals = dict.fromkeys(MODELS, 0.0)
    previous = [None, None, None]
    for st in cbtf.coefficients:
        zeros = np.rint(-np.asarray(st.bias, np.float64) / np.asarray(st.scale, np.float64)).astype(np.int64)
        mags = []
        for c in range(3):
            codes = st.pixels[:, :, c]
            bits = plane_bits(codes, int(zeros[c]), previous[c], mags[0] if c else None)
            for key in totals:
                totals[key] += bits[key]
            mags.append(np.abs(codes.astype(np.int64) - zeros[c]))
        previous = mags
    return totals


def basis_bits(cbtf) -> dict | None:
    """Summed :func:`plane_bits` over the basis vectors as views x lights images (None when
    the basis is not integer codes on a cross sampling)."""
    from usdbtf.compress.format import cross_layout

    layout = cross_layout(cbtf.sampling)
    if layout is None or cbtf.basis.pixels.dtype.kind != "u":
        return None
    views, lights = layout
    totals = dict.fromkeys(MODELS, 0.0)
    previous = None
    for j in range(cbtf.k):
        codes = cbtf.basis.pixels[:, j, 0].reshape(views, lights)
        zero = int(np.rint(-float(cbtf.basis.bias[j]) / float(cbtf.basis.scale[j])))
        bits = plane_bits(codes, zero, previous, None)
        for key in totals:
            totals[key] += bits[key]
        previous = np.abs(codes.astype(np.int64) - zero)
    return totals


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", type=Path, help="compressed BTF folders")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args(argv)

    from usdbtf.compress import packs
    from usdbtf.compress.format import read_compressed

    print_header("# issue 43: shipped pages against an adaptive coder's code length on the same codes")
    rows = []
    for folder in args.folders:
        t0 = time.perf_counter()
        cbtf = read_compressed(folder)
        pack_bytes = int(sum(packs.shipped_pack_bytes(cbtf)))
        basis_bytes = int(packs.shipped_basis_bytes(cbtf))
        coeff = {key: bits / 8 for key, bits in coefficient_bits(cbtf).items()}
        basis = basis_bits(cbtf)
        basis = None if basis is None else {key: bits / 8 for key, bits in basis.items()}
        row = {"folder": str(folder), "k": cbtf.k, "texels": cbtf.width * cbtf.height, "samples": cbtf.n_samples,
               "coefficient_dtypes": sorted({str(st.pixels.dtype) for st in cbtf.coefficients}),
               "pack_bytes": pack_bytes, "basis_bytes": basis_bytes, "coefficients": coeff, "basis": basis,
               "seconds": round(time.perf_counter() - t0, 1)}
        rows.append(row)
        b = "-" if basis is None else f"{basis['best']:,.0f} ({basis_bytes / basis['best']:.2f}x)"
        print(f"{folder}: k {cbtf.k}; packs {pack_bytes:,} B shipped, order0 {coeff['order0']:,.0f}, "
              f"med {coeff['med']:,.0f}, ctx {coeff['ctx']:,.0f}, med_ctx {coeff['med_ctx']:,.0f}, best {coeff['best']:,.0f} "
              f"(shipped / best {pack_bytes / coeff['best']:.3f}); basis {basis_bytes:,} B shipped, best {b}; "
              f"{row['seconds']} s", flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
