"""Reconstructions as manifest folders, and error metrics between two BTFs."""
from __future__ import annotations

import numpy as np

from .. import color
from ..errors import UsageError
from ..manifest import encode_for_file, write_manifest
from ..model import BTF
from .format import CompressedBTF, reconstruct, working_coefficients
from .metrics import ErrorSums

__all__ = ["parse_samples", "decompress_to_folder", "compare"]


def parse_samples(spec: str | None, n: int) -> np.ndarray:
    """"0-99,200,300-" -> sorted unique indices in [0, n).  None or "all" -> every sample."""
    if spec is None or spec.strip() in ("", "all"):
        return np.arange(n)
    out = []
    for part in spec.split(","):
        part = part.strip()
        try:
            if "-" in part:
                a, b = part.split("-", 1)
                lo, hi = int(a) if a else 0, int(b) if b else n - 1
            else:
                lo = hi = int(part)
        except ValueError:
            raise UsageError(f"--samples: cannot parse {part!r} (use e.g. 0-99,200)") from None
        if not (0 <= lo <= hi < n):
            raise UsageError(f"--samples: {part!r}: indices must lie in 0..{n - 1}")
        out.extend(range(lo, hi + 1))
    idx = np.unique(np.asarray(out, int))
    if len(idx) == 0:
        raise UsageError(f"--samples: indices must lie in 0..{n - 1}")
    return idx


def decompress_to_folder(cbtf: CompressedBTF, out, *, samples: np.ndarray | None = None, k: int | None = None,
                         chunk: int = 128):
    """Write the reconstruction of ``samples`` as a manifest in the source's colour space and bit depth."""
    idx = np.arange(cbtf.n_samples) if samples is None else np.asarray(samples)
    coeff = working_coefficients(cbtf, k)
    space = cbtf.source.get("color_space") or cbtf.working_space
    depth = cbtf.source.get("bit_depth") or "half"

    def images():
        for a in range(0, len(idx), chunk):
            yield from reconstruct(cbtf, idx[a:a + chunk], k=k, coefficients=coeff)

    return write_manifest(out, cbtf.sampling.subset(idx), images(), color_space=space, bit_depth=depth,
                          ext="png" if depth in ("uint8", "uint16") else "exr", array_space=cbtf.working_space,
                          ocio_config=cbtf.ocio_config, interpolated=cbtf.interpolated[idx],
                          metadata={"reconstructed_from_k": k or cbtf.k})


def compare(orig: BTF, recon_images, indices=None, *, chunk: int = 256) -> dict:
    """Error metrics of reconstructions against ``orig``.

    recon_images : callable(indices) -> (n, H, W, 3) float32 working-space reconstructions.
    Returns {"linear": {...}, "encoded": {...}} with percent, rmse, psnr_db; "encoded" is on
    the original's stored encoding normalised to [0, 1] (reconstruction encoded and rounded
    the way a file of that bit depth would hold it).
    """
    idx = np.arange(orig.n_samples) if indices is None else np.asarray(indices)
    lin, enc = ErrorSums(), ErrorSums()
    to_file = color.processor(orig.working_space, orig.color_space, orig.ocio_config)
    top = {"uint8": 255.0, "uint16": 65535.0}.get(orig.bit_depth, 1.0)
    for a in range(0, len(idx), chunk):
        sel = idx[a:a + chunk]
        stored = orig.read_encoded(sel)
        truth = orig.decode(stored)
        rec = recon_images(sel)
        lin.add(truth, rec)
        enc.add(stored.astype(np.float32) / top, encode_for_file(rec, to_file, orig.bit_depth).astype(np.float32) / top)
    return {"linear": lin.report(), "encoded": enc.report(), "samples": int(len(idx))}
