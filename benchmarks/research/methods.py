"""The methods the research scripts compare: the paper's, as the paper ran it, and the
prototype factorisations (issue 16).  See ``rlib`` for the data and the error definitions.

A method returns a :class:`Factorised`: the de-quantised basis and coefficients exactly as
a reader of its stored files would see them, the working domain's curve, and the stored
bytes (every file encoded for real).  ``Factorised.recon`` is what a renderer computes:
basis row . coefficients in the domain, then the inverse curve.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rlib import Data, Domain, domain as get_domain, encode_bytes

__all__ = ["Factorised", "paper_method", "fit_texels", "project", "color_axes", "Storage", "uniform_store",
           "factorise", "parse_config", "run_config"]

#: The paper's storage as usdbtf's --solver paper writes it: JPEG q90 4:4:4 coefficients,
#: an uncompressed 8-bit TIFF basis.
PAPER_JPEG = {"Compression": "jpeg:90", "jpeg:subsampling": "4:4:4"}
PAPER_TIFF = {"compression": "none"}


@dataclass
class Factorised:
    """A stored BTF as its reader sees it.

    basis : (S, k) float32 de-quantised basis; coeff : (k, P * 3) float32 de-quantised
    coefficients already mixed back to the domain's Rec.709 channels (the colour matrix
    applied), texel-major with channels interleaved; dom : the working domain;
    bytes : {"basis", "coefficients", "payload"}; info : what was chosen.
    """

    basis: np.ndarray
    coeff: np.ndarray
    dom: Domain
    bytes: dict
    info: dict = field(default_factory=dict)

    @property
    def k(self) -> int:
        return self.basis.shape[1]

    def recon_rows(self, rows: np.ndarray, gain=None) -> np.ndarray:
        """Linear Rec.709 images (n, P, 3) for basis rows ``rows`` (n, k) (measured or blended
        rows); ``gain`` (n,) multiplies the linear result (foreshortening of blended rows)."""
        d = rows.astype(np.float32) @ self.coeff
        lin = self.dom.inverse(d)
        if gain is not None:
            lin *= np.asarray(gain, np.float32)[:, None]
        return lin.reshape(len(rows), -1, 3)

    def recon(self, sel) -> np.ndarray:
        return self.recon_rows(self.basis[sel])


# ----------------------------------------------------------------------------- the paper


def paper_method(data: Data, k: int = 150, region: int = 32) -> Factorised:
    """Koudelka et al. 2003 as the paper ran it, on the 8-bit camera values (no linearisation):
    exact SVD of the central ``region``² texels' apparent BRDFs (R, G, B as separate columns,
    one basis), every texel projected, each coefficient texture min-max scaled to 8-bit JPEG
    (quality 90, 4:4:4), the basis min-max scaled per vector into one uncompressed 8-bit TIFF.
    The reconstruction is in code values / 255; its linear version is the sRGB decode of it
    clipped to [0, 1] (the float value, not rounded to 8 bits: the generous reading)."""
    from usdbtf.compress.codecs import quantize_minmax
    from usdbtf.compress.linalg import exact_basis

    n, S = data.size, data.S
    y0 = (n - region) // 2
    yy, xx = np.mgrid[y0:y0 + region, y0:y0 + region]
    texels = (yy * n + xx).ravel()
    table = (np.arange(256) / 255.0).astype(np.float32)
    m = table[np.asarray(data.codes[:, texels, :])].reshape(S, -1)
    u, sv = exact_basis(m, k)
    coeff = project(data, u, table)[0]                                   # (k, P, 3)
    basis = quantize_minmax(u[None, :, :], per_channel=True)            # per vector
    basis_bytes = encode_bytes(basis.pixels[0][:, :, None], PAPER_TIFF, "tif")
    b = (basis.pixels[0].astype(np.float32) * basis.scale.astype(np.float32) + basis.bias.astype(np.float32))
    coeff_bytes = 0
    c = np.empty((k, data.P * 3), np.float32)
    for i in range(k):
        st = quantize_minmax(coeff[i].reshape(n, n, 3), per_channel=False)
        size, back = encode_bytes(st.pixels, PAPER_JPEG, "jpg", readback=True)
        coeff_bytes += size
        c[i] = (back.astype(np.float32) * st.scale.astype(np.float32) + st.bias.astype(np.float32)).ravel()
    return Factorised(b, c, get_domain("srgb"), {"basis": basis_bytes, "coefficients": coeff_bytes,
                                                  "payload": basis_bytes + coeff_bytes},
                      {"method": "paper", "k": k, "region": region, "singular_values": sv[:5].tolist()})


# ----------------------------------------------------------------------------- pieces


def fit_texels(data: Data, count: int, seed: int = 0, run: int = 64) -> np.ndarray:
    """Sorted texel indices of ``count // run`` random runs of ``run`` consecutive texels
    (usdbtf's default fitting sample; all texels when count >= P)."""
    runs = data.P // run
    n_runs = min(runs, max(1, count // run))
    if n_runs >= runs:
        return np.arange(data.P)
    pick = np.sort(np.random.default_rng(seed).choice(runs, size=n_runs, replace=False)) * run
    return (pick[:, None] + np.arange(run)[None, :]).ravel()


def project(data: Data, u: np.ndarray, table: np.ndarray, chunk: int = 512):
    """Coefficients (k, P, 3) float32 = U^T X_d of every texel, X_d = table[codes] (the
    domain values), accumulated over sample chunks; and ||X_d||^2 (float)."""
    k = u.shape[1]
    acc = np.zeros((k, data.P * 3), np.float32)
    energy = 0.0
    for a in range(0, data.S, chunk):
        x = table[np.asarray(data.codes[a:a + chunk])].reshape(-1, data.P * 3)
        acc += u[a:a + chunk].T @ x
        flat = x.ravel()
        energy += float(np.einsum("i,i->", flat, flat, dtype=np.float64))
    return acc.reshape(k, data.P, 3), energy


def color_axes(coeff: np.ndarray) -> np.ndarray:
    """Orthonormal (3, 3) R, columns the colour principal axes of the coefficients (k, P, 3),
    largest first, each column's largest entry positive.  Stored channels = coeff @ R."""
    gram = np.zeros((3, 3))
    for plane in coeff:
        f = plane.astype(np.float64)
        gram += f.T @ f
    w, v = np.linalg.eigh(gram)
    v = v[:, np.argsort(w)[::-1]]
    v *= np.sign(v[np.argmax(np.abs(v), axis=0), [0, 1, 2]])
    return v


# ----------------------------------------------------------------------------- storage


def _basis_steps(u: np.ndarray, step: float, energy: np.ndarray) -> np.ndarray:
    """Per-column basis steps step / sigma_i (reverse water-filling), capped at each column's
    span and at 16 bits."""
    span = u.max(axis=0) - u.min(axis=0)
    steps = np.minimum(step / np.sqrt(np.maximum(energy, 1e-300)), np.where(span > 0, span, 1.0))
    return np.maximum(steps, span / (2**16 - 2))


def _quantise_columns(u: np.ndarray, steps: np.ndarray):
    """(pixels (S, k) uint8/16, values (S, k) float32) for per-column uniform steps."""
    q = np.rint(u / steps.astype(np.float32)).astype(np.int64)
    lo = q.min(axis=0)
    pix = q - lo
    dtype = np.uint8 if pix.max() < 256 else np.uint16
    values = (pix.astype(np.float32) * steps.astype(np.float32) + (lo * steps).astype(np.float32))
    return pix.astype(dtype), values


def basis_image_bytes(data: Data, pixels: np.ndarray, attributes: dict) -> int:
    """Bytes of the basis (S, k) integer image in usdbtf's tiled layout (view x light tiles)."""
    from usdbtf.compress.format import basis_layout, basis_to_image

    layout = basis_layout(data.sampling, pixels.shape[1], "jxl")
    return encode_bytes(basis_to_image(pixels[:, :, None], layout), attributes)


@dataclass(frozen=True)
class Storage:
    """How quantised textures become files.

    layout : "rgb" = one 3-channel image per component (usdbtf today); "planar" = one
        single-channel H x 3W image per component, the three decorrelated channels side by
        side (JPEG XL codes these 20-30 % smaller: its 3-channel lossless path models the
        very unequal decorrelated channels badly).
    effort, basis_effort : JPEG XL encoder effort for the coefficient textures / the basis.
    """

    layout: str = "rgb"
    effort: int = 2
    basis_effort: int = 3

    def coefficient_image(self, pixels: np.ndarray) -> np.ndarray:
        if self.layout == "rgb":
            return pixels
        return np.ascontiguousarray(np.concatenate([pixels[:, :, c] for c in range(3)], axis=1)[:, :, None])

    @property
    def attributes(self) -> dict:
        return {"jpegxl:distance": 0.0, "jpegxl:effort": self.effort}

    @property
    def basis_attributes(self) -> dict:
        return {"jpegxl:distance": 0.0, "jpegxl:effort": self.basis_effort}


def uniform_store(data: Data, u: np.ndarray, stored: np.ndarray, energy: np.ndarray, k: int, step: float,
                  storage: Storage = Storage()) -> tuple[np.ndarray, np.ndarray, dict, list]:
    """usdbtf's default quantisation of the first k components: one uniform step for every
    coefficient (uint8/16 per texture), basis column i at step / sigma_i; files per ``storage``.
    Returns (basis values (S, k), coefficient values (k, P, 3) in stored channels, bytes,
    per-texture bytes)."""
    from usdbtf.compress.codecs import quantize_uniform

    steps = _basis_steps(u[:, :k], step, energy[:k])
    pix, b = _quantise_columns(u[:, :k], steps)
    basis_bytes = basis_image_bytes(data, pix, storage.basis_attributes)
    n = data.size
    c = np.empty((k, data.P, 3), np.float32)
    per = []
    for i in range(k):
        st = quantize_uniform(stored[i].reshape(n, n, 3), step)
        per.append(encode_bytes(storage.coefficient_image(st.pixels), storage.attributes))
        c[i] = st.values().reshape(-1, 3)
    return b, c, {"basis": basis_bytes, "coefficients": int(sum(per)), "payload": basis_bytes + int(sum(per))}, per


def _rd_choice(data, u, stored, total_energy, budget, storage, seed=0):
    """(k, step) by usdbtf's rate-distortion model (ratedist), calibrated on a probe encode
    (a dozen textures and the basis), then the full encode, trimmed until it fits."""
    from usdbtf.compress import ratedist
    from usdbtf.compress.codecs import quantize_uniform

    table = ratedist.rd_table(stored, u, total_energy, seed=seed)
    k, step = ratedist.choose_for_bytes(table, budget, 1.0)
    j = list(table.steps).index(step)
    probe = np.unique(np.linspace(0, k - 1, min(k, 12)).round().astype(int))
    n = data.size
    cb = sum(encode_bytes(storage.coefficient_image(quantize_uniform(stored[i].reshape(n, n, 3), step).pixels),
                          storage.attributes) for i in probe)
    steps = _basis_steps(u[:, :k], step, table.energy[:k])
    bb = basis_image_bytes(data, _quantise_columns(u[:, :k], steps)[0], storage.basis_attributes)
    fc = max(cb - len(probe) * ratedist.FILE_OVERHEAD_BYTES, 1.0) / max(float(table.coeff_bytes[probe, j].sum()), 1.0)
    fb = bb / max(float(table.basis_bytes[:k, j].sum()), 1.0)
    k, step = ratedist.choose_for_bytes(table, 0.995 * budget, fc, fb)
    return k, step, table.energy


def _fit_k(per: list, basis_bytes: int, budget: int) -> int:
    """Largest k' < k whose first k' textures plus the basis pro rata fit 0.995 * budget
    (trailing components are the cheapest: dropping them keeps the most)."""
    k = len(per)
    total = np.cumsum(per) + basis_bytes * np.arange(1, k + 1) / k
    fits = np.flatnonzero(total <= 0.995 * budget)
    return max(1, min(k - 1, int(fits[-1]) + 1 if len(fits) else 1))


def factorise(data: Data, budget: int, *, dom="linear", k_max: int = 300, n_fit: int = 4096,
              power_iterations: int = 1, seed: int = 0, fit_weight: float = 0.0,
              storage: Storage = Storage()) -> Factorised:
    """usdbtf's default solver (randomized SVD on sampled texels, every texel projected, colour
    PCA, one uniform step with basis steps step / sigma_i, (k, step) by rate-distortion under
    ``budget`` bytes, lossless JPEG XL), in the working domain ``dom``.

    fit_weight : a > 0 weights each fitted texel's columns by ||x_t||^-a (equalising dark and
        bright texels in the fit), 0 = unweighted.
    """
    from usdbtf.compress.linalg import randomized_basis

    dom = get_domain(dom) if isinstance(dom, str) else dom
    table = dom.code_table(data.lut)
    fit = fit_texels(data, n_fit, seed)
    x = table[np.asarray(data.codes[:, fit, :])].reshape(data.S, -1)
    if fit_weight:
        norms = np.sqrt((x.reshape(data.S, -1, 3) ** 2).sum(axis=(0, 2)))
        w = np.repeat(np.maximum(norms, norms.max() * 1e-6) ** -fit_weight, 3).astype(np.float32)
        x = x * w
    u, sv = randomized_basis(x, min(k_max, data.S), power_iterations=power_iterations, seed=seed)
    del x
    coeff, total = project(data, u, table)
    r = color_axes(coeff)
    stored = (coeff.reshape(-1, 3) @ r.astype(np.float32)).reshape(coeff.shape)
    k, step, energy = _rd_choice(data, u, stored, total, budget, storage, seed)
    while True:
        b, c, sizes, per = uniform_store(data, u, stored, energy, k, step, storage)
        if sizes["payload"] <= budget:
            break
        k = _fit_k(per, sizes["basis"], budget)
    coeff_dom = (c.reshape(-1, 3) @ r.T.astype(np.float32)).reshape(k, -1)
    return Factorised(b, coeff_dom, dom, sizes, {"method": "factorise", "domain": dom.name, "k": k, "step": step,
                                                  "n_fit": len(fit), "fit_weight": fit_weight,
                                                  "power_iterations": power_iterations,
                                                  "storage": storage.__dict__})


# ----------------------------------------------------------------------------- caching


def save(f: Factorised, path) -> None:
    """Keep a method's result (basis, coefficients, domain, bytes, info) as one .npz."""
    import json
    from pathlib import Path

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, basis=f.basis, coeff=f.coeff, meta=json.dumps({"domain": f.dom.name, "bytes": f.bytes,
                                                                   "info": f.info}))
    tmp.replace(path)


def restore(path) -> Factorised | None:
    import json
    from pathlib import Path

    if not Path(path).is_file():
        return None
    z = np.load(path)
    meta = json.loads(str(z["meta"]))
    return Factorised(z["basis"], z["coeff"], get_domain(meta["domain"]), meta["bytes"], meta["info"])


def paper_cached(data: Data) -> Factorised:
    """:func:`paper_method` of ``data`` (k 150, 32² region), computed once per dataset."""
    from rlib import OUT

    path = OUT / "paper" / f"{data.name}-{data.S}-{data.size}.npz"
    f = restore(path)
    if f is None:
        f = paper_method(data)
        save(f, path)
    return f


# ----------------------------------------------------------------------------- held-out directions


@dataclass
class DirectionSplit:
    """10 % of the light directions held out of ``data`` (every view; ``bench.heldout``):
    ``sub`` the fitted samples as a Data of their own, ``fitted`` / ``query`` their samplings,
    ``held`` the held-out sample indices, ``position[s]`` the index of sample s among them."""

    data: Data
    fit: np.ndarray
    held: np.ndarray
    sub: Data
    fitted: object
    query: object
    position: np.ndarray

    def manifest(self):
        """A manifest folder of the fitted samples (images by reference), for the CLI."""
        from usdbtf.bench.datasets import write_subset
        from rlib import DATA, OUT

        folder = OUT / "subsets" / f"{self.data.name}-fit90"
        if not (folder / "btf.json").is_file():
            write_subset(DATA / f"{self.data.name}-paper-{self.data.size}-seed0", self.fit, folder)
        return folder


def direction_split(data: Data, fraction: float = 0.1, seed: int = 0) -> DirectionSplit:
    from usdbtf.bench.heldout import split_lights

    fit, held = split_lights(data.sampling, fraction, seed=seed)
    sub = data.subset(fit)
    sub.name = data.name
    position = np.full(data.S, -1)
    position[held] = np.arange(len(held))
    return DirectionSplit(data, fit, held, sub, data.sampling.subset(fit), data.sampling.subset(held), position)



def heldout_errors(data: Data, split: DirectionSplit, sel: np.ndarray, methods: dict) -> dict:
    """Held-out-direction errors {name: {"encoded", "linear", "bytes", "k"}} of each stored
    method (``name -> Factorised``-like: ``basis``, ``dom``, ``recon_rows``, ``bytes``, ``k``)
    predicted by :func:`heldout_predictor`, plus "floor": the original fitted images blended
    the same way (linear, foreshortening per neighbour).  ``sel``: held-out sample indices."""
    from rlib import evaluate
    from usdbtf.bench.heldout import neighbour_weights

    out = {}
    for name, f in methods.items():
        predict = heldout_predictor(f, split.fitted, split.query)
        e = evaluate(data, lambda s: predict(split.position[s]), sel)
        out[name] = {"encoded": e.encoded, "linear": e.linear, "bytes": f.bytes["payload"], "k": f.k}
    idx, w = neighbour_weights(split.fitted, split.query, 4)

    def floor(s):
        pos = split.position[s]
        codes = np.asarray(data.codes[split.fit[idx[pos]].ravel()])
        imgs = data.lut[codes].reshape(len(pos), idx.shape[1], -1, 3)
        return np.einsum("qn,qnpc->qpc", w[pos].astype(np.float32), imgs)
    e = evaluate(data, floor, sel, chunk=64)
    out["floor"] = {"encoded": e.encoded, "linear": e.linear}
    return out


def heldout_predictor(f: Factorised, fitted_sampling, query_sampling, neighbours: int = 4, mode: str = "rows"):
    """``predict(positions) -> (n, P, 3)`` linear images of held-out directions from the
    stored fitted ones, the way a renderer would: blend the ``neighbours`` nearest basis rows
    in the working domain (inverse-distance-squared weights, ``usdbtf.bench.heldout``), dot
    with the coefficients, apply the inverse curve.  The light's foreshortening is carried
    as in ``bench.heldout`` (neighbour j scaled by a_j = cos theta_l(query) / cos theta_l(j)):
    exactly, by a_j^(1/g) on the rows, for a power curve x^(1/g) (g = 1: linear, identical
    to the benchmark's predictor; sRGB as g = 2.2), else as one gain on the linear result.

    mode "images" instead reconstructs each neighbour (dot product, inverse curve) and blends
    the linear images with the benchmark's weights: exact for any curve, but a renderer then
    evaluates ``neighbours`` dot products per texel instead of one."""
    from usdbtf.bench.heldout import neighbour_weights

    idx, w = neighbour_weights(fitted_sampling, query_sampling, neighbours, foreshortening=False)
    cos_f = np.maximum(np.cos(np.radians(fitted_sampling.light[:, 0])), 1e-3)
    a = np.cos(np.radians(query_sampling.light[:, 0]))[:, None] / cos_f[idx]
    if mode == "images":
        wa = (w * a).astype(np.float32)

        def blend_images(pos):
            imgs = f.recon_rows(f.basis[idx[pos].ravel()]).reshape(len(pos), idx.shape[1], -1, 3)
            return np.einsum("qn,qnpc->qpc", wa[pos], imgs)
        return blend_images
    g = f.dom.gamma
    if g is not None:
        wr, gain = w * a ** (1.0 / g), None
    else:
        wr, gain = w, (w * a).sum(axis=1)
    rows = np.einsum("qn,qnk->qk", wr.astype(np.float32), f.basis[idx])

    def predict(pos):
        return f.recon_rows(rows[pos], None if gain is None else gain[pos])
    return predict


# ----------------------------------------------------------------------------- configurations

_INT = ("k_max", "n_fit", "power_iterations", "seed", "effort", "basis_effort")
_FLOAT = ("fit_weight",)
_STORAGE = ("layout", "effort", "basis_effort")


def parse_config(text: str) -> dict:
    """"dom=gamma2,k_max=450,layout=planar" -> keyword arguments of :func:`factorise`
    (whitelisted keys, typed values)."""
    out = {}
    for part in filter(None, text.split(",")):
        key, _, value = part.partition("=")
        if key in _INT:
            out[key] = int(value)
        elif key in _FLOAT:
            out[key] = float(value)
        elif key in ("dom", "layout"):
            out[key] = value
        else:
            raise SystemExit(f"unknown configuration key {key!r} in {text!r}")
    return out


def run_config(data: Data, budget: int, text: str) -> Factorised:
    """:func:`factorise` with the configuration string ``text`` (see :func:`parse_config`)."""
    kw = parse_config(text)
    storage = Storage(**{k: kw.pop(k) for k in _STORAGE if k in kw})
    return factorise(data, budget, storage=storage, **kw)


# ----------------------------------------------------------------------------- domain choice


def eval_texels(data: Data, fit: np.ndarray, count: int, seed: int = 1, run: int = 64) -> np.ndarray:
    """Sorted texels of random runs of ``run`` texels disjoint from the fitting runs."""
    used = np.unique(fit // run)
    free = np.setdiff1d(np.arange(data.P // run), used)
    pick = np.sort(np.random.default_rng(seed).choice(free, size=min(len(free), max(1, count // run)),
                                                      replace=False)) * run
    return (pick[:, None] + np.arange(run)[None, :]).ravel()


def domain_scores(data: Data, candidates, *, k_probe: int = 300, n_fit: int = 4096, n_eval: int = 2048,
                  sample_stride: int = 2, seed: int = 0) -> dict:
    """Cheap proxy for picking the working domain per material: for each candidate curve, fit
    the basis as :func:`factorise` does, project held-out texels only, and measure the
    UNQUANTISED error of the first ``k_probe`` components on them (every ``sample_stride``-th
    sample), in both error domains.  Returns {name: (enc %, lin %, score)} with score =
    log(enc) + log(lin): lower is better in both domains at once (the paper's errors, which
    the ratios divide by, are constants per material)."""
    from usdbtf.color import mix_rgb
    from usdbtf.compress.linalg import randomized_basis
    from rlib import srgb_encode

    fit = fit_texels(data, n_fit, seed)
    ev = eval_texels(data, fit, n_eval, seed + 1)
    rows = np.arange(0, data.S, sample_stride)
    codes = np.asarray(data.codes[:, ev, :])                       # (S, n, 3)
    truth = data.lut[codes[rows]]
    out = {}
    for name in candidates:
        dom = get_domain(name)
        table = dom.code_table(data.lut)
        x = table[np.asarray(data.codes[:, fit, :])].reshape(data.S, -1)
        u, _ = randomized_basis(x, min(k_probe, data.S), power_iterations=1, seed=seed)
        y = table[codes].reshape(data.S, -1)
        rec = dom.inverse(u[rows] @ (u.T @ y)).reshape(truth.shape)
        enc = srgb_encode(rec).astype(np.int16)
        e_enc = 100.0 * np.abs(enc - codes[rows]).sum() / codes[rows].sum(dtype=np.int64)
        e_lin = 100.0 * np.abs(mix_rgb(rec - truth, data.to_aces)).sum() / mix_rgb(truth, data.to_aces).sum()
        out[name] = (float(e_enc), float(e_lin), float(np.log(e_enc) + np.log(e_lin)))
    return out


# ----------------------------------------------------------------------------- the proposal

#: Curves the proposed solver chooses from, per material (:func:`domain_scores`).
CANDIDATES = ("gamma1.6", "gamma1.8", "gamma2", "gamma2.2", "gamma2.6", "srgb")
#: The proposed solver's settings (chosen on the tuning presets only).
PROPOSED = {"k_max": 500, "n_fit": 8192, "power_iterations": 2}
PROPOSED_STORAGE = Storage(layout="planar", effort=7, basis_effort=7)


def proposed(data: Data, budget: int) -> Factorised:
    """The proposal: pick the working curve per material with the cheap unquantised proxy
    (:func:`domain_scores` over :data:`CANDIDATES`), then :func:`factorise` in it with
    :data:`PROPOSED` and :data:`PROPOSED_STORAGE` under ``budget`` bytes."""
    import time

    t0 = time.perf_counter()
    scores = domain_scores(data, CANDIDATES)
    best = min(scores, key=lambda name: scores[name][2])
    t1 = time.perf_counter()
    f = factorise(data, budget, dom=best, storage=PROPOSED_STORAGE, **PROPOSED)
    f.info.update(domain_scores={k: [round(x, 4) for x in v] for k, v in scores.items()},
                  seconds={"choose_domain": round(t1 - t0, 1), "factorise": round(time.perf_counter() - t1, 1)})
    return f
