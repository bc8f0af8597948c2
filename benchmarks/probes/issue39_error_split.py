"""Issue 39 probe: where the squared error of a budget's choice (K, STEP) lies, on a captured
factorisation (``issue39_capture_factorisation.py``), working domain: outside the fitted
basis (residual), components K.. dropped, coefficient rounding (rint at STEP), basis rounding
(step / sigma_i per column, sigma_i^2 x the column's squared error); and the fraction of zero
coefficient codes.

    .venv/bin/python benchmarks/probes/issue39_error_split.py CAPTURE.npz K STEP
"""
import os
import platform
import sys

import numpy as np

from usdbtf.compress.quantise import basis_steps

print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, load {os.getloadavg()[0]:.2f}")
cap = np.load(sys.argv[1])
k0, d = int(sys.argv[2]), float(sys.argv[3])
C, U = cap["coefficients"], cap["basis"].astype(np.float64)
energy = np.einsum("kpc,kpc->k", C, C, dtype=np.float64)
res = max(float(cap["total_energy"]) - energy.sum(), 0)
dropped = energy[k0:].sum()
cerr = sum(((C[i].astype(np.float64) - np.rint(C[i] / d) * d) ** 2).sum() for i in range(k0))
a = basis_steps(d, energy[:k0], U[:, :k0])
berr = (((U[:, :k0] - np.rint(U[:, :k0] / a) * a) ** 2).sum(axis=0) * energy[:k0]).sum()
tot = res + dropped + cerr + berr
print(f"{sys.argv[1]} k {k0} step {d:.4g}: residual {res / tot:.3f} dropped {dropped / tot:.3f} "
      f"coeff quant {cerr / tot:.3f} basis quant {berr / tot:.3f}")
z = np.mean([np.mean(np.rint(C[i] / d) == 0) for i in range(k0)])
print(f"  codes zero: {z:.3f}; per colour plane, zero fraction of the last 50 components:",
      [round(float(np.mean(np.rint(C[k0 - 50:k0, :, c] / d) == 0)), 3) for c in range(3)])
