"""Issue 39 probe: does a dead-zone quantiser of the coefficients (and of the basis) buy error
at the shipped bytes?  On a captured paper-scale factorisation (the float basis and projected
coefficients rate control receives, ``--max-bytes`` of the asset), each variant's codes are
packed and encoded exactly as the asset ships them (RGBA PNG packs of four layers,
``packs._encode_pack``; the basis codes as 8-bit high/low byte blocks of ``packs.basis_page``,
one group encoded at a time), the squared error measured in the working domain (coefficient
error + sigma_i^2 x basis column error + energy of the dropped components + residual), and the
least error at the bytes the baseline (rint, the main branch's step and k) ships is found over
a grid of steps and every k.  The baseline is measured in the same run.

    .venv/bin/python benchmarks/probes/issue39_deadzone.py CAPTURE.npz K STEP [variants]

CAPTURE.npz: ``basis`` (S, k), ``coefficients`` (k, P, 3), ``total_energy``, ``height``,
``width`` (written by a run of compress whose ``core.rate_control`` is replaced by a dump).
Variants: ``rint``; ``f0.35``: q = sign(x) floor(|x| / d + 0.35) on every bin; ``z0.7``: rint
except |x| < 0.7 d -> 0 (the zero bin alone widened); ``a0.35``: f0.35 on the colour
planes where rint makes more than half the codes 0, rint elsewhere; prefix ``b`` applies it to the basis too.
"""
from __future__ import annotations

import os
import platform
import sys
import time

import numpy as np

from usdbtf.compress.packs import _encode_pack, basis_page, encode_png_page
from usdbtf.compress.quantise import basis_steps


def quantiser(name: str):
    if name == "rint":
        return lambda x, d: np.rint(x / d)
    if name.startswith("f"):
        f = float(name[1:])
        return lambda x, d: np.sign(x) * np.floor(np.abs(x) / d + f)
    if name.startswith("a"):
        f = float(name[1:])

        def aq(x, d):
            # per colour channel (last axis): the dead zone only where rint leaves most codes zero
            q = np.rint(x / d)
            sparse = (q == 0).mean(axis=0) > 0.5
            return np.where(sparse, np.sign(x) * np.floor(np.abs(x) / d + f), q)
        return aq
    if name.startswith("z"):
        z = float(name[1:])

        def zq(x, d):
            q = np.rint(x / d)
            q[np.abs(x) < z * d] = 0
            return q
        return zq
    raise ValueError(name)


def codes(q):
    """Integer symbols (..., C) -> stored codes q - min per channel, uint8 or uint16."""
    q = q.astype(np.int64)
    lo = q.reshape(-1, q.shape[-1]).min(axis=0)
    span = int((q.reshape(-1, q.shape[-1]).max(axis=0) - lo).max())
    return (q - lo).astype(np.uint8 if span < 256 else np.uint16)


def curve(cap, k_max, step, coeff_q, basis_q):
    """(k_max,) shipped bytes and squared error of keeping the first 1..k_max components."""
    H, W = int(cap["height"]), int(cap["width"])
    U = cap["basis"][:, :k_max].astype(np.float64)
    C = cap["coefficients"][:k_max]
    energy = np.einsum("kpc,kpc->k", C, C, dtype=np.float64)
    all_energy = np.einsum("kpc,kpc->k", cap["coefficients"], cap["coefficients"], dtype=np.float64)
    residual = max(float(cap["total_energy"]) - all_energy.sum(), 0.0)
    stored, cerr = [], np.zeros(k_max)
    for i in range(k_max):
        x = C[i].astype(np.float64)
        q = coeff_q(x, step)
        cerr[i] = ((x - q * step) ** 2).sum()
        stored.append(codes(q.reshape(H, W, 3)))
    # the basis: per-column steps (reverse water-filling), codes of all k_max columns share a type
    a = basis_steps(step, energy, U)
    qb = basis_q(U, a[None, :])
    berr = ((U - qb * a[None, :]) ** 2).sum(axis=0) * energy
    bcodes = (qb - qb.min(axis=0)).astype(np.int64)
    pack = np.zeros(k_max)
    for g in range(-(-k_max // 4)):
        layers = stored[4 * g:4 * g + 4]
        dtype = np.uint16 if any(s.dtype == np.uint16 for s in layers) else np.uint8
        nbytes = 0
        for c in range(3):
            pix = np.zeros((H, W, 4), dtype)
            for j, s in enumerate(layers):
                pix[:, :, j] = s[:, :, c]
            nbytes += len(_encode_pack(pix))
        blk = np.zeros((U.shape[0], 4), np.int64)
        blk[:, :len(layers)] = bcodes[:, 4 * g:4 * g + 4]
        nbytes += len(encode_png_page(basis_page(blk, 90, 120)))
        pack[4 * g] = nbytes                              # a group ships whole
    bytes_ = np.cumsum(pack)
    dropped = all_energy.sum() - np.cumsum(energy)
    err = np.cumsum(cerr + berr) + dropped + residual
    return bytes_, err


def main():
    path, k0, step0 = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    variants = sys.argv[4].split(",") if len(sys.argv) > 4 else ["rint", "f0.42", "f0.35", "z0.6", "z0.7", "bz0.7"]
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, load {os.getloadavg()[0]:.2f}")
    cap = np.load(path)
    S, k_fit = cap["basis"].shape
    N = S * 3 * int(cap["height"]) * int(cap["width"])
    k_max = min(k_fit, int(1.3 * k0) + 8)
    print(f"input {path}: S {S}, k fitted {k_fit}, baseline k {k0} step {step0:.4g}; k up to {k_max}")
    rint = quantiser("rint")
    t = time.process_time()
    b0, e0 = curve(cap, k_max, step0, rint, rint)
    budget = b0[k0 - 1]
    base = np.sqrt(e0[k0 - 1] / N)
    print(f"baseline rint: {budget:.0f} shipped bytes (packs + basis groups), rms {base:.5g} ({time.process_time() - t:.1f} s CPU)")
    for name in variants:
        basis_name = name[1:] if name.startswith("b") else "rint"
        cq, bq = quantiser(name.lstrip("b")), quantiser(basis_name)
        best = (np.inf, None, None)
        for j in range(-4, 3):
            d = step0 * 2.0 ** (j / 4)
            by, er = curve(cap, k_max, d, cq, bq)
            ok = np.flatnonzero(by <= budget)
            if ok.size:
                i = ok[np.argmin(er[ok])]
                if er[i] < best[0]:
                    best = (er[i], i + 1, d)
        rms = np.sqrt(best[0] / N)
        print(f"{name:>8}: at <= {budget:.0f} bytes best rms {rms:.5g} = {rms / base:.4f}x rint "
              f"(k {best[1]}, step {best[2]:.4g})", flush=True)


if __name__ == "__main__":
    main()
