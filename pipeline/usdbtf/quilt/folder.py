"""Writing a quilt as a ``btf-compressed/1`` folder: same basis and codec, new textures.

The output is an ordinary compressed BTF (``usdbtf decompress``/``info``/``package`` read it
unchanged): the basis image is rewritten from the same values, each coefficient texture is
the source texture's stored integers gathered through the position map (so quantisation
scale and bias carry over exactly and lossless codecs add no error), one texture at a time.
Extra entries in the metadata:

* ``source_metadata.physical_size_m`` scaled by output/source texels (same texel density);
* ``quilt``: provenance (options, sizes, seam error) and ``position_map``: the file
  ``quilt_positions.exr`` (float32; R = source column, G = source row with row 0 at the
  top, B = 1 for synthesised texels, 0 for padding).
"""
from __future__ import annotations

import copy
import logging
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..atomic import atomic_dir
from ..compress.codecs import Stored, get_codec
from ..compress.format import CompressedBTF, coefficient_file, write_basis, write_metadata
from ..imageio import write_image
from .core import QuiltResult

__all__ = ["POSITION_MAP", "write_quilt", "quilted_btf", "position_image", "read_position_map"]

log = logging.getLogger(__name__)

POSITION_MAP = "quilt_positions.exr"
_CURVE_FILES = ("error_curve.csv", "error_curve.png")


def position_image(q: QuiltResult, source_width: int) -> np.ndarray:
    """(H, W, 3) float32: source column, source row, synthesised flag."""
    y, x = np.divmod(q.positions, source_width)
    return np.stack([x, y, q.valid], axis=-1).astype(np.float32)


def read_position_map(folder) -> tuple[np.ndarray, np.ndarray]:
    """(source x, source y) int arrays (H, W) from a quilted folder's position map."""
    from ..imageio import read_image

    px, _ = read_image(Path(folder) / POSITION_MAP)
    return px[..., 0].astype(np.int64), px[..., 1].astype(np.int64)


def _gather(stored: Stored, flat: np.ndarray, shape) -> Stored:
    """A stored texture's integers gathered through flat source indices (scale, bias kept)."""
    pixels = np.take(stored.pixels.reshape(-1, stored.pixels.shape[-1]), flat, axis=0).reshape(*shape, -1)
    return Stored(pixels, stored.scale, stored.bias)


def quilted_btf(q: QuiltResult) -> CompressedBTF:
    """The quilt as an in-memory CompressedBTF (all k textures held: for small outputs; files
    go through :func:`write_quilt`, which streams)."""
    cbtf = q.source
    shape = q.positions.shape
    flat = q.positions.ravel()
    info = dict(cbtf.info, quilt=dict(q.record))
    return replace(cbtf, width=shape[1], height=shape[0], info=info,
                   coefficients=[_gather(st, flat, shape) for st in cbtf.coefficients])


def write_quilt(q: QuiltResult, out) -> dict:
    """Write the quilted compressed BTF to folder ``out`` atomically; returns its metadata's
    ``bytes`` record.  The source's folder (``q.source_folder``, when it was read from one) is
    recorded, and its error-curve files are copied when present (they describe the same basis)."""
    cbtf, source_folder = q.source, q.source_folder
    # Quilts are large (1024^2+ x k textures): encode time, not bytes, is what matters here.
    codec = get_codec(cbtf.codec).fastest()
    H, W = q.positions.shape
    flat = q.positions.ravel()
    record = copy.deepcopy(q.record)
    record.pop("_seconds", None)
    if source_folder is not None:
        record["source"]["path"] = str(source_folder)
    record["position_map"] = {"file": POSITION_MAP, "channels": {
        "R": "source column", "G": "source row (0 = top)", "B": "1 = synthesised, 0 = gutter padding"}}
    if not codec.lossless:
        record["note"] = f"{codec.name} textures were decoded and re-encoded (one more generation of loss)"
    info = {key: copy.deepcopy(v) for key, v in cbtf.info.items() if key not in ("bytes", "timings", "error_curve")}
    meta = dict(info.get("source_metadata") or {})
    size = meta.get("physical_size_m")
    if isinstance(size, (list, tuple)) and len(size) == 2:
        meta["physical_size_m"] = [float(size[0]) * W / cbtf.width, float(size[1]) * H / cbtf.height]
    info["source_metadata"] = meta
    info["quilt"] = record
    with atomic_dir(out) as tmp:
        (tmp / "coeff").mkdir()
        per = []
        headers = []
        for i, st in enumerate(cbtf.coefficients):
            gathered = _gather(st, flat, (H, W))
            per.append(codec.write(tmp / coefficient_file(codec, i), gathered, "data"))
            # Metadata needs only each texture's scale, bias and dtype: keep no pixels around.
            headers.append(Stored(np.empty((0, 0, st.pixels.shape[-1]), st.pixels.dtype), st.scale, st.bias))
            if (i + 1) % 50 == 0:
                log.info(f"  wrote {i + 1}/{cbtf.k} coefficient textures")
        header = replace(cbtf, width=W, height=H, coefficients=headers, info=info)
        basis_bytes = write_basis(header, tmp)
        header.info["bytes"] = {"basis": basis_bytes, "coefficients": int(sum(per)),
                                "payload": basis_bytes + int(sum(per)), "per_coefficient": per}
        if source_folder is not None:
            copied = [n for n in _CURVE_FILES if (Path(source_folder) / n).is_file()]
            for name in copied:
                shutil.copyfile(Path(source_folder) / name, tmp / name)
            if "error_curve.csv" in copied:
                header.info["error_curve"] = {"file": "error_curve.csv", "plot": "error_curve.png",
                                              "note": "of the source sample (same basis)"}
        write_image(tmp / POSITION_MAP, position_image(q, cbtf.width), color_space="data",
                    attributes={"compression": "zip"})
        write_metadata(header, tmp)
    return header.info["bytes"]

