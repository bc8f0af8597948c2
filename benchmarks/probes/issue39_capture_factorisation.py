"""Issue 39 probe helper: run ``usdbtf compress ARGS`` up to rate control and save the
factorisation rate control receives (float basis, projected coefficients, total energy, texture
size) to OUT.npz, for ``issue39_deadzone.py`` and ``issue39_error_split.py``; nothing is written
besides OUT.npz (rate control is replaced by the dump, which exits).

    .venv/bin/python benchmarks/probes/issue39_capture_factorisation.py OUT.npz compress IN -o DIR --max-bytes B
"""
import sys

import numpy as np

import usdbtf.compress.core as core

out = sys.argv.pop(1)


def _dump(f, opts, held, k_fit=None):
    np.savez(out, basis=f.basis, coefficients=f.coefficients, total_energy=f.total_energy, planes=np.array(f.planes),
             height=f.btf.height, width=f.btf.width, n_samples=f.btf.n_samples)
    print("captured", f.basis.shape, f.coefficients.shape, f.domain, flush=True)
    raise SystemExit(0)


core.rate_control = _dump
from usdbtf.cli import main  # noqa: E402

sys.exit(main())
