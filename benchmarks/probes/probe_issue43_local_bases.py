#!/usr/bin/env python
"""Issue 43, first probe: clustered local bases and per-texel k against today's one global basis.

No product change.  On paper-sampled synthetic data (90 views x 120 lights) at a small size, per
preset (tuning presets first, held-out presets reported apart and never used to choose anything):

* **paper**: the paper's method as the paper ran it (``research/methods.paper_cached``: k = 150
  SVD of the 8-bit values, JPEG q90 coefficients, 8-bit TIFF basis); its stored bytes B and its
  errors are the targets.
* **global** (a): one basis for every texel, the product's design re-implemented here so that all
  three methods share one quantiser and one byte count: a randomized SVD (K0 vectors) of every
  texel's apparent BRDF (R, G, B as columns) in a fixed working domain, colour PCA of the
  coefficients, one uniform coefficient step ``step``, basis column j at ``step / sigma_j``
  (``research/methods`` and the product's rule), the first k vectors kept.
* **local C** (b, C in --clusters): Mueller et al. 2003 local PCA. Texels are clustered in the
  global basis's coefficient space (k-means++ on the first --feature-k coefficients, then
  local-PCA reassignment: each texel to the cluster whose rank --refine-rank subspace leaves the
  least residual); each cluster gets its own basis (SVD of its texels' projected coefficients,
  so the cluster bases lie in the global K0-vector span: cheap, and a slight handicap to
  clustering); a texel's coefficients are in its cluster's basis; a cluster-index map is stored.
  How many vectors each cluster keeps: greedily by energy per byte, sigma_cj^2 / (a 3 n_c + b S),
  a and b = bytes per coefficient value and per basis value measured on the global method at the
  same step, the total number of vectors the knob.
* **per-texel k** (c): the global basis; texel t keeps its first k_t coefficients, k_t minimising
  tail_t(k) + mu k (tail = the energy of its dropped coefficients), the rest set to 0 before
  quantisation (a constant code, which the PNG pages compress); the vectors kept = max k_t.
  Knob: mu, for a cap K of 1 and 1.5 times the global method's k at the same target.

Bytes are counted as the packaged asset ships them (``usdbtf.compress.packs``): coefficient codes
in RGBA packs of four layers per colour channel, each pack encoded as the asset encodes a page
(8-bit: PNG level 6, the smaller of two filters; a 16-bit pack: OpenEXR zip), and the basis codes
group-major plus 2^23 as float32 OpenEXR zip in rows of 512 (``packs.basis_block_bytes``; each
cluster's block encoded alone and summed), plus for clustered bases the cluster-index map as an
8-bit grey PNG.  Per-vector scale/bias metadata (a few bytes per vector) is not counted for any
method.  The paper's bytes are its own files (JPEG + TIFF), as ``bench_issue16`` counts them.

For each method and each coefficient step of --steps, the knob is bisected twice: the largest
setting whose bytes fit B (then its error), and the smallest whose encoded AND linear errors are
both at or below the paper's (then its bytes).  The best over steps is reported: at B, the least
geometric mean of the two error ratios; at the paper's error, the fewest bytes.  Errors: percent
error over every --stride-th sample, all texels and channels, on the 8-bit sRGB file values and
in scene-linear ACEScg (``research/rlib.evaluate``).  CPU seconds = process time (all threads)
of the fit (basis, clustering, cluster bases) and of the whole search.

``--hybrid F,..``: for each C of --clusters, the first f x (the global's k at the same target, rounded
to whole groups of four) global vectors are shared by every texel and shipped once; each cluster adds its
own vectors fitted to what the shared ones leave (greedy by energy per byte, the knob their total).

Side measurements on the global configuration at the paper's error (its k and step):
``--separable R,..`` replaces each basis vector by its rank-r SVD as a views x lights matrix (half-float
factors counted raw, coefficients re-fitted by least squares in the global span); ``--basis-factors
F,..`` multiplies the basis steps by f and counts the basis codes both as today's EXR block and as one
16-bit RGBA PNG per group of four vectors laid out views x lights.

Usage::

    nice -n 19 .venv/bin/python benchmarks/probes/probe_issue43_local_bases.py \\
        [--presets metal_flakes,pebbles,crevice_stones] [--size 32] [--stride 12] [--clusters 2,4,8]
        [--steps 0.1,0.2,0.4] [--cap-factors 1,1.5] [--separable 2,4,8,16] [--basis-factors 1,2,4] [--hybrid 0.5]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_HERE = _Path(__file__).resolve().parent
_sys.path.insert(0, str(_HERE.parent / "research"))

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np  # noqa: E402

from rlib import OUT, evaluate, header, load, preset_list, say, stride_rows  # noqa: E402
from rlib import domain as get_domain  # noqa: E402
from methods import color_axes, paper_cached  # noqa: E402


# ----------------------------------------------------------------------------- representation


@dataclass
class Cluster:
    """One cluster's basis and coefficients (all in the working domain).

    texels : (n,) texel indices; u : (S, m) float32 orthonormal basis; coeff : (m, n, 3)
    float32 coefficients in the colour-PCA (stored) channels; energy : (m,) sigma_j^2.
    """

    texels: np.ndarray
    u: np.ndarray
    coeff: np.ndarray
    energy: np.ndarray


@dataclass
class Model:
    """Clusters of a texture (C = 1: the global basis), the colour rotation R (stored = domain @ R)."""

    clusters: list
    rot: np.ndarray
    P: int
    size: int
    S: int
    labels: np.ndarray
    seconds: float = 0.0
    info: dict = field(default_factory=dict)
    shared: int = 0             # the first ``shared`` vectors of every cluster are one basis, shipped once


def global_fit(x: np.ndarray, k0: int, seed: int = 0):
    """Randomized SVD of the domain values ``x`` (S, P, 3): basis (S, k0), coefficients (k0, P, 3)."""
    from usdbtf.compress.linalg import randomized_basis

    S, P, _ = x.shape
    u, sv, g = randomized_basis(x.reshape(S, -1), min(k0, S, 3 * P), power_iterations=1, seed=seed,
                                return_coefficients=True)
    return u, g.reshape(-1, P, 3)


def kmeans(features: np.ndarray, C: int, seed: int = 0, iterations: int = 20) -> np.ndarray:
    """Labels (n,) of k-means++ then Lloyd on ``features`` (n, d) float64; deterministic."""
    rng = np.random.default_rng(seed)
    n = len(features)
    centres = [features[rng.integers(n)]]
    d2 = ((features - centres[0]) ** 2).sum(axis=1)
    for _ in range(1, C):
        centres.append(features[rng.choice(n, p=d2 / d2.sum())])
        d2 = np.minimum(d2, ((features - centres[-1]) ** 2).sum(axis=1))
    centres = np.array(centres)
    labels = np.zeros(n, int)
    for _ in range(iterations):
        dist = (features ** 2).sum(1)[:, None] - 2 * features @ centres.T + (centres ** 2).sum(1)[None, :]
        labels = dist.argmin(axis=1)
        for c in range(C):
            if np.any(labels == c):
                centres[c] = features[labels == c].mean(axis=0)
    return labels


def _cluster_svd(g: np.ndarray, texels: np.ndarray):
    """SVD of the projected coefficients of ``texels``: (V (K0, m), sigma (m,), coefficients (m, n, 3))."""
    gc = g[:, texels, :].reshape(g.shape[0], -1).astype(np.float64)
    v, s, wt = np.linalg.svd(gc, full_matrices=False)
    v *= np.sign(v[np.argmax(np.abs(v), axis=0), np.arange(v.shape[1])])   # deterministic signs
    coeff = (v.T @ gc).reshape(len(s), len(texels), 3)
    return v, s, coeff


def local_labels(g: np.ndarray, C: int, feature_k: int, refine_rank: int, refine_iterations: int,
                 seed: int = 0) -> np.ndarray:
    """Cluster labels (P,): k-means++ on the first ``feature_k`` coefficients (x 3 channels) of each
    texel, then local-PCA reassignment (Mueller et al. 2003) to the cluster whose rank
    ``refine_rank`` subspace leaves the least residual energy."""
    K0, P, _ = g.shape
    feats = g[:feature_k].transpose(1, 0, 2).reshape(P, -1).astype(np.float64)
    labels = kmeans(feats, C, seed)
    g64 = g.astype(np.float64)
    norm2 = (g64 ** 2).sum(axis=(0, 2))
    for _ in range(refine_iterations):
        resid = np.empty((P, C))
        for c in range(C):
            texels = np.flatnonzero(labels == c)
            if len(texels) == 0:
                resid[:, c] = np.inf
                continue
            v = _cluster_svd(g, texels)[0][:, :refine_rank]
            proj = (v.T @ g64.reshape(K0, -1)).reshape(-1, P, 3)
            resid[:, c] = norm2 - (proj ** 2).sum(axis=(0, 2))
        new = resid.argmin(axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
    return labels


def build_model(u0: np.ndarray, g: np.ndarray, rot: np.ndarray, labels: np.ndarray, size: int) -> Model:
    """Per-cluster bases in the global span: U_c = U0 V_c."""
    clusters = []
    for c in range(labels.max() + 1):
        texels = np.flatnonzero(labels == c)
        v, s, coeff = _cluster_svd(g, texels)
        stored = (coeff.reshape(-1, 3) @ rot).reshape(coeff.shape).astype(np.float32)
        clusters.append(Cluster(texels, (u0.astype(np.float64) @ v).astype(np.float32), stored, s ** 2))
    return Model(clusters, rot, g.shape[1], size, u0.shape[0], labels)


def hybrid_model(u0: np.ndarray, g: np.ndarray, rot: np.ndarray, labels: np.ndarray, shared: int,
                 size: int) -> Model:
    """The first ``shared`` global vectors for every texel, then per cluster its own vectors fitted
    to what they leave (SVD of the cluster's remaining projected coefficients): a texel reads the
    shared block and its cluster's block."""
    head = g[:shared]
    e_head = (head.astype(np.float64) ** 2).sum(axis=(1, 2))
    clusters = []
    for c in range(labels.max() + 1):
        texels = np.flatnonzero(labels == c)
        v, s, coeff = _cluster_svd(g[shared:], texels)
        both = np.concatenate([head[:, texels].astype(np.float64), coeff])
        stored = (both.reshape(-1, 3) @ rot).reshape(both.shape).astype(np.float32)
        u = np.concatenate([u0[:, :shared], (u0[:, shared:].astype(np.float64) @ v).astype(np.float32)], axis=1)
        clusters.append(Cluster(texels, u, stored, np.concatenate([e_head, s ** 2])))
    return Model(clusters, rot, g.shape[1], size, u0.shape[0], labels, shared=shared)


# ----------------------------------------------------------------------------- storage


_PACK_BYTES: dict = {}


def _pack_bytes(pix: np.ndarray) -> int:
    """Shipped bytes of one (H, W, 4) pack (memoised on its content)."""
    from usdbtf.compress.packs import _encode_pack

    key = hashlib.sha1(pix.tobytes() + str(pix.dtype).encode()).hexdigest()
    if key not in _PACK_BYTES:
        _PACK_BYTES[key] = len(_encode_pack(pix))
    return _PACK_BYTES[key]


def quantise_basis(u: np.ndarray, energy: np.ndarray, step: float):
    """Codes (S, m) int64 and values (S, m) float32 of columns at ``step / sigma_j`` (capped at each
    column's span and at 16 bits; ``research/methods._basis_steps``)."""
    span = u.max(axis=0) - u.min(axis=0)
    steps = np.minimum(step / np.sqrt(np.maximum(energy, 1e-300)), np.where(span > 0, span, 1.0))
    steps = np.maximum(steps, span / (2 ** 16 - 2)).astype(np.float32)
    q = np.rint(u / steps).astype(np.int32)
    lo = q.min(axis=0)
    return q - lo, ((q - lo) * steps + lo * steps).astype(np.float32)


_BASIS_BYTES: dict = {}


def _group_block(codes: np.ndarray) -> np.ndarray:
    """Basis codes (S, n <= 4) as one group's texels (S, 4) float32 plus 2^23 (``packs``)."""
    from usdbtf.compress.packs import BASIS_CODE_OFFSET

    block = np.full((codes.shape[0], 4), BASIS_CODE_OFFSET, np.float32)
    block[:, :codes.shape[1]] = codes + BASIS_CODE_OFFSET
    return block


def exr_header_bytes(S: int) -> int:
    """What one more OpenEXR file costs beyond its data: the bytes of a constant block of S texels."""
    from usdbtf.compress.packs import BASIS_CODE_OFFSET, basis_block_bytes

    return basis_block_bytes(np.full((S, 4), BASIS_CODE_OFFSET, np.float32))


def basis_bytes(key, codes: np.ndarray, header: int) -> int:
    """Shipped bytes of basis codes (S, k) group-major plus 2^23 (``packs.basis_block_bytes``),
    as the sum of each group of four vectors encoded alone (memoised by ``key`` + group, so a
    bisection over k pays each group once) less ``header`` for every group but the first: the
    whole block's bytes within the check the run prints (:func:`check_basis_bytes`)."""
    from usdbtf.compress.packs import basis_block_bytes

    S, k = codes.shape
    total = 0
    for g in range(-(-k // 4)):
        n = min(4, k - 4 * g)
        gkey = (key, g, n)
        if gkey not in _BASIS_BYTES:
            _BASIS_BYTES[gkey] = basis_block_bytes(_group_block(codes[:, 4 * g:4 * g + n]))
        total += _BASIS_BYTES[gkey]
    return total - header * (-(-k // 4) - 1)


def check_basis_bytes(codes: np.ndarray, header: int) -> tuple[int, int]:
    """(summed-groups estimate, whole-block encode) of basis codes (S, k)."""
    from usdbtf.compress.packs import basis_block_bytes

    S, k = codes.shape
    whole = np.concatenate([_group_block(codes[:, 4 * g:4 * g + 4]) for g in range(-(-k // 4))])
    return basis_bytes(("check", codes.shape), codes, header), basis_block_bytes(whole)


@dataclass
class Stored:
    """A configuration as a reader sees it: per cluster the de-quantised basis (S, k_c) and
    coefficients (k_c, n_c * 3) in the domain's channels, and the bytes."""

    bases: list
    coeffs: list
    texels: list
    bytes: dict
    keep: list
    layers: int


class Encoder:
    """Quantises a :class:`Model` at a coefficient step for given per-cluster vector counts and
    optional per-texel cutoffs, counting shipped bytes."""

    def __init__(self, model: Model, step: float, tag: str):
        self.m, self.step, self.tag = model, step, tag
        self.bq = [quantise_basis(c.u, c.energy, step) for c in model.clusters]
        self.header = exr_header_bytes(model.S)

    def store(self, keep, cutoff=None) -> Stored:
        """keep: vectors per cluster; cutoff: (P,) per-texel k_t or None."""
        m, step = self.m, self.step
        L = max(int(max(keep)), 1)
        layers = np.zeros((L, m.P, 3), np.float32)
        for c, cl in zip(keep, m.clusters):
            layers[:c, cl.texels] = cl.coeff[:c]
        if cutoff is not None:
            layers[np.arange(L)[:, None] >= cutoff[None, :]] = 0.0
        q = np.rint(layers / np.float32(step)).astype(np.int64)
        lo = q.min(axis=1, keepdims=True)
        codes = q - lo
        values = (codes * step + lo * step).astype(np.float32)
        n = m.size
        coeff_bytes = 0
        for g in range(-(-L // 4)):
            part = codes[4 * g:4 * g + 4]
            dtype = np.uint8 if part.max() < 256 else np.uint16
            for ch in range(3):
                pix = np.zeros((n, n, 4), dtype)
                for j in range(len(part)):
                    pix[:, :, j] = part[j, :, ch].reshape(n, n)
                coeff_bytes += _pack_bytes(pix)
        h = m.shared
        bb = 0 if not h else basis_bytes((self.tag, step, "shared"), self.bq[0][0][:, :h], self.header)
        bb += sum(basis_bytes((self.tag, step, ci), self.bq[ci][0][:, h:c], self.header)
                  for ci, c in enumerate(keep) if c > h)
        index_bytes = 0
        if len(m.clusters) > 1:
            from usdbtf.imageio import encode_image

            index_bytes = len(encode_image(m.labels.reshape(n, n, 1).astype(np.uint8), "png", color_space="data",
                                           attributes={"png:compressionLevel": 6}))
        back = (values.reshape(-1, 3) @ m.rot.T).reshape(values.shape)        # stored -> domain channels
        bases, coeffs = [], []
        for c, cl, (_, bval) in zip(keep, m.clusters, self.bq):
            bases.append(bval[:, :c])
            coeffs.append(np.ascontiguousarray(back[:c, cl.texels].reshape(c, len(cl.texels) * 3)))
        total = coeff_bytes + bb + index_bytes
        return Stored(bases, coeffs, [cl.texels for cl in m.clusters],
                      {"payload": total, "coefficients": coeff_bytes, "basis": bb, "index": index_bytes},
                      [int(c) for c in keep], L)


def recon_fn(st: Stored, dom, P: int):
    """``recon(sel) -> (n, P, 3)`` linear Rec.709: per cluster basis rows . coefficients, inverse curve."""
    def recon(sel):
        out = np.zeros((len(sel), P, 3), np.float32)
        for b, c, t in zip(st.bases, st.coeffs, st.texels):
            if b.shape[1]:
                out[:, t, :] = (b[sel] @ c).reshape(len(sel), len(t), 3)
        return dom.inverse(out)
    return recon


# ----------------------------------------------------------------------------- search


def bisect_int(lo: int, hi: int, ok) -> int | None:
    """Largest n in [lo, hi] with ok(n), ok monotone (True then False); None if not ok(lo)."""
    if not ok(lo):
        return None
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if ok(mid):
            lo = mid
        else:
            hi = mid - 1
    return lo


def greedy_keep(model: Model, total: int, a: float, b: float) -> list:
    """Vectors per cluster: the ``total`` components of most energy per byte, sigma^2 / (a 3 n_c + b S)."""
    util, owner = [], []
    h = model.shared                              # shared vectors are always kept; the knob counts the rest
    for ci, cl in enumerate(model.clusters):
        util.append(cl.energy[h:] / (a * 3 * len(cl.texels) + b * model.S))
        owner.append(np.full(len(cl.energy) - h, ci))
    util, owner = np.concatenate(util), np.concatenate(owner)
    top = owner[np.argsort(-util, kind="stable")[:total]]
    return [h + int((top == ci).sum()) for ci in range(len(model.clusters))]


def per_texel_cutoff(model: Model, K: int, log_mu: float) -> np.ndarray:
    """(P,) k_t = argmin_k tail_t(k) + mu k over k <= K (the global model: one cluster)."""
    cl = model.clusters[0]
    e = (cl.coeff[:K].astype(np.float64) ** 2).sum(axis=2)                  # (K, P)
    tail = np.concatenate([np.cumsum(e[::-1], axis=0)[::-1], np.zeros((1, e.shape[1]))])   # (K+1, P)
    cost = tail + np.exp(log_mu) * np.arange(K + 1)[:, None]
    return cost.argmin(axis=0)


def cut_store(enc: "Encoder", model: Model, K: int, log_mu: float) -> Stored:
    """The global model with per-texel cutoffs (cap K), trailing all-zero vectors dropped."""
    cutoff = per_texel_cutoff(model, K, log_mu)
    return enc.store([max(1, int(cutoff.max()))], cutoff)


class Search:
    """Evaluates configurations (memoised) against the paper's bytes and errors."""

    def __init__(self, data, dom, sel, budget, target):
        self.data, self.dom, self.sel, self.budget, self.target = data, dom, sel, budget, target
        self.evals = 0

    def errors(self, st: Stored):
        self.evals += 1
        e = evaluate(self.data, recon_fn(st, self.dom, self.data.P), self.sel)
        return e.encoded, e.linear

    def meets(self, err) -> bool:
        return err[0] <= self.target[0] and err[1] <= self.target[1]

    def row(self, st: Stored, err) -> dict:
        return {"bytes": st.bytes, "encoded": err[0], "linear": err[1], "keep": st.keep, "layers": st.layers,
                "ratio": [err[0] / self.target[0], err[1] / self.target[1]],
                "x_budget": st.bytes["payload"] / self.budget}

    def at_bytes(self, make, lo, hi):
        """Largest knob in [lo, hi] whose bytes fit the budget: (its row) or None."""
        n = bisect_int(lo, hi, lambda n: make(n).bytes["payload"] <= self.budget)
        if n is None:
            return None
        st = make(n)
        return {**self.row(st, self.errors(st)), "knob": n}

    def at_error(self, make, lo, hi, quality_increases=True):
        """The knob of fewest bytes in [lo, hi] still meeting both target errors (bisection,
        errors taken as monotone in the knob): (its row) or None."""
        cache = {}

        def ok(n):
            if n not in cache:
                st = make(n)
                cache[n] = (st, self.errors(st))
            return self.meets(cache[n][1])
        if quality_increases:        # more knob = better: smallest n that meets -> bisect on -n
            n = bisect_int(-hi, -lo, lambda m: ok(-m))
            n = None if n is None else -n
        else:
            n = bisect_int(lo, hi, ok)
        if n is None:
            return None
        st, err = cache[n]
        return {**self.row(st, err), "knob": n}


def best_at_bytes(rows):
    rows = [r for r in rows if r]
    return min(rows, key=lambda r: np.log(r["ratio"][0]) + np.log(r["ratio"][1])) if rows else None


def best_at_error(rows):
    rows = [r for r in rows if r]
    return min(rows, key=lambda r: r["bytes"]["payload"]) if rows else None


def separable_basis(u: np.ndarray, sampling, rank: int) -> np.ndarray:
    """Each basis vector (S,) as a (views x lights) matrix cut to rank ``rank``, its factors
    rounded to half floats: (S, k) float32.  A renderer would rebuild a basis row from ``rank``
    view and light factors per vector instead of reading S codes."""
    vid = np.unique(sampling.view, axis=0, return_inverse=True)[1].ravel()
    lid = np.unique(sampling.light, axis=0, return_inverse=True)[1].ravel()
    out = np.empty_like(u)
    for j in range(u.shape[1]):
        m = np.zeros((vid.max() + 1, lid.max() + 1))
        m[vid, lid] = u[:, j]
        a, sv, bt = np.linalg.svd(m, full_matrices=False)
        fa = (a[:, :rank] * sv[:rank]).astype(np.float16).astype(np.float64)
        fb = bt[:rank].astype(np.float16).astype(np.float64)
        out[:, j] = (fa @ fb)[vid, lid]
    return out, int(vid.max() + 1 + lid.max() + 1)


def separable_rows(search, glob: Model, u0, g, sampling, row: dict, ranks, size: int) -> list:
    """The global configuration ``row`` (its k and step) with a rank-r separable basis (r in
    ``ranks``): coefficients re-fitted by least squares in the global span, quantised at the same
    step and counted as PNG packs; the basis counted as half-float factors, 2 bytes each."""
    out = []
    k, step = row["keep"][0], row["step"]
    for r in ranks:
        us, nvl = separable_basis(glob.clusters[0].u[:, :k], sampling, r)
        coef = np.linalg.lstsq(us.astype(np.float64), u0.astype(np.float64) @ g.reshape(g.shape[0], -1),
                               rcond=None)[0]                                  # (k, 3P) domain channels
        stored = (coef.reshape(-1, 3) @ glob.rot).reshape(k, -1, 3).astype(np.float32)
        m = Model([Cluster(np.arange(glob.P), us, stored, np.ones(k))], glob.rot, glob.P, size, glob.S,
                  np.zeros(glob.P, int))
        st = Encoder(m, step, f"separable{r}").store([k])
        st.bases[0] = us
        factor_bytes = 2 * k * r * nvl
        st.bytes = {"payload": st.bytes["coefficients"] + factor_bytes, "coefficients": st.bytes["coefficients"],
                    "basis": factor_bytes, "index": 0}
        out.append({**search.row(st, search.errors(st)), "rank": r, "step": step})
    return out


def basis_png_bytes(codes: np.ndarray, sampling) -> int:
    """Bytes of basis codes (S, k) as one 16-bit RGBA PNG per group of four vectors, each laid out
    views x lights (rows x columns), so PNG's filters see both directional neighbours: the
    codec alternative to today's group-major float32 OpenEXR zip rows (Storm reads 16-bit PNG)."""
    from usdbtf.compress.packs import encode_png_page

    vid = np.unique(sampling.view, axis=0, return_inverse=True)[1].ravel()
    lid = np.unique(sampling.light, axis=0, return_inverse=True)[1].ravel()
    total = 0
    for g in range(-(-codes.shape[1] // 4)):
        img = np.zeros((vid.max() + 1, lid.max() + 1, 4), np.uint16)
        part = codes[:, 4 * g:4 * g + 4]
        img[vid, lid, :part.shape[1]] = part
        total += len(encode_png_page(img))
    return total


def basis_codec_rows(search, glob: Model, sampling, row: dict, factors) -> list:
    """The global configuration ``row`` with its basis steps multiplied by each of ``factors``
    (coarser basis codes at the same coefficient step): error, bytes with today's EXR block, and
    the basis as 16-bit PNG views x lights (:func:`basis_png_bytes`)."""
    out = []
    k, step = row["keep"][0], row["step"]
    cl = glob.clusters[0]
    for f in factors:
        enc = Encoder(glob, step, f"basis{f}")
        enc.bq = [quantise_basis(cl.u, cl.energy / f ** 2, step)]           # step / sigma_j -> f step / sigma_j
        st = enc.store([k])
        png = basis_png_bytes(enc.bq[0][0][:, :k], sampling)
        r = {**search.row(st, search.errors(st)), "factor": f, "basis_png": png,
             "payload_png": st.bytes["coefficients"] + png, "x_budget_png": (st.bytes["coefficients"] + png)
             / search.budget}
        out.append(r)
    return out


# ----------------------------------------------------------------------------- main


def run_preset(preset: str, args) -> dict:
    from usdbtf.bench.datasets import HELDOUT_PRESETS

    res = {"held_out": preset in HELDOUT_PRESETS}
    _BASIS_BYTES.clear()              # its keys name a method, a step and a group, not a preset
    data = load(preset, "paper", args.size)
    sel = stride_rows(data, args.stride)
    paper = paper_cached(data)
    pe = evaluate(data, paper.recon, sel)
    budget = paper.bytes["payload"]
    res["paper"] = {"bytes": paper.bytes, "encoded": pe.encoded, "linear": pe.linear}
    say(f"## {preset}{' (held out)' if res['held_out'] else ''}: paper k 150: {budget:,} B "
        f"(basis {paper.bytes['basis']:,}, coefficients {paper.bytes['coefficients']:,}), {pe.row()}")
    dom = get_domain(args.domain)
    search = Search(data, dom, sel, budget, (pe.encoded, pe.linear))

    t0 = time.process_time()
    x = dom.code_table(data.lut)[np.asarray(data.codes)]                   # (S, P, 3) domain values
    u0, g = global_fit(x, args.k0)
    del x                                       # g = U0^T X: the later fits work in the global span
    rot = color_axes(g).astype(np.float64)
    glob = build_model(u0, g, rot, np.zeros(data.P, int), args.size)
    glob.seconds = time.process_time() - t0
    models = {"global": glob}
    for C in args.clusters:
        t = time.process_time()
        labels = local_labels(g, C, args.feature_k, args.refine_rank, args.refine_iterations)
        m = build_model(u0, g, rot, labels, args.size)
        m.seconds = glob.seconds + time.process_time() - t
        m.info["sizes"] = np.bincount(labels, minlength=C).tolist()
        models[f"local {C}"] = m
    say(f"  fit CPU s: " + ", ".join(f"{k} {m.seconds:.1f}" for k, m in models.items())
        + "; cluster sizes " + "; ".join(f"{k}: {m.info['sizes']}" for k, m in models.items() if m.info))

    out = {name: {"fit_cpu_s": m.seconds, "at_bytes": [], "at_error": []} for name, m in models.items()}
    out["per-texel k"] = {"fit_cpu_s": glob.seconds, "at_bytes": [], "at_error": []}
    for step in args.steps:
        t = time.process_time()
        enc_g = Encoder(glob, step, "global")
        kmax = glob.clusters[0].u.shape[1]
        make_g = lambda n: enc_g.store([n])                                # noqa: E731
        gb = search.at_bytes(make_g, 1, kmax)
        ge = search.at_error(make_g, 1, kmax)
        for r in (gb, ge):
            if r:
                r["step"] = step
        out["global"]["at_bytes"].append(gb)
        out["global"]["at_error"].append(ge)
        # bytes per coefficient value / per basis value at this step (the greedy rule's weights)
        ref = make_g(64)
        if step == args.steps[0]:
            est, whole = check_basis_bytes(enc_g.bq[0][0][:, :64], enc_g.header)
            res["basis_bytes_check"] = [est, whole]
            say(f"  basis bytes of 64 global vectors: summed groups {est:,}, one block {whole:,} "
                f"({100 * (est / whole - 1):+.2f} %)")
        a = ref.bytes["coefficients"] / (ref.layers * data.P * 3)
        b = ref.bytes["basis"] / (64 * data.S)
        for name, m in models.items():
            if name == "global":
                continue
            enc = Encoder(m, step, name)
            total = sum(len(c.energy) for c in m.clusters)
            make = lambda n, m=m, enc=enc: enc.store(greedy_keep(m, n, a, b))   # noqa: E731
            rows = (search.at_bytes(make, 1, total), search.at_error(make, 1, total))
            for r, key in zip(rows, ("at_bytes", "at_error")):
                if r:
                    r["step"] = step
                out[name][key].append(r)
        # shared + per-cluster vectors: the shared count a fraction of the global's k at the same target
        for frac in args.hybrid:
            for C, labels in ((C, models[f"local {C}"].labels) for C in args.clusters):
                for key, ref_row in (("at_bytes", gb), ("at_error", ge)):
                    if ref_row is None:
                        continue
                    h = max(4, 4 * int(round(frac * ref_row["knob"] / 4)))
                    hm = hybrid_model(u0, g, rot, labels, h, args.size)
                    enc = Encoder(hm, step, f"hybrid{C}-{h}")
                    total = sum(len(c.energy) - h for c in hm.clusters)
                    make = lambda n, hm=hm, enc=enc: enc.store(greedy_keep(hm, n, a, b))   # noqa: E731
                    r = search.at_bytes(make, 0, total) if key == "at_bytes" else search.at_error(make, 0, total)
                    if r:
                        r.update(step=step, shared=h)
                    out.setdefault(f"shared x{frac:g} + local {C}", {"fit_cpu_s": models[f"local {C}"].seconds,
                                                                     "at_bytes": [], "at_error": []})[key].append(r)
        # per-texel k: cap K at 1, 1.5, 2 x the global method's k for the same target; knob mu
        e0 = float(glob.clusters[0].energy.max())
        grid = np.linspace(np.log(e0 * 1e-12), np.log(e0 * 1e-2), 129)     # knob index -> log mu
        for key, ref_row in (("at_bytes", gb), ("at_error", ge)):
            if ref_row is None:
                continue
            for factor in args.cap_factors:
                K = min(kmax, int(round(ref_row["knob"] * factor)))
                make = lambda i, K=K: cut_store(enc_g, glob, K, grid[i])  # noqa: E731
                if key == "at_bytes":      # larger mu = fewer bytes: smallest i that fits
                    i = bisect_int(-(len(grid) - 1), 0, lambda j: make(-j).bytes["payload"] <= budget)
                    r = None
                    if i is not None:
                        st = make(-i)
                        r = {**search.row(st, search.errors(st)), "knob": -i}
                else:
                    r = search.at_error(make, 0, len(grid) - 1, quality_increases=False)
                if r:
                    r.update(step=step, cap=K, log_mu=float(grid[r["knob"]]))
                out["per-texel k"][key].append(r)
        say(f"  step {step}: {time.process_time() - t:.0f} CPU s, {search.evals} evaluations so far")
    if args.separable and best_at_error(out["global"]["at_error"]):
        rows = separable_rows(search, glob, u0, g, data.sampling, best_at_error(out["global"]["at_error"]),
                              args.separable, args.size)
        out["separable"] = rows
        for r in rows:
            say(f"  global at the paper's error, basis as rank-{r['rank']} view x light factors: "
                f"{r['bytes']['payload']:,} B = {r['x_budget']:.3f} B (factors {r['bytes']['basis']:,}, coeff "
                f"{r['bytes']['coefficients']:,}), {r['encoded']:.3f} / {r['linear']:.3f} %, ratio "
                f"{r['ratio'][0]:.3f} / {r['ratio'][1]:.3f}")
    if args.basis_factors and best_at_error(out["global"]["at_error"]):
        rows = basis_codec_rows(search, glob, data.sampling, best_at_error(out["global"]["at_error"]),
                                args.basis_factors)
        out["basis_codec"] = rows
        for r in rows:
            say(f"  global at the paper's error, basis steps x{r['factor']:g}: EXR block {r['bytes']['basis']:,} B, "
                f"16-bit PNG views x lights {r['basis_png']:,} B; total {r['x_budget']:.3f} B (EXR) / "
                f"{r['x_budget_png']:.3f} B (PNG); {r['encoded']:.3f} / {r['linear']:.3f} %, ratio "
                f"{r['ratio'][0]:.3f} / {r['ratio'][1]:.3f}")
    for name, o in out.items():
        if name in ("separable", "basis_codec") or (not o["at_bytes"] and not o["at_error"]):
            continue
        o["best_at_bytes"] = best_at_bytes(o["at_bytes"])
        o["best_at_error"] = best_at_error(o["at_error"])
        bb, be = o["best_at_bytes"], o["best_at_error"]
        say(f"  {name:12s}: at B: " + ("-" if not bb else
            f"{bb['bytes']['payload']:,} B, layers {bb['layers']} keep {bb['keep']}, {bb['encoded']:.3f} / "
            f"{bb['linear']:.3f} %, ratio {bb['ratio'][0]:.3f} / {bb['ratio'][1]:.3f} (step {bb['step']})")
            + " | at paper's error: " + ("not reached" if not be else
            f"{be['bytes']['payload']:,} B = {be['x_budget']:.3f} B (basis {be['bytes']['basis']:,}, "
            f"coeff {be['bytes']['coefficients']:,}, index {be['bytes']['index']:,}), layers {be['layers']} "
            f"keep {be['keep']} (step {be['step']})"))
    res["methods"] = out
    return res


def main(argv=None) -> int:
    from usdbtf.bench.datasets import HELDOUT_PRESETS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", default="metal_flakes,pebbles,crevice_stones")
    p.add_argument("--size", type=int, default=32)
    p.add_argument("--stride", type=int, default=12)
    p.add_argument("--domain", default="gamma2.2")
    p.add_argument("--k0", type=int, default=400, help="global basis vectors fitted (the span of every basis)")
    p.add_argument("--clusters", default="2,4,8")
    p.add_argument("--steps", default="0.1,0.2,0.4", help="coefficient quantisation steps (domain units)")
    p.add_argument("--cap-factors", default="1,1.5")
    p.add_argument("--feature-k", type=int, default=24)
    p.add_argument("--refine-rank", type=int, default=16)
    p.add_argument("--refine-iterations", type=int, default=4)
    p.add_argument("--separable", default="", help="ranks r: also the global at-error configuration with "
                   "each basis vector as a rank-r view x light matrix (e.g. 4,8,16)")
    p.add_argument("--basis-factors", default="", help="also the global at-error configuration with its "
                   "basis steps times each factor (e.g. 1,2,4), basis bytes as EXR and as 16-bit PNG")
    p.add_argument("--hybrid", default="", help="fractions f: also f x the global's k shared vectors plus "
                   "per-cluster vectors for each C of --clusters (e.g. 0.5,0.75)")
    p.add_argument("--json", default=str(OUT / "probe_issue43.json"))
    args = p.parse_args(argv)
    args.clusters = [int(c) for c in args.clusters.split(",") if c]
    args.steps = [float(s) for s in args.steps.split(",") if s]
    args.cap_factors = [float(s) for s in args.cap_factors.split(",") if s]
    args.separable = [int(s) for s in args.separable.split(",") if s]
    args.basis_factors = [float(s) for s in args.basis_factors.split(",") if s]
    args.hybrid = [float(s) for s in args.hybrid.split(",") if s]
    presets = preset_list(args.presets, tuning_only=False)
    presets = [x for x in presets if x not in HELDOUT_PRESETS] + [x for x in presets if x in HELDOUT_PRESETS]
    header("issue 43 probe: clustered local bases and per-texel k vs one global basis (shipped bytes)",
           [f"presets {', '.join(presets)}; held out (never tuned on): "
            f"{', '.join(x for x in presets if x in HELDOUT_PRESETS) or '-'}",
            f"sampling paper (90 views x 120 lights = 10,800 samples), {args.size}x{args.size}, 8-bit sRGB PNG, "
            "synth seed 0",
            f"errors over every {args.stride}-th sample, all texels and channels; encoded = 8-bit sRGB file values, "
            "linear = scene-linear ACEScg",
            "baseline = the paper's method (k 150 SVD of the 8-bit values, JPEG q90 + 8-bit TIFF), its bytes B",
            f"working domain {args.domain} for every method; K0 {args.k0}; steps {args.steps}; clusters "
            f"{args.clusters}; per-texel caps x{args.cap_factors}; k-means features {args.feature_k}, "
            f"refine rank {args.refine_rank} x {args.refine_iterations}",
            "bytes: PNG/EXR packs and EXR basis block as packaged (usdbtf.compress.packs), + 8-bit PNG index map"])
    t0 = time.process_time()
    results = {}
    for preset in presets:
        t = time.process_time()
        results[preset] = run_preset(preset, args)
        results[preset]["cpu_s"] = time.process_time() - t
        say(f"  preset CPU s {results[preset]['cpu_s']:.0f}")
        Path = _Path
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))
    say("\nB = the paper's bytes; ratio = error / the paper's error (encoded / linear); x B = bytes / B; "
        "CPU s = fit (basis + clustering)")
    say("\n| preset | method | at B: % enc / lin | at B: ratio enc / lin | at paper's error: bytes (x B) | "
        "basis / coeff / index bytes | layers | fit CPU s |")
    say("|" + "---|" * 8)
    for preset in presets:
        r = results[preset]
        name = ("**held out:** " if r["held_out"] else "") + preset
        pa = r["paper"]
        say(f"| {name} | paper k 150 | {pa['encoded']:.3f} / {pa['linear']:.3f} | 1 / 1 | {pa['bytes']['payload']:,} "
            f"(1) | {pa['bytes']['basis']:,} / {pa['bytes']['coefficients']:,} / - | 150 | - |")
        for method, o in r["methods"].items():
            if method in ("separable", "basis_codec") or (not o["at_bytes"] and not o["at_error"]):
                continue                                   # not run (per-texel k with --cap-factors "")
            bb, be = o["best_at_bytes"], o["best_at_error"]
            at_b = ("-", "-") if not bb else (f"{bb['encoded']:.3f} / {bb['linear']:.3f}",
                                              f"{bb['ratio'][0]:.3f} / {bb['ratio'][1]:.3f}")
            at_e = ("not reached", "-", "-") if not be else (
                f"{be['bytes']['payload']:,} ({be['x_budget']:.3f})",
                f"{be['bytes']['basis']:,} / {be['bytes']['coefficients']:,} / {be['bytes']['index']:,}",
                f"{be['layers']}")
            say(f"| {name} | {method} | {at_b[0]} | {at_b[1]} | {at_e[0]} | {at_e[1]} | {at_e[2]} | "
                f"{o['fit_cpu_s']:.1f} |")
    say(f"\ntotal CPU s {time.process_time() - t0:.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
