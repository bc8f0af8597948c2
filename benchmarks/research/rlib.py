"""Shared pieces of the compression research prototypes (issue 16).

Nothing here is product code: the scripts in this folder import it to load the cached
benchmark datasets, to measure percent error exactly as issue 16 defines it, and to run the
honest paper baseline and the prototype solvers.  They use usdbtf's public pieces (synth
datasets, the sampling, OCIO decode tables, ``compress.linalg``, ``compress.codecs``,
``compress.ratedist``, ``bench.heldout``) and never edit ``usdbtf.compress``.

Definitions
-----------
* Input: a ``usdbtf synth`` dataset, 8-bit sRGB PNG (``usdbtf.bench.datasets``), held in
  memory as codes (S, P, 3) uint8, cached as ``.npy`` under ``benchmarks/out/research/``.
* Percent error: ``100 * sum|orig - recon| / sum orig`` over every sample, texel and channel
  (the paper's metric), in two domains:

  - **encoded**: on the 8-bit file values; the reconstruction is encoded with the exact
    IEC 61966-2-1 sRGB curve, clipped to [0, 1] and rounded to 8 bits the way a file would
    hold it (OCIO's own fast evaluation of the curve rounds 0.05 % of values one code
    differently; a 1e-5 relative effect on the percentages);
  - **linear**: scene-linear in usdbtf's working space (ACEScg): file codes decoded by the
    sRGB curve (OCIO's table) and the Rec.709 -> ACEScg matrix, against the reconstruction
    in the same space.
* Stored bytes: the files a renderer needs, basis + coefficient textures (metadata excluded),
  measured by encoding them for real with OpenImageIO.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
OUT = REPO / "benchmarks" / "out" / "research"
DATA = REPO / "benchmarks" / "out" / "data"

__all__ = ["Data", "load", "Domain", "DOMAINS", "domain", "Errors", "evaluate", "srgb_encode", "srgb_decode",
           "header", "say", "OUT", "DATA", "encode_bytes", "Timer", "stride_rows", "preset_list"]


def say(msg: str = "") -> None:
    print(msg, flush=True)


def header(title: str, inputs: list[str]) -> None:
    """Print the title, the command, the machine (CPU, BLAS, versions, load, git) and the inputs."""
    from usdbtf.bench.machine import format_machine, machine_info

    say(f"# {title}")
    say(f"command: {' '.join([os.path.relpath(sys.executable, REPO), *sys.argv])}")
    say(f"started: {time.strftime('%Y-%m-%d %H:%M:%S')}")
    say("\n## machine (shared with other sessions: times are indicative)")
    say(format_machine(machine_info()))
    say("\n## inputs")
    for line in inputs:
        say(f"- {line}")
    say("")


class Timer:
    """``with Timer() as t: ...``; then ``t.s`` seconds (wall)."""

    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.s = time.perf_counter() - self.t0


# ----------------------------------------------------------------------------- sRGB curve


def srgb_decode(v: np.ndarray) -> np.ndarray:
    """Exact sRGB EOTF on encoded values in [0, 1] (clipped): -> linear (float64 math, input dtype)."""
    v = np.clip(np.asarray(v, np.float64), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _srgb_oetf(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, np.float64), 0.0, None)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


class _Encoder:
    """Linear -> 8-bit sRGB code, exact, through two tables over float32 bit patterns.

    The top 19 bits of a non-negative float32 (exponent + 10 mantissa bits) index a bin;
    each bin holds at most one code boundary (checked), so code = low[bin] + (x >= thr[bin]).
    """

    def __init__(self):
        bins = np.arange(2**18, dtype=np.uint64)
        with np.errstate(invalid="ignore"):                 # the NaN bit patterns of the top bins
            lo = (bins << 13).astype(np.uint32).view(np.float32).astype(np.float64)
            hi = (((bins + 1) << 13) - 1).astype(np.uint32).view(np.float32).astype(np.float64)
        finite = np.isfinite(lo) & np.isfinite(hi)
        lo, hi = np.where(finite, lo, 1e30), np.where(finite, hi, 1e30)
        c_lo = np.clip(np.floor(_srgb_oetf(lo) * 255 + 0.5), 0, 255)
        c_hi = np.clip(np.floor(_srgb_oetf(hi) * 255 + 0.5), 0, 255)
        if np.any(c_hi - c_lo > 1):
            raise AssertionError("sRGB encoder bins too coarse")
        # boundary between c_lo and c_lo + 1: x with oetf(x) * 255 = c_lo + 0.5
        edge = srgb_decode((c_lo + 0.5) / 255.0)
        thr = np.where(c_hi > c_lo, edge, np.nan).astype(np.float32)    # NaN: no boundary (x >= NaN is False)
        # float32 rounding of the boundary: make the comparison agree with the float64 rule
        with np.errstate(invalid="ignore"):
            low_side = thr.astype(np.float64) < edge
        thr = np.where(low_side, np.nextafter(thr, np.float32(np.inf)), thr)
        self.low = c_lo.astype(np.uint8)
        self.thr = thr

    def __call__(self, lin: np.ndarray) -> np.ndarray:
        x = np.fmax(np.asarray(lin, np.float32), np.float32(0.0))      # NaN -> 0 too (fmax, not maximum)
        idx = x.view(np.uint32) >> 13
        return self.low[idx] + (x >= self.thr[idx]).astype(np.uint8)


_ENCODER: _Encoder | None = None


def srgb_encode(lin: np.ndarray) -> np.ndarray:
    """Linear Rec.709 float -> 8-bit sRGB codes (uint8), clipped and rounded like a file."""
    global _ENCODER
    if _ENCODER is None:
        _ENCODER = _Encoder()
    return _ENCODER(lin)


# ----------------------------------------------------------------------------- data


@dataclass
class Data:
    """An 8-bit sRGB BTF held in memory.

    codes : (S, P, 3) uint8 (a read-only memory map of the cache file), P = H * W texels in
        row-major order; sampling : usdbtf Sampling; lut : (256,) float32 sRGB decode (OCIO's
        table: code -> linear Rec.709); to_aces : (3, 3) float32 Rec.709 -> ACEScg.
    """

    name: str
    codes: np.ndarray
    sampling: object
    size: int
    lut: np.ndarray
    to_aces: np.ndarray
    rows: np.ndarray | None = None          # when a subset: indices into the full dataset

    @property
    def S(self) -> int:
        return self.codes.shape[0]

    @property
    def P(self) -> int:
        return self.codes.shape[1]

    def subset(self, rows) -> "Data":
        rows = np.asarray(rows)
        return Data(f"{self.name}[{len(rows)} rows]", self.codes[rows], self.sampling.subset(rows), self.size,
                    self.lut, self.to_aces, rows)


def load(preset: str, sampling: str = "paper", size: int = 128, seed: int = 0, say=say) -> Data:
    """The dataset ``usdbtf synth PRESET --sampling SAMPLING --size SIZE --seed SEED`` writes
    (generated once under benchmarks/out/data), as codes cached under benchmarks/out/research."""
    from usdbtf import color
    from usdbtf.bench.datasets import ensure_dataset
    from usdbtf.io import open_btf

    info = ensure_dataset(DATA, preset, sampling, size, seed, say=say)
    btf = open_btf(info["folder"])
    cache = OUT / "cache" / f"{Path(info['folder']).name}.npy"
    stamp = os.path.getmtime(Path(info["folder"]) / "btf.json")
    if not cache.is_file() or os.path.getmtime(cache) < stamp:
        cache.parent.mkdir(parents=True, exist_ok=True)
        t = time.perf_counter()
        codes = np.empty((btf.n_samples, btf.n_pixels, 3), np.uint8)
        for a in range(0, btf.n_samples, 256):
            b = min(a + 256, btf.n_samples)
            codes[a:b] = btf.read_encoded(slice(a, b)).reshape(b - a, -1, 3)
        tmp = cache.with_suffix(".tmp.npy")
        np.save(tmp, codes)
        os.replace(tmp, cache)
        say(f"  decoded {btf.n_samples} files into {cache} in {time.perf_counter() - t:.1f} s")
    codes = np.load(cache, mmap_mode="r")
    dec = color.integer_decoder(btf.color_space, 8, btf.working_space)
    if not (dec.exact and dec.shared_curve and btf.color_space.startswith("sRGB")):
        raise SystemExit(f"{info['folder']}: expected 8-bit sRGB files with an exact table decode")
    return Data(preset, codes, btf.sampling, size, dec.lut[0].astype(np.float32), dec.matrix.astype(np.float32))


def paper_budget_inputs(presets: list, stride: int) -> list[str]:
    """The "inputs" lines of a comparison at the paper's bytes over ``presets`` (for :func:`header`)."""
    from usdbtf.bench.datasets import HELDOUT_PRESETS

    return [f"presets {', '.join(presets)}; held out (never tuned on): "
            f"{', '.join(x for x in presets if x in HELDOUT_PRESETS) or '-'}",
            "sampling paper (90 views x 120 lights = 10,800 samples), 128x128, 8-bit sRGB PNG, synth seed 0",
            f"errors over every {stride}-th sample, all texels and channels; encoded = 8-bit sRGB file values, "
            "linear = scene-linear ACEScg",
            "budget = the paper method's stored bytes (basis + coefficient files) on the same data"]


def stride_rows(data: Data, stride: int) -> np.ndarray:
    """Every ``stride``-th sample (an evaluation subset for sweeps)."""
    return np.arange(0, data.S, stride)


# ----------------------------------------------------------------------------- domains


@dataclass(frozen=True)
class Domain:
    """A per-channel curve on linear Rec.709 values: fitting and quantisation happen on
    ``forward(x)``; a renderer applies ``inverse`` after the dot product (and before the
    Rec.709 -> working-space matrix).  ``gamma`` = the exponent g with forward(x) = x^(1/g)
    for power curves (1 = linear, used to blend foreshortening exactly); None otherwise."""

    name: str
    kind: str
    param: float = 1.0

    def forward(self, x: np.ndarray) -> np.ndarray:
        x = np.maximum(np.asarray(x, np.float32), 0.0)
        if self.kind == "power":
            return x if self.param == 1.0 else np.power(x, np.float32(1.0 / self.param))
        if self.kind == "srgb":
            return _srgb_oetf(x).astype(np.float32)
        if self.kind == "log":
            e = np.float32(self.param)
            return np.log(x + e) - np.log(e)
        raise ValueError(self.kind)

    def inverse(self, d: np.ndarray) -> np.ndarray:
        """Domain values -> linear, float32; negative reconstructions clamp to 0 (one max per
        value in a shader)."""
        d = np.asarray(d, np.float32)
        if self.kind == "power":
            return d if self.param == 1.0 else np.power(np.maximum(d, np.float32(0.0)), np.float32(self.param))
        if self.kind == "srgb":
            return srgb_decode(d).astype(np.float32)
        if self.kind == "log":
            e = np.float32(self.param)
            return np.maximum(np.exp(d + np.log(e)) - e, np.float32(0.0))
        raise ValueError(self.kind)

    @property
    def gamma(self) -> float | None:
        return self.param if self.kind == "power" else (2.2 if self.kind == "srgb" else None)

    def code_table(self, lut: np.ndarray) -> np.ndarray:
        """(256,) float32: domain value of each 8-bit sRGB code (exact for sRGB: code / 255)."""
        if self.kind == "srgb":
            return (np.arange(256) / 255.0).astype(np.float32)
        return self.forward(lut).astype(np.float32)


DOMAINS = {
    "linear": Domain("linear", "power", 1.0),
    "gamma1.5": Domain("gamma1.5", "power", 1.5),
    "gamma2": Domain("gamma2", "power", 2.0),
    "gamma2.2": Domain("gamma2.2", "power", 2.2),
    "gamma3": Domain("gamma3", "power", 3.0),
    "srgb": Domain("srgb", "srgb"),
    "log1e-2": Domain("log1e-2", "log", 1e-2),
    "log1e-3": Domain("log1e-3", "log", 1e-3),
}


def domain(name: str) -> Domain:
    """A named domain, or ``gammaG`` / ``logE`` for any G / E."""
    if name in DOMAINS:
        return DOMAINS[name]
    if name.startswith("gamma"):
        return Domain(name, "power", float(name[5:]))
    if name.startswith("log"):
        return Domain(name, "log", float(name[3:]))
    raise ValueError(f"unknown domain {name!r}")


# ----------------------------------------------------------------------------- errors


@dataclass
class Errors:
    """Both domains' error sums (``usdbtf.compress.metrics.ErrorSums``): ``enc`` on the 8-bit
    codes (peak 255), ``lin`` in scene-linear ACEScg (peak 1)."""

    enc: object = None
    lin: object = None

    def __post_init__(self):
        from usdbtf.compress.metrics import ErrorSums

        self.enc = self.enc or ErrorSums()
        self.lin = self.lin or ErrorSums()

    @property
    def encoded(self) -> float:
        return self.enc.percent

    @property
    def linear(self) -> float:
        return self.lin.percent

    def row(self) -> str:
        return f"{self.encoded:7.3f} % enc, {self.linear:7.3f} % lin"


def evaluate(data: Data, recon, rows=None, chunk: int = 256) -> Errors:
    """Errors of ``recon(rows) -> (n, P, 3) float32 linear Rec.709`` against ``data`` over the
    samples ``rows`` (default all): every texel and channel."""
    from usdbtf.color import mix_rgb

    rows = np.arange(data.S) if rows is None else np.asarray(rows)
    e = Errors()
    for a in range(0, len(rows), chunk):
        sel = rows[a:a + chunk]
        codes = np.asarray(data.codes[sel])
        rec = recon(sel)
        e.enc.add(codes.astype(np.float32), srgb_encode(rec).astype(np.float32))
        e.lin.add(mix_rgb(data.lut[codes], data.to_aces), mix_rgb(rec, data.to_aces))
    return e


def preset_list(text: str, *, tuning_only: bool) -> list:
    """Comma-separated preset names; with ``tuning_only`` a held-out preset is refused (no
    sweep may look at one)."""
    from usdbtf.bench.datasets import preset_split

    presets = [x for x in text.split(",") if x]
    held = [x for x in presets if preset_split(x) == "held-out"]
    if tuning_only and held:
        raise SystemExit(f"held-out presets {held} are never tuned on")
    return presets


# ----------------------------------------------------------------------------- codecs


_TMP = None


def encode_bytes(pixels: np.ndarray, attributes: dict, ext: str = "jxl", readback: bool = False):
    """Encode ``pixels`` (H, W, C) with OpenImageIO and ``attributes``; returns bytes, and with
    ``readback`` also the decoded pixels."""
    from usdbtf.imageio import read_image, write_image

    global _TMP
    if _TMP is None:
        _TMP = tempfile.TemporaryDirectory(prefix="usdbtf-research-")
    path = Path(_TMP.name) / f"t.{ext}"
    size = write_image(path, pixels, color_space="data", attributes=attributes)   # as compress writes them
    if not readback:
        return size
    back, _ = read_image(path)
    return size, back
