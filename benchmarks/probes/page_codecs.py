#!/usr/bin/env python
"""Rate-distortion of candidate encodings of the asset's coefficient pages (issue 39, "rate control of
what is shipped").

The packaged asset ships a folder's k coefficient textures as 8-bit RGBA PNG packs (pack 3g+c = colour
channel c of coefficients 4g..4g+3; ``usdbtf.compress.packs``).  For each compressed folder given, this
re-derives the float coefficients the codes quantise (the dataset projected onto the folder's
de-quantised basis by least squares, in the folder's working domain and stored colour planes) and
measures, at the folder's k and basis:

* the added squared error of any coding of the coefficients, in coefficient space: for a coding
  error D (k, 3P) in working-space colour, ``trace(D^T G D)`` with G = U^T U the de-quantised basis's
  Gram matrix (U is orthonormal only to the basis quantiser's precision: the probe prints G's diagonal
  range and largest off-diagonal, and uses G exactly; the least-squares residual is orthogonal to any
  coding error, so this is the working-domain error the coding adds to the reconstruction);
* lossless layouts of the same codes (equal error by construction, ``--layouts``): RGBA packs as the
  asset encoded pages before issue 39's page encoder (OIIO/libpng level 6, the smaller of adaptive and
  no filter: the baseline, measured in the same run) and as ``packs.encode_png_page`` encodes them now
  (adaptive rows, zlib Z_RLE); and, each the best of 6 row-filter choices x 4 zlib strategies at level 9
  (``imageio.encode_png_rle``): RGBA packs; one gray 128 x 512 PNG per pack (the four planes stacked);
  RGB of one coefficient's three colour planes; gray planes at the lowest PNG bit depth (1/2/4/8) that
  holds each plane's codes;
* the packaged asset's own PNG pages and basis pages (FOLDER-asset, when present) re-encoded by
  ``packs.encode_png_page``: the same pixels, the bytes before and now;
* the uniform quantiser's step moved (``--steps``, times the folder's step) with the shipped PNG: the
  curve a lossy codec must beat at equal added error;
* lossy gray JPEG (Pillow/libjpeg-turbo, baseline, optimised Huffman, no subsampling: one channel)
  with a flat quantisation table (MSE-optimal for an orthonormal DCT) per page of 16 planes of one
  colour channel, each plane mapped to 8 bits at step ``q / Q`` (Q the table's value), so the DCT-domain
  step is the target step ``q``; planes re-quantised from the float coefficients;
* OpenEXR DWAA half pages (one channel, values in step units) at a few compression levels.

Bytes are per pack / per plane file (headers included); the asset's pages hold several packs per
PNG stream (the run-length pages measured 1.02x the per-pack files).  With ``--evaluate`` the baseline and the
JPEG point nearest the baseline's error are also converted to the paper's metrics (percent error on
the 8-bit sRGB values and in scene-linear ACEScg, every ``--stride``-th sample) as
``benchmarks/bench_issue16.py`` computes them.

Usage (repository root)::

    nice .venv/bin/python benchmarks/probes/page_codecs.py FOLDER [FOLDER ...] [--evaluate] [--stride 4]

FOLDER: a compressed folder whose ``source`` path names a paper-sampling dataset; its decoded codes are
read from ``--cache`` (``benchmarks/research/rlib.load``'s cache, read-only here).
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))                 # benchmarks/: common.py
_sys.path.insert(0, str(_Path(__file__).resolve().parents[1] / "research"))    # rlib

import argparse
import io
import os
import time
import zlib

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

from common import format_machine, machine_info
from usdbtf.compress.format import read_compressed
from usdbtf.compress.packs import encode_png_page, pack_count
from usdbtf.imageio import decode_image, encode_image, encode_png_rle, encode_png_smallest

FILTERS = ("adaptive", 0, 1, 2, 3, 4)      # per-row minimum-sum-of-absolute-differences, then one filter for all
STRATEGIES = (zlib.Z_DEFAULT_STRATEGY, zlib.Z_FILTERED, zlib.Z_HUFFMAN_ONLY, zlib.Z_RLE)


# ----------------------------------------------------------------------------- float coefficients

def load_data(cbtf, cache_dir: _Path):
    """The folder's dataset as ``rlib.Data`` (its cached 8-bit codes, memory-mapped read-only)."""
    from rlib import Data
    from usdbtf import color
    from usdbtf.io import open_btf

    src = _Path(cbtf.source["path"])
    btf = open_btf(src)
    codes = np.load(cache_dir / f"{src.name}.npy", mmap_mode="r")
    dec = color.integer_decoder(btf.color_space, 8, btf.working_space)
    return Data(src.name, codes, btf.sampling, btf.width, dec.lut[0].astype(np.float32),
                dec.matrix.astype(np.float32))


def float_coefficients(cbtf, data, chunk: int = 256):
    """The float coefficients the folder's codes quantise, and what the error model needs.

    Returns
    -------
    stored : (k, P, 3) float64 least-squares coefficients on the de-quantised basis, in the stored
        (decorrelated) colour planes.
    gram : (k, k) float64 U^T U of the de-quantised basis U (S, k).
    truncation : float, ||X - U c||^2 of the working-domain BTF X (S, 3P): the error outside the basis.
    energy : float, ||X||^2.
    """
    from usdbtf.color import mix_rgb

    U = cbtf.basis_values().astype(np.float64)
    k, P = cbtf.k, data.P
    acc = np.zeros((k, P * 3), np.float64)
    energy = 0.0
    for a in range(0, data.S, chunk):
        b = min(a + chunk, data.S)
        lin = mix_rgb(data.lut[np.asarray(data.codes[a:b])], data.to_aces)
        x = cbtf.domain.forward(lin).reshape(b - a, -1).astype(np.float32)
        acc += (U[a:b].T.astype(np.float32) @ x).astype(np.float64)
        energy += float(np.einsum("ij,ij->", x, x, dtype=np.float64))
    gram = U.T @ U
    working = np.linalg.solve(gram, acc)                           # (k, 3P) working-space colour
    m = np.asarray(cbtf.color_matrix, np.float64)                  # working = stored @ m.T
    stored = (working.reshape(k, P, 3) @ np.linalg.inv(m.T))
    truncation = energy - float(np.einsum("ij,ij->", working, gram @ working))
    return stored, gram, truncation, energy


def added_error(delta_stored: np.ndarray, gram: np.ndarray, m: np.ndarray) -> float:
    """Working-domain squared error of a coefficient error ``delta_stored`` (k, P, 3) (stored planes)."""
    k = delta_stored.shape[0]
    d = (delta_stored @ m.T).reshape(k, -1)
    return float(np.einsum("ij,ij->", d, gram @ d))


def uniform_codes(stored: np.ndarray, step: float):
    """(codes (k, P, 3) int64 from 0, lo (k, 3) int64): the uniform quantiser at ``step`` (compress's
    ``quantize_uniform``: rint(x / step) less its minimum per texture channel)."""
    q = np.rint(stored / step).astype(np.int64)
    lo = q.min(axis=1)
    return q - lo[:, None, :], lo


# ----------------------------------------------------------------------------- PNG encodings

def png_bytes(pixels: np.ndarray, bit_depth: int = 8) -> int:
    """Bytes of the smallest PNG of ``pixels`` over :data:`FILTERS` x :data:`STRATEGIES` at zlib level 9
    (``imageio.encode_png_rle``; gray values below 2^bit_depth packed at ``bit_depth``)."""
    return min(len(encode_png_rle(pixels, row_filter=f, strategy=s, bit_depth=bit_depth))
               for f in FILTERS for s in STRATEGIES)


def bit_depth_of(plane: np.ndarray) -> int:
    """The lowest PNG gray bit depth holding a plane's codes (from 0)."""
    top = int(plane.max())
    return next(b for b in (1, 2, 4, 8) if top < 2**b)


# ----------------------------------------------------------------------------- layouts of the codes

def rgba_packs(codes: np.ndarray, H: int, W: int):
    """Packs 3g+c (H, W, 4) uint8 of ``codes`` (k, P, 3) (layers past k zero), as ``packs.coefficient_packs``."""
    k = codes.shape[0]
    for g in range(-(-k // 4)):
        for c in range(3):
            pix = np.zeros((H, W, 4), np.uint8)
            for j in range(min(4, k - 4 * g)):
                pix[:, :, j] = codes[4 * g + j, :, c].reshape(H, W)
            yield pix


def libpng_page(pixels: np.ndarray) -> bytes:
    """A pack as the asset encoded pages before this probe (OIIO/libpng level 6, the smaller of the
    adaptive and no filter): the baseline."""
    return encode_png_smallest(pixels, color_space="data", level=6, attributes={"oiio:UnassociatedAlpha": 1})


LAYOUTS = {"before": "RGBA packs, OIIO/libpng level 6, adaptive or no filter (the asset before: baseline)",
           "shipped": "RGBA packs, packs.encode_png_page now (adaptive rows, zlib Z_RLE)",
           "rgba_best": "RGBA packs, level 9, best of 6 filter choices x 4 zlib strategies",
           "gray_pack": "gray 128x512 per pack (its 4 planes stacked), best of the same",
           "rgb": "RGB of one coefficient (its 3 colour planes), best of the same",
           "gray_depth": "gray plane per file at 1/2/4/8 bits (fewest holding its codes), best of the same"}


def lossless_bytes(codes: np.ndarray, H: int, W: int, which) -> dict:
    """Bytes of each lossless layout in ``which`` (keys of :data:`LAYOUTS`) of ``codes`` (k, P, 3),
    integers 0..255."""
    k = codes.shape[0]
    out = dict.fromkeys(which, 0)
    for pix in rgba_packs(codes, H, W):
        if "before" in out:
            out["before"] += len(libpng_page(pix))
        if "shipped" in out:
            out["shipped"] += len(encode_png_page(pix))
        if "rgba_best" in out:
            out["rgba_best"] += png_bytes(pix)
        if "gray_pack" in out:
            out["gray_pack"] += png_bytes(pix.transpose(2, 0, 1).reshape(4 * H, W))
    for i in range(k):
        if "rgb" in out:
            out["rgb"] += png_bytes(codes[i].reshape(H, W, 3).astype(np.uint8))
        if "gray_depth" in out:
            for c in range(3):
                plane = codes[i, :, c].reshape(H, W).astype(np.uint8)
                out["gray_depth"] += png_bytes(plane, bit_depth_of(plane))
    return out


# ----------------------------------------------------------------------------- lossy pages

PAGE_PLANES = 16


def jpeg_page_planes(stored: np.ndarray, q: float, H: int, W: int):
    """Gray JPEG pages of 16 planes of one colour channel each, DCT-domain step ``q`` (module
    docstring).  Returns (bytes, decoded (k, P, 3) float64 coefficients)."""
    from PIL import Image

    k = stored.shape[0]
    out = np.zeros_like(stored)
    total = 0
    for c in range(3):
        for a in range(0, k, PAGE_PLANES):
            planes = stored[a:a + PAGE_PLANES, :, c]                      # (n, P)
            lo, hi = planes.min(axis=1), planes.max(axis=1)
            span = float((hi - lo).max())
            # Flat table Q: pixels at step q / Q; the 8-bit range must hold the widest plane.
            Q = int(np.clip(np.floor(254.0 * q / max(span, 1e-12)), 1, 255))
            s = q / Q
            if span / s > 254.0:
                s = span / 254.0
            mid = (lo + hi) / 2
            pix = np.clip(np.rint((planes - mid[:, None]) / s) + 128, 0, 255).astype(np.uint8)
            img = Image.fromarray(pix.reshape(-1, W))
            buf = io.BytesIO()
            img.save(buf, "JPEG", qtables=[[Q] * 64], optimize=True, subsampling=0)
            total += buf.tell()
            dec = np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("L"), np.float64).reshape(len(planes), -1)
            out[a:a + PAGE_PLANES, :, c] = (dec - 128) * s + mid[:, None]
    return total, out


def exr_dwa_pages(stored: np.ndarray, level: float, scale: float, H: int, W: int):
    """OpenEXR DWAA half pages (one ``Y`` channel, 16 planes of one colour channel stacked), values
    ``x / scale``.  Returns (bytes, decoded (k, P, 3) float64)."""
    k = stored.shape[0]
    out = np.zeros_like(stored)
    total = 0
    for c in range(3):
        for a in range(0, k, PAGE_PLANES):
            planes = stored[a:a + PAGE_PLANES, :, c]
            img = (planes / scale).astype(np.float16).astype(np.float32).reshape(-1, W, 1)
            data = encode_image(img, "exr", color_space="data", attributes={"compression": f"dwaa:{level:g}"})
            total += len(data)
            dec = decode_image(data)
            dec = dec.reshape(dec.shape[0], dec.shape[1], -1)[..., 0].astype(np.float64).reshape(len(planes), -1)
            out[a:a + PAGE_PLANES, :, c] = dec * scale
    return total, out


# ----------------------------------------------------------------------------- the paper's metrics

def paper_errors(cbtf, data, stored_values: np.ndarray, stride: int):
    """(encoded %, linear %) of the folder's basis with coefficients ``stored_values`` (k, P, 3, stored
    planes), over every ``stride``-th sample, as bench_issue16's Product evaluates a folder."""
    from rlib import evaluate
    from usdbtf.color import mix_rgb

    basis = cbtf.basis_values()
    m = np.asarray(cbtf.color_matrix, np.float64)
    coeff = (stored_values @ m.T).reshape(cbtf.k, -1).astype(np.float32)
    to_709 = np.linalg.inv(data.to_aces.astype(np.float64)).astype(np.float32)

    def recon(sel):
        lin = cbtf.domain.inverse(basis[sel].astype(np.float32) @ coeff)
        return mix_rgb(lin.reshape(len(sel), -1, 3), to_709)

    e = evaluate(data, recon, np.arange(0, data.S, stride))
    return e.encoded, e.linear


# ----------------------------------------------------------------------------- main

def interpolate_bytes(curve, error: float) -> float:
    """Bytes of a (error, bytes) curve at ``error`` (log-log interpolation; the curve sorted by error)."""
    e, b = np.log(np.array([p[0] for p in curve])), np.log(np.array([p[1] for p in curve]))
    order = np.argsort(e)
    return float(np.exp(np.interp(np.log(error), e[order], b[order])))


def probe(folder: _Path, args) -> dict:
    t0 = time.process_time()
    cbtf = read_compressed(folder)
    H, W, k = cbtf.height, cbtf.width, cbtf.k
    step = float(cbtf.coefficients[0].scale[0])
    m = np.asarray(cbtf.color_matrix, np.float64)
    data = load_data(cbtf, args.cache)
    stored, gram, trunc, energy = float_coefficients(cbtf, data)
    N = data.S * data.P * 3
    print(f"\n## {folder.name}: k {k}, step {step:.4g}, {data.S} samples x {data.P} texels, domain {cbtf.domain.name}")
    off = gram - np.diag(np.diag(gram))
    print(f"basis orthonormality (de-quantised basis): diagonal of U^T U in [{np.diag(gram).min():.4f}, "
          f"{np.diag(gram).max():.4f}], largest off-diagonal {np.abs(off).max():.2e}; "
          f"truncation error {trunc / N:.4e} per value (working domain, squared)")
    folder_codes = np.stack([st.pixels.reshape(-1, 3) for st in cbtf.coefficients]).astype(np.int64)
    codes, lo = uniform_codes(stored, step)
    bias = np.array([st.bias for st in cbtf.coefficients]) / step
    agree = float(np.mean((codes + lo[:, None, :]) == folder_codes + np.rint(bias)[:, None, :].astype(np.int64)))
    folder_values = np.stack([st.pixels.reshape(-1, 3) * st.scale + st.bias for st in cbtf.coefficients])
    e_folder = added_error(folder_values - stored, gram, m)
    print(f"re-quantised codes equal to the folder's: {100 * agree:.3f} %; the folder's coefficient quantisation "
          f"adds {e_folder / N:.4e} per value ({100 * e_folder / trunc:.2f} % of the truncation error)")
    rec = {"folder": folder.name, "k": k, "step": step, "truncation": trunc, "N": N, "e_folder": e_folder}

    # Lossless layouts at the folder's step (the same codes: equal error).
    t = time.process_time()
    lossless = lossless_bytes(folder_codes, H, W, args.layouts)
    base = lossless["before"]
    print(f"\n### lossless layouts of the codes at the folder's step ({3 * k} planes, {pack_count(k)} packs; "
          f"{time.process_time() - t:.0f} s CPU)")
    print("| layout | bytes | / before |\n|---|---:|---:|")
    for key, n in lossless.items():
        print(f"| {LAYOUTS[key]} | {n:,} | {n / base:.4f} |")
    depths = np.array([bit_depth_of(codes[i, :, c]) for i in range(k) for c in range(3)])
    print(f"planes by bit depth 1/2/4/8: {[int((depths == b).sum()) for b in (1, 2, 4, 8)]}")
    rec["lossless"] = lossless
    asset = folder.parent / f"{folder.name}-asset"
    files = sorted(asset.glob("*_textures/gpu/page*.png")) + sorted(asset.glob("*_textures/gpu/basis*.png"))
    if files:
        from usdbtf.imageio import read_rgba

        print(f"\n### the packaged asset's PNG pages re-encoded ({asset.name}; gAMA chunk not counted after)")
        print("| file | bytes in the asset | packs.encode_png_page now | ratio |\n|---|---:|---:|---:|")
        tb = ta = 0
        for path in files:
            before, after = path.stat().st_size, len(encode_png_page(read_rgba(path)))
            full = path.name.startswith("page") or path.name == "basis.png"
            tb, ta = tb + before * full, ta + after * full
            print(f"| {path.name} | {before:,} | {after:,} | {after / before:.4f} |")
        print(f"| full lod's pages and basis page | {tb:,} | {ta:,} | {ta / tb:.4f} |")
        rec["asset_pages"] = (tb, ta)

    # The shipped PNG's curve as the step moves, and the lossy codecs' points, at equal added error.
    t = time.process_time()
    curve = []
    for f in args.steps:
        c_f, lo_f = uniform_codes(stored, f * step)
        if int(c_f.max()) > 255:
            continue
        vals = (c_f + lo_f[:, None, :]) * (f * step)
        n = lossless_bytes(c_f, H, W, ("shipped",))["shipped"]
        curve.append((added_error(vals - stored, gram, m), n, f))
    print(f"\n### the shipped PNG (packs.encode_png_page) as the step moves ({time.process_time() - t:.0f} s CPU)")
    print("| step / folder's | added error per value | (truncation + added) / folder's | bytes |\n|---:|---:|---:|---:|")
    for e, n, f in curve:
        print(f"| {f:.2f} | {e / N:.4e} | {(trunc + e) / (trunc + e_folder):.4f} | {n:,} |")
    rec["png_curve"] = curve

    t = time.process_time()
    lossy = []
    for qf in args.jpeg_steps:
        n, dec = jpeg_page_planes(stored, qf * step, H, W)
        lossy.append(("jpeg flat Q", qf, added_error(dec - stored, gram, m), n, dec))
    for level in args.dwa_levels:
        n, dec = exr_dwa_pages(stored, level, step, H, W)
        lossy.append(("exr dwaa", level, added_error(dec - stored, gram, m), n, None))
    print(f"\n### lossy pages against the shipped PNG at equal added error ({time.process_time() - t:.0f} s CPU)")
    print("| codec | knob | added error per value | (trunc + added) / folder's | bytes | PNG bytes at that error | ratio |\n"
          "|---|---:|---:|---:|---:|---:|---:|")
    errs = [p[0] for p in curve]
    for name, knob, e, n, _ in lossy:
        inside = min(errs) <= e <= max(errs)
        png = interpolate_bytes(curve, e) if inside else float("nan")
        print(f"| {name} | {knob:g} | {e / N:.4e} | {(trunc + e) / (trunc + e_folder):.4f} | {n:,} | "
              f"{png:,.0f}{'' if inside else ' (outside the curve)'} | {n / png:.3f} |")
    rec["lossy"] = [(a, b, c, d) for a, b, c, d, _ in lossy]

    if args.evaluate:
        t = time.process_time()
        jp = [p for p in lossy if p[0].startswith("jpeg")]
        near = min(jp, key=lambda p: abs(p[2] - e_folder))
        enc0, lin0 = paper_errors(cbtf, data, folder_values, args.stride)
        enc1, lin1 = paper_errors(cbtf, data, near[4], args.stride)
        print(f"\n### the paper's metrics (every {args.stride}-th sample; {time.process_time() - t:.0f} s CPU)")
        print(f"folder's codes (shipped PNG, {lossless['shipped']:,} bytes): {enc0:.3f} % enc, {lin0:.3f} % lin")
        print(f"JPEG step x{near[1]:g} ({near[3]:,} bytes, added error {near[2] / e_folder:.3f}x the folder's): "
              f"{enc1:.3f} % enc, {lin1:.3f} % lin")
        rec["paper"] = {"folder": (enc0, lin0), "jpeg": (near[1], enc1, lin1)}
    print(f"\n{folder.name}: {time.process_time() - t0:.0f} s CPU")
    return rec


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folders", nargs="+", type=_Path)
    p.add_argument("--cache", type=_Path, default=_Path("/work/snap755/benchmarks/out/research/cache"),
                   help="rlib.load's cache of decoded dataset codes (<dataset>.npy), read only")
    p.add_argument("--steps", type=float, nargs="+", default=[0.8, 0.9, 1.0, 1.15, 1.3, 1.5, 1.75, 2.0])
    p.add_argument("--jpeg-steps", type=float, nargs="+", default=[0.8, 1.0, 1.25, 1.5, 2.0, 2.5])
    p.add_argument("--dwa-levels", type=float, nargs="+", default=[45, 200])
    p.add_argument("--layouts", nargs="+", default=["before", "shipped", "rgba_best", "gray_pack", "gray_depth"],
                   choices=list(LAYOUTS))
    p.add_argument("--evaluate", action="store_true")
    p.add_argument("--stride", type=int, default=4)
    args = p.parse_args(argv)
    print("# Coefficient page codecs: bytes against added error (issue 39)")
    print(f"command: {' '.join(_sys.argv)}")
    print(f"started: {time.strftime('%Y-%m-%d %H:%M:%S')}")
    print("\n## machine (shared with other sessions: CPU times quoted)")
    print(format_machine(machine_info()))
    print(f"load average {os.getloadavg()}")
    for folder in args.folders:
        probe(folder, args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
