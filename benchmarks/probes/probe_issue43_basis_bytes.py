#!/usr/bin/env python
"""Issue 43, second probe: how small can the basis get at the paper's error, at paper scale?

No product change.  Per preset at the paper's scale (90 views x 120 lights = 10,800 samples, 128^2
texels, 8-bit sRGB; tuning presets first, held-out presets reported apart and never used to choose
anything), one global basis as the product builds it, stored several ways:

* **fit** (shared by every variant): randomized SVD (``usdbtf.compress.linalg.randomized_basis``, one
  power iteration) of --fit-texels random texels' apparent BRDFs (R, G, B as columns) in the working
  domain the product chose for the preset at the paper's bytes (its ``btf-compressed.json`` under
  --product), K0 vectors; every texel projected (float64 sums in float32 GEMMs); the colour PCA of the
  coefficients (``research/methods.color_axes``).  Cached per preset under --cache.
* **today** (f 1): the product's storage: one uniform coefficient step ``step`` for every stored
  coefficient, basis column j at step / sigma_j (``usdbtf.compress.quantise.basis_steps``: reverse
  water-filling, capped at the column's span and at 16 bits), the first k vectors.
* **(a) basis step factor f**: basis steps f x step / sigma_j, searched jointly with k and the
  coefficient step (f in --factors).
* **(c) 8-bit basis cap**: every column's step at least its span / 255 (one byte a code, the basis
  page's high-byte plane constant), else as today.
* **(b) per-vector low rank**: each basis vector as a views x lights matrix cut to the rank r_j at which
  its dropped energy sigma_j^2 (1 - sum_{r<r_j} s_jr^2) is at most --lowrank-tol x the quantisation
  error of that vector's coefficients (3 P step^2 / 12); factors stored as 16-bit codes
  (view factor s_jr a_jr at step / sigma_j, light factor b_jr at step / (sigma_j s_jr): the same
  water-filling), 16-bit PNG pages like the basis page; the coefficients re-fitted by least squares
  against the de-quantised low-rank basis before they are quantised.  Per-pixel work: sum_j r_j
  multiply-adds to rebuild a basis row (reported as mean r).
* **(b') low-rank tail**: (b) with each rank capped at HYBRID_RANK_CAP: a vector whose rank would pass it
  is stored full, as today, in a basis page of its own (counted beside the factors); per-pixel work at
  most the cap per vector (--hybrid-tol).
* **(d) JPEG basis**: the basis codes at a quarter of today's steps (at most 8 bits: a column's step at
  least its span / 255) as one grey JPEG of quality Q (--jpeg), each vector a views x lights tile; the
  loader's DCT decode is the transform coding of (b) at no per-pixel cost; error from the decoded file.
* **folded** (lossless, a layout question only): today's codes in the basis page with the low-byte
  plane reflected where the high byte is odd (low' = 255 - low), so a code crossing a multiple of 256
  does not jump by 255 in the low plane; bytes only (same values).

Bytes as the asset ships them: coefficient codes in RGBA packs of four layers per colour channel, each
pack as the asset encodes a page (``packs._encode_pack``: 8-bit PNG level 6, the smaller of two
filters; a 16-bit pack OpenEXR zip); the basis codes as ``gpu/basis.png`` itself
(``packs.basis_page`` + ``encode_png_page`` + the gAMA chunk, byte for byte what
``packs.shipped_basis_bytes`` counts).  What packaging adds besides (fallback maps, thumbnail, tables,
layers) is not in "payload"; the product's measured overhead at the paper's bytes
(``choice.asset.overhead``) is printed beside it, and "asset" = payload + that overhead.

Targets: the paper's method as the paper ran it (``research/methods.paper_cached``: k 150 SVD of the
8-bit values, JPEG q90 + 8-bit TIFF; bytes B as ``bench_issue16`` counts them) and its errors over the
same samples.  Errors: percent error over every --stride-th sample, every texel and channel, on the
8-bit sRGB file values (enc) and in scene-linear ACEScg (lin) (``research/rlib.evaluate``).  At the
paper's error: for every coefficient step of --steps, the fewest k whose enc AND lin errors are both at
or below the paper's (errors taken as monotone in k; bisection), the fewest payload bytes over steps.
At the paper's bytes: the largest k whose payload + the product's overhead fits B, the least geometric
mean of the two error ratios over steps.

Usage::

    nice -n 19 .venv/bin/python benchmarks/probes/probe_issue43_basis_bytes.py \\
        [--presets pebbles,...] [--stride 24] [--steps 0.5,0.7,1.0,1.4] [--factors 1,1.5,2] [--cap8 1]
        [--lowrank-tol 0.5,1,2] [--jpeg 90] [--no-at-bytes]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_HERE = _Path(__file__).resolve().parent
_sys.path.insert(0, str(_HERE.parent / "research"))

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np  # noqa: E402

from rlib import OUT, evaluate, header, load, say, stride_rows  # noqa: E402
from rlib import domain as get_domain  # noqa: E402
from methods import color_axes, paper_cached  # noqa: E402
from probe_issue43_local_bases import bisect_int  # noqa: E402

PRODUCT = Path("/work/snap755/benchmarks/out/issue16")
PRESETS = "pebbles,ridged_fabric,fuzzy_moss,metal_flakes,satin_weave,crevice_stones,velvet"


# ----------------------------------------------------------------------------- fit


def product_choice(preset: str, product: Path) -> dict:
    """The product's compress at the paper's bytes for ``preset``: its domain (an rlib name), k, step
    and the asset overhead it measured (bytes packaging adds beside pages and basis page)."""
    folder = next(p for p in sorted(product.glob(f"{preset}-128-asset_budget-*")) if p.is_dir()
                  and not p.name.endswith("-asset"))
    meta = json.loads((folder / "btf-compressed.json").read_text())
    d = meta["domain"]
    name = "srgb" if d["curve"] == "srgb" else ("linear" if d.get("gamma", 1) == 1 else f"gamma{d['gamma']:g}")
    return {"folder": str(folder), "domain": name, "k": meta["k"], "step": meta["choice"]["step"],
            "overhead": meta["choice"]["asset"]["overhead"], "bytes": meta["choice"]["bytes"]}


def fit(data, dom, k0: int, n_fit: int, cache: Path) -> dict:
    """Global basis U (S, k0) float32, stored-channel coefficients (k0, P, 3) float32, colour
    rotation R (3, 3) (stored = domain @ R) and sigma^2 (k0,) = each component's coefficient
    energy over every texel; cached in ``cache``."""
    if cache.is_file():
        z = np.load(cache)
        return {k: z[k] for k in z.files}
    from usdbtf.compress.linalg import randomized_basis

    t = time.process_time()
    table = dom.code_table(data.lut)
    rng = np.random.default_rng(0)
    sel = np.sort(rng.choice(data.P, size=min(n_fit, data.P), replace=False))
    x = table[np.asarray(data.codes[:, sel])].reshape(data.S, -1)                  # (S, 3 n)
    u, sv = randomized_basis(x, k0, power_iterations=1, seed=0)[:2]
    del x
    g = np.empty((k0, data.P, 3), np.float32)
    ut = np.ascontiguousarray(u.T)
    for a in range(0, data.P, 1024):
        b = min(a + 1024, data.P)
        xc = table[np.asarray(data.codes[:, a:b])].reshape(data.S, -1)
        g[:, a:b] = (ut @ xc).reshape(k0, b - a, 3)
    rot = color_axes(g)
    stored = (g.reshape(-1, 3) @ rot).reshape(g.shape).astype(np.float32)
    energy = np.einsum("kpc,kpc->k", stored, stored, dtype=np.float64)
    out = {"u": u, "coeff": stored, "rot": rot, "energy": energy, "fit_cpu_s": np.float64(time.process_time() - t)}
    cache.parent.mkdir(parents=True, exist_ok=True)
    tmp = cache.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    tmp.replace(cache)
    return out


# ----------------------------------------------------------------------------- storage


def png16_bytes(codes: np.ndarray) -> int:
    """Bytes of integer codes (rows, n) < 2^16 as the basis page stores codes: 8-bit RGBA PNG (level 6,
    smaller of two filters), four columns a texel, the high-byte image above the low-byte one, plus
    the asset's gAMA chunk.  For factor matrices (rows = views or lights)."""
    from usdbtf.compress.packs import PNG_DATA_CHUNK_BYTES, encode_png_page

    rows, n = codes.shape
    width = -(-n // 4)
    pad = np.zeros((rows, width * 4), np.int64)
    pad[:, :n] = codes
    img = np.concatenate([pad >> 8, pad & 255]).reshape(2 * rows, width, 4).astype(np.uint8)
    return len(encode_png_page(img)) + PNG_DATA_CHUNK_BYTES


def basis_page_bytes(codes: np.ndarray, views: int, lights: int, fold: bool = False) -> int:
    """``gpu/basis.png``'s bytes for basis codes (S, k) (``packs.basis_page``); ``fold``: the low
    byte reflected where the high byte is odd (a layout a reader would undo)."""
    from usdbtf.compress.packs import PNG_DATA_CHUNK_BYTES, basis_page, encode_png_page

    if fold:
        codes = np.where((codes >> 8) & 1, (codes & ~255) | (255 - (codes & 255)), codes)
    return len(encode_png_page(basis_page(codes, views, lights))) + PNG_DATA_CHUNK_BYTES


def quantise_columns(u: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(codes (S, k) int64 >= 0, de-quantised values (S, k) float32) at per-column ``steps``."""
    q = np.rint(u / steps.astype(np.float32)).astype(np.int64)
    lo = q.min(axis=0)
    return q - lo, (q * steps.astype(np.float32)).astype(np.float32)


class Coefficients:
    """Quantised coefficient layers at one step, with their pack bytes memoised per group of four."""

    def __init__(self, coeff: np.ndarray, step: float, size: int):
        self.coeff, self.step, self.size = coeff, step, size
        self.memo: dict = {}

    def layers(self, k: int, coeff: np.ndarray | None = None):
        """(values (k, P, 3) float32 de-quantised, bytes) of the first k layers (``coeff`` overrides
        the stored coefficients: re-fitted ones, never memoised)."""
        from usdbtf.compress.packs import _encode_pack

        c = (self.coeff if coeff is None else coeff)[:k]
        q = np.rint(c / np.float32(self.step)).astype(np.int64)
        lo = q.min(axis=1, keepdims=True)
        codes = q - lo
        total = 0
        for g in range(-(-k // 4)):
            key = (g, min(4, k - 4 * g))
            if coeff is None and key in self.memo:
                total += self.memo[key]
                continue
            part = codes[4 * g:4 * g + 4]
            n = 0
            for ch in range(3):
                dtype = np.uint8 if part[..., ch].max() < 256 else np.uint16
                pix = np.zeros((self.size, self.size, 4), dtype)
                for j in range(len(part)):
                    pix[:, :, j] = part[j, :, ch].reshape(self.size, self.size)
                n += len(_encode_pack(pix))
            if coeff is None:
                self.memo[key] = n
            total += n
        return (q * np.float32(self.step)).astype(np.float32), total


def basis_steps(u: np.ndarray, energy: np.ndarray, step: float, factor: float, cap8: bool) -> np.ndarray:
    """Per-column steps: the product's ``basis_steps(factor step, energy, u)``; ``cap8``: at least
    span / 255 (8-bit codes)."""
    from usdbtf.compress.quantise import basis_steps as product_steps

    steps = product_steps(factor * step, energy, u)
    if cap8:
        span = u.max(axis=0) - u.min(axis=0)
        steps = np.maximum(steps, np.where(span > 0, span / 255.0, steps))
    return steps


#: Variant (b'): a vector whose water-filled rank passes this stays a full row of the basis page.
HYBRID_RANK_CAP = 8

#: Variant (d) codes the basis at JPEG_FINE x today's steps (at most 8 bits) before JPEG, so the codec's
#: own error (a code or two at quality 90+) stays below today's quantisation step.
JPEG_FINE = 0.25


def jpeg_basis(u: np.ndarray, steps: np.ndarray, views: int, lights: int, quality: int):
    """Variant (d): 8-bit basis codes (``steps`` at least span / 255) as one grey JPEG (``quality``,
    libjpeg through OIIO), each vector a views x lights tile padded to whole 8-row blocks by repeating
    its last view, tiles stacked down: (codes (S, k), de-quantised values (S, k) float32 from the
    decoded file, bytes).  A loader decodes it: the shader reads texels as from the PNG page."""
    from usdbtf.imageio import decode_image, encode_image

    q = np.rint(u / steps.astype(np.float32)).astype(np.int64)
    lo = q.min(axis=0)
    codes = np.minimum(q - lo, 255)
    k = u.shape[1]
    rows = -(-views // 8) * 8
    tiles = codes.T.reshape(k, views, lights)
    tiles = np.concatenate([tiles, np.repeat(tiles[:, -1:], rows - views, axis=1)], axis=1)
    data = encode_image(tiles.reshape(k * rows, lights, 1).astype(np.uint8), "jpg", color_space="data",
                        attributes={"Compression": f"jpeg:{quality}"})
    back = decode_image(data)[..., 0].reshape(k, rows, lights)[:, :views].reshape(k, -1).T.astype(np.int64)
    return back, ((back + lo) * steps.astype(np.float32)).astype(np.float32), len(data)


def vl_matrices(u: np.ndarray, views: int, lights: int):
    """Per column of ``u`` (S, k), S view-major: SVD of its views x lights matrix:
    (a (k, V, m), s (k, m), b (k, m, L)), m = min(V, L)."""
    m = u.T.reshape(-1, views, lights).astype(np.float64)
    a, s, b = np.linalg.svd(m, full_matrices=False)
    return a, s, b


class LowRank:
    """Variant (b): per-vector low-rank views x lights basis, coefficients re-fitted."""

    def __init__(self, f: dict, views: int, lights: int, kmax: int):
        self.f, self.V, self.L = f, views, lights
        self.a, self.s, self.b = vl_matrices(f["u"][:, :kmax], views, lights)

    def store(self, k: int, step: float, tol: float, n_values: int, cap: int | None = None):
        """(basis values (S, k) float32, re-fitted stored coefficients (k, P, 3), factor bytes, ranks).
        ``cap``: a vector whose rank would pass it is stored full, as today (its codes in a basis page,
        counted with the factors; its rank reported as 1: one read a row)."""
        sigma2 = self.f["energy"][:k]
        budget = tol * n_values * step ** 2 / 12.0
        tail = sigma2[:, None] * (1.0 - np.cumsum(self.s[:k] ** 2, axis=1))       # dropped energy at rank r+1
        ranks = np.minimum((tail > budget).sum(axis=1) + 1, self.s.shape[1])
        full = ranks > cap if cap else np.zeros(k, bool)
        sig = np.sqrt(np.maximum(sigma2, 1e-300))
        cols_a, cols_b, steps_a, steps_b, owner = [], [], [], [], []
        for j in np.flatnonzero(~full):
            for r in range(ranks[j]):
                cols_a.append(self.a[j, :, r] * self.s[j, r])
                cols_b.append(self.b[j, r, :])
                steps_a.append(step / sig[j])
                steps_b.append(step / (sig[j] * max(self.s[j, r], 1e-12)))
                owner.append(j)
        nbytes, va, vb = 0, np.zeros((self.V, 0)), np.zeros((self.L, 0))
        if owner:
            A, B = np.array(cols_a).T, np.array(cols_b).T                            # (V, R), (L, R)
            ca, va = quantise_columns(A, np.minimum(np.array(steps_a), np.ptp(A, axis=0) + 1e-30))
            cb, vb = quantise_columns(B, np.minimum(np.array(steps_b), np.ptp(B, axis=0) + 1e-30))
            nbytes = png16_bytes(np.minimum(ca, 65535)) + png16_bytes(np.minimum(cb, 65535))
        if full.any():
            u = self.f["u"][:, :k][:, full]
            codes, whole = quantise_columns(u, basis_steps(u, sigma2[full], step, 1.0, False))
            nbytes += basis_page_bytes(codes, self.V, self.L)
        owner = np.array(owner)
        basis = np.zeros((self.V, self.L, k), np.float32)
        for j in np.flatnonzero(~full):
            cols = owner == j
            basis[:, :, j] = va[:, cols].astype(np.float64) @ vb[:, cols].T.astype(np.float64)
        basis = basis.reshape(-1, k)
        if full.any():
            basis[:, full] = whole
        ranks = np.where(full, 1, ranks)
        # least squares in the global span: C' = (Ut~ Ut)^-1 Ut~ U0 G, G = the unquantised coefficients
        u0 = self.f["u"].astype(np.float64)
        g = self.f["coeff"].reshape(self.f["coeff"].shape[0], -1).astype(np.float64)
        ub = basis.astype(np.float64)
        proj = np.linalg.solve(ub.T @ ub, ub.T @ u0)                                  # (k, K0)
        coeff = (proj @ g).astype(np.float32).reshape(k, -1, 3)
        return basis, coeff, nbytes, ranks


# ----------------------------------------------------------------------------- search


class Probe:
    """One preset: evaluates (variant, step, k) configurations, memoised."""

    def __init__(self, data, dom, f: dict, sel, target, budget_payload, views, lights):
        self.data, self.dom, self.f, self.sel = data, dom, f, sel
        self.target, self.budget_payload = target, budget_payload
        self.V, self.L = views, lights
        self.coeffs: dict = {}
        self.memo: dict = {}
        self.lowrank = None
        self.evals = 0

    def _coeff(self, step):
        if step not in self.coeffs:
            self.coeffs[step] = Coefficients(self.f["coeff"], step, self.data.size)
        return self.coeffs[step]

    def _build(self, variant: tuple, step: float, k: int):
        """(basis values (S, k), stored coefficient values (k, P, 3), row fields) of a configuration."""
        kind, param = variant
        f, u, energy = self.f, self.f["u"][:, :k], self.f["energy"][:k]
        if kind in ("lowrank", "hybrid"):
            if self.lowrank is None:
                self.lowrank = LowRank(f, self.V, self.L, f["u"].shape[1])
            basis, refit, bb, ranks = self.lowrank.store(k, step, param, 3 * self.data.P,
                                                         HYBRID_RANK_CAP if kind == "hybrid" else None)
            values, cb = self._coeff(step).layers(k, refit)
            extra = {"mean_rank": float(ranks.mean()), "max_rank": int(ranks.max())}
        elif kind == "jpeg":
            codes, basis, bb = jpeg_basis(u, basis_steps(u, energy, step, JPEG_FINE, True), self.V, self.L, int(param))
            values, cb = self._coeff(step).layers(k)
            extra = {}
        else:
            steps = basis_steps(u, energy, step, param, kind == "cap8")
            codes, basis = quantise_columns(u, steps)
            bb = basis_page_bytes(codes, self.V, self.L)
            values, cb = self._coeff(step).layers(k)
            extra = {"codes16": int((codes.max(axis=0) >= 256).sum())}
        return basis, values, {"k": k, "step": step, "variant": list(variant), "basis": bb, "coefficients": cb,
                               "payload": bb + cb, **extra}

    def config(self, variant: tuple, step: float, k: int, errors: bool = True) -> dict:
        """Bytes (and errors) of the first k vectors at coefficient ``step`` stored as ``variant``:
        ("factor", f) / ("cap8", 1) / ("lowrank", tol) / ("jpeg", quality).  Memoised without
        the arrays (a paper-scale configuration's coefficients are 63 MB)."""
        key = (variant, step, k)
        row = self.memo.get(key)
        if row is not None and (not errors or "encoded" in row):
            return row
        basis, values, row = self._build(variant, step, k)
        if errors:
            self.evals += 1
            back = (values.reshape(-1, 3) @ self.f["rot"].T.astype(np.float32)).reshape(k, -1)
            del values

            def recon(s):
                return self.dom.inverse(basis[s] @ back).reshape(len(s), self.data.P, 3)
            e = evaluate(self.data, recon, self.sel)
            row.update(encoded=e.encoded, linear=e.linear,
                       ratio=[e.encoded / self.target[0], e.linear / self.target[1]])
        self.memo[key] = row
        return row

    def meets(self, row) -> bool:
        return row["ratio"][0] <= 1.0 and row["ratio"][1] <= 1.0

    def at_error(self, variant, step, guess: int = 48):
        """Fewest k meeting both target errors (errors taken as monotone in k), or None: galloping
        up from ``guess`` by 1.25x to the first k that meets them (at most K0), then bisection
        below it."""
        kmax = self.f["u"].shape[1]
        lo, n = 3, max(4, min(guess, kmax))
        if self.meets(self.config(variant, step, n)):
            hi = n
            while hi > 4:                                  # gallop down to a k that fails
                m = max(4, int(hi / 1.25))
                if not self.meets(self.config(variant, step, m)):
                    lo = m
                    break
                hi = m
        else:
            lo = n
            while True:
                if n == kmax:
                    return None
                n = min(kmax, int(np.ceil(n * 1.25)))
                if self.meets(self.config(variant, step, n)):
                    hi = n
                    break
                lo = n
        while hi - lo > 1:                                 # lo fails (or is 3), hi meets
            mid = (lo + hi) // 2
            if self.meets(self.config(variant, step, mid)):
                hi = mid
            else:
                lo = mid
        return self.config(variant, step, hi)

    def at_bytes(self, variant, step, lo=4, hi=None):
        """Most k in [lo, hi] whose payload fits the budget (bisection on bytes), with its errors."""
        n = bisect_int(lo, hi or self.f["u"].shape[1],
                       lambda n: self.config(variant, step, n, errors=False)["payload"] <= self.budget_payload)
        return None if n is None else self.config(variant, step, n)


def run_preset(preset: str, args) -> dict:
    from usdbtf.bench.datasets import HELDOUT_PRESETS
    from usdbtf.compress.format import cross_layout

    t0 = time.process_time()
    prod = product_choice(preset, Path(args.product))
    data = load(preset, "paper", 128)
    views, lights = cross_layout(data.sampling)
    dom = get_domain(prod["domain"])
    sel = stride_rows(data, args.stride)
    paper = paper_cached(data)
    pe = evaluate(data, paper.recon, sel)
    B = paper.bytes["payload"]
    res = {"held_out": preset in HELDOUT_PRESETS, "paper": {"bytes": paper.bytes, "encoded": pe.encoded,
                                                             "linear": pe.linear}, "product_at_B": prod}
    f = fit(data, dom, args.k0, args.fit_texels, Path(args.cache) / f"{preset}-k{args.k0}-{prod['domain']}.npz")
    say(f"## {preset}{' (held out)' if res['held_out'] else ''}: paper k 150 {B:,} B (basis "
        f"{paper.bytes['basis']:,}), {pe.row()} over {len(sel)} samples; domain {prod['domain']} (the product's "
        f"choice); product overhead at B {prod['overhead']:,} B = {prod['overhead'] / B:.3f} B; fit "
        f"{float(f['fit_cpu_s']):.0f} CPU s")
    probe = Probe(data, dom, f, sel, (pe.encoded, pe.linear), B - prod["overhead"], views, lights)
    variants = [("factor", x) for x in args.factors] + [("cap8", 1.0)] * args.cap8 + \
        [("lowrank", t) for t in args.lowrank_tol] + [("hybrid", t) for t in args.hybrid_tol] + \
        [("jpeg", int(q)) for q in args.jpeg]
    out = {}
    for v in variants:
        name = f"{v[0]} {v[1]:g}"
        t = time.process_time()
        at_e, guess = [], 48
        for s in args.steps:                   # a coarser step needs more vectors: start from the last k
            at_e.append(probe.at_error(v, s, guess))
            guess = at_e[-1]["k"] if at_e[-1] else guess
        # at B: not for the low-rank variants (every byte count re-fits the coefficients)
        at_b = [probe.at_bytes(v, s) for s in args.steps] if not args.no_at_bytes and v[0] in (
            "factor", "cap8", "jpeg") else []
        be = min((r for r in at_e if r), key=lambda r: r["payload"], default=None)
        bb = min((r for r in at_b if r), key=lambda r: np.log(r["ratio"][0]) + np.log(r["ratio"][1]), default=None)
        out[name] = {"at_error": be, "at_bytes": bb, "cpu_s": time.process_time() - t, "by_step": at_e}
        say(f"  {name:11s}: at paper's error " + ("not reached" if not be else
            f"k {be['k']} step {be['step']:g}: {be['payload']:,} B = {be['payload'] / B:.3f} B (basis "
            f"{be['basis']:,} = {be['basis'] / B:.3f} B, coeff {be['coefficients']:,}); + overhead "
            f"{(be['payload'] + prod['overhead']) / B:.3f} B; ratio {be['ratio'][0]:.3f} / {be['ratio'][1]:.3f}"
            + (f"; mean rank {be['mean_rank']:.1f}" if "mean_rank" in be else ""))
            + (" | at B: " + ("-" if not bb else f"k {bb['k']} step {bb['step']:g} ratio {bb['ratio'][0]:.3f} / "
                              f"{bb['ratio'][1]:.3f}") if at_b else "")
            + f"  [{time.process_time() - t:.0f} CPU s]")
    today = out.get("factor 1", {}).get("at_error")
    if today:
        row = probe.config(("factor", 1.0), today["step"], today["k"])
        codes, _ = quantise_columns(f["u"][:, :today["k"]], basis_steps(f["u"][:, :today["k"]],
                                                                         f["energy"][:today["k"]], today["step"], 1.0,
                                                                         False))
        folded = basis_page_bytes(codes, views, lights, fold=True)
        from usdbtf.compress.packs import PNG_DATA_CHUNK_BYTES, basis_page, encode_png_page

        page = basis_page(codes, views, lights)
        low = page[(np.arange(page.shape[0]) // views) % 2 == 1]              # the low-byte rows only
        res["low_plane_only"] = len(encode_png_page(low)) + PNG_DATA_CHUNK_BYTES
        say(f"  the same codes with no high-byte plane (8-bit page): {res['low_plane_only']:,} B "
            f"({100 * (res['low_plane_only'] / row['basis'] - 1):+.1f} %); codes >= 256: {row.get('codes16')}")
        res["folded"] = {"k": today["k"], "step": today["step"], "basis": row["basis"], "folded": folded}
        say(f"  folded low bytes (today's codes at the paper's error, k {today['k']}): basis page "
            f"{row['basis']:,} -> {folded:,} B ({100 * (folded / row['basis'] - 1):+.1f} %)")
    res["variants"] = out
    res["cpu_s"] = time.process_time() - t0
    res["evals"] = probe.evals
    return res


def numbers(text: str) -> list:
    """A comma-separated list of numbers (argparse type)."""
    return [float(x) for x in text.split(",") if x]


def main(argv=None) -> int:
    from usdbtf.bench.datasets import HELDOUT_PRESETS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", default=PRESETS)
    p.add_argument("--stride", type=int, default=24)
    p.add_argument("--k0", type=int, default=320)
    p.add_argument("--fit-texels", type=int, default=4096)
    p.add_argument("--steps", type=numbers, default="0.5,0.7,1.0,1.4")
    p.add_argument("--factors", type=numbers, default="1")
    p.add_argument("--cap8", type=int, default=0)
    p.add_argument("--lowrank-tol", type=numbers, default="1")
    p.add_argument("--hybrid-tol", type=numbers, default="", help="low-rank tolerances of variant (b'): "
                   "ranks capped at HYBRID_RANK_CAP, a vector past it kept full")
    p.add_argument("--jpeg", type=numbers, default="90", help="JPEG qualities for variant (d), e.g. 85,95")
    p.add_argument("--no-at-bytes", action="store_true")
    p.add_argument("--table", default="", help="only print the table of these result files (comma-separated "
                   "--json outputs of earlier runs, later files adding variants)")
    p.add_argument("--product", default=str(PRODUCT))
    p.add_argument("--cache", default=str(OUT / "probe_issue43_basis"))
    p.add_argument("--json", default=str(OUT / "probe_issue43_basis_bytes.json"))
    args = p.parse_args(argv)
    if args.table:
        merged: dict = {}
        for path in args.table.split(","):
            for preset, r in json.loads(Path(path).read_text()).items():
                if preset in merged:
                    merged[preset]["variants"].update(r["variants"])
                else:
                    merged[preset] = r
        order = [x for x in PRESETS.split(",") if x in merged]
        table(merged, [x for x in order if not merged[x]["held_out"]] + [x for x in order if merged[x]["held_out"]])
        return 0
    presets = [x for x in args.presets.split(",") if x]
    presets = [x for x in presets if x not in HELDOUT_PRESETS] + [x for x in presets if x in HELDOUT_PRESETS]
    header("issue 43 probe: basis bytes at the paper's error (paper scale, shipped bytes)",
           [f"presets {', '.join(presets)}; held out (never tuned on): "
            f"{', '.join(x for x in presets if x in HELDOUT_PRESETS) or '-'}",
            "sampling paper (90 views x 120 lights = 10,800 samples), 128x128, 8-bit sRGB PNG, synth seed 0",
            f"errors over every {args.stride}-th sample, all texels and channels; enc = 8-bit sRGB file values, "
            "lin = scene-linear ACEScg",
            "baseline = the paper's method (k 150 SVD of the 8-bit values, JPEG q90 + 8-bit TIFF), its bytes B; "
            "today = the product's storage re-run in this probe",
            f"K0 {args.k0} from {args.fit_texels} fit texels; steps {args.steps}; basis step factors {args.factors}; "
            f"cap8 {bool(args.cap8)}; low-rank tol {args.lowrank_tol}",
            "payload = coefficient packs (PNG/EXR as packaged) + gpu/basis.png (or low-rank factor PNGs)"])
    results = {}
    if Path(args.json).is_file():
        results = json.loads(Path(args.json).read_text())
    for preset in presets:
        results[preset] = run_preset(preset, args)
        say(f"  preset CPU s {results[preset]['cpu_s']:.0f}, {results[preset]['evals']} evaluations")
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(results, indent=1, default=float))
    table(results, [x for x in presets])
    return 0


def table(results: dict, presets: list) -> None:
    """The markdown table: per preset and variant, bytes at the paper's error and error at B."""
    columns = ("preset", "variant", "at paper's error: k, step", "payload x B", "basis x B", "asset x B",
               "ratio enc / lin", "at B: k, ratio enc / lin")
    say("\nB = the paper's bytes; x B = payload / B (asset = payload + the product's overhead at B); ratio = "
        "error / the paper's error (enc / lin)\n\n| " + " | ".join(columns) + " |\n|" + "---|" * len(columns))
    for preset in presets:
        r = results[preset]
        B = r["paper"]["bytes"]["payload"]
        name = ("**held out:** " if r["held_out"] else "") + preset
        for v, o in r["variants"].items():
            e, b = o["at_error"], o["at_bytes"]
            extra = f", r {e['mean_rank']:.1f}" if e and "mean_rank" in e else ""
            at_e = ("not reached", "-", "-", "-", "-") if not e else (
                f"{e['k']}, {e['step']:g}{extra}", f"{e['payload'] / B:.3f}", f"{e['basis'] / B:.3f}",
                f"{(e['payload'] + r['product_at_B']['overhead']) / B:.3f}",
                f"{e['ratio'][0]:.3f} / {e['ratio'][1]:.3f}")
            at_b = "-" if not b else f"{b['k']}, {b['ratio'][0]:.3f} / {b['ratio'][1]:.3f}"
            say(f"| {name} | {v} | " + " | ".join(at_e) + f" | {at_b} |")


if __name__ == "__main__":
    raise SystemExit(main())
