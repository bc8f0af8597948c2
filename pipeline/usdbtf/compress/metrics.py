"""Error metrics, accumulated over chunks so they never need the whole BTF at once.

* percent error (the paper's): 100 * sum|orig - recon| / sum(orig)
* RMSE, and PSNR = 20 log10(peak / RMSE)

Both on the input's encoded values (normalised to [0, 1] for integer files,
peak 1) and in scene-linear working space (peak 1.0 = diffuse white).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ErrorSums"]


@dataclass
class ErrorSums:
    """Running sums for one domain.  ``add`` takes equally shaped arrays (any shape)."""

    abs_err: float = 0.0
    total: float = 0.0
    sq_err: float = 0.0
    count: int = 0

    def add(self, orig: np.ndarray, recon: np.ndarray, chunk: int = 1 << 20) -> None:
        """Accumulate over equally shaped arrays.  Differences are taken at the inputs'
        precision (float32 data stays float32) and summed in float64 per ~1M-value chunk,
        so large arrays never get a float64 copy."""
        dtype = np.result_type(orig, recon, np.float32)   # float32 data stays float32
        o = np.ascontiguousarray(orig, dtype).reshape(-1)
        r = np.ascontiguousarray(recon, dtype).reshape(-1)
        if o.shape != r.shape:
            raise ValueError(f"shapes differ: {np.shape(orig)} vs {np.shape(recon)}")
        for a in range(0, o.size, chunk):
            self.add_difference(o[a:a + chunk] - r[a:a + chunk])
        self.total += float(o.sum(dtype=np.float64))
        self.count += o.size

    def add_difference(self, diff: np.ndarray) -> None:
        """Accumulate |diff| and diff^2 of a 1-D chunk (not the totals): float64 sums of
        float32 values, cast in the reduction's buffers rather than as a float64 copy
        (4x faster per million values)."""
        self.abs_err += float(np.abs(diff).sum(dtype=np.float64))
        self.sq_err += float(np.einsum("i,i->", diff, diff, dtype=np.float64))

    def merge(self, other: "ErrorSums") -> None:
        """Add the sums of ``other`` (a part accumulated on its own, e.g. one block of samples)."""
        self.abs_err += other.abs_err
        self.total += other.total
        self.sq_err += other.sq_err
        self.count += other.count

    def merge_scaled(self, other: "ErrorSums", weight: float) -> None:
        """Add ``weight`` times the sums of ``other``: a sample of ``1 / weight`` of a
        stratum standing for the whole stratum (``count`` rounded)."""
        self.abs_err += weight * other.abs_err
        self.total += weight * other.total
        self.sq_err += weight * other.sq_err
        self.count += int(round(weight * other.count))

    @property
    def percent(self) -> float:
        return 100.0 * self.abs_err / self.total if self.total > 0 else float("nan")

    @property
    def rmse(self) -> float:
        return float(np.sqrt(self.sq_err / self.count)) if self.count else float("nan")

    def psnr(self, peak: float = 1.0) -> float:
        r = self.rmse
        return float(20 * np.log10(peak / r)) if r > 0 else float("inf")

    def report(self) -> dict:
        """percent, rmse, psnr_db; a non-finite value (PSNR of an exact result, anything of an
        empty sum) is None, so reports stay strict JSON."""
        out = {"percent": self.percent, "rmse": self.rmse, "psnr_db": self.psnr()}
        return {k: (v if np.isfinite(v) else None) for k, v in out.items()}
