"""Machine-readable summaries of BTF inputs and compressed BTFs (``info --json``, ``compress --json``).

Both return plain dicts (JSON types only); the keys are documented in the README
("Scripting").  The human-readable ``usdbtf info`` text is written from the same dicts.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["compressed_summary", "btf_summary"]


def compressed_summary(folder) -> dict:
    """What a ``btf-compressed/1`` folder holds: k, sizes, error, colour, provenance."""
    from .compress import read_compressed
    from .compress.format import FORMAT, METADATA, folder_bytes

    folder = Path(folder)
    c = read_compressed(folder)
    info = c.info
    sizes = dict(info.get("bytes") or {})
    sizes.pop("per_coefficient", None)
    sizes["metadata"] = (folder / METADATA).stat().st_size
    sizes["folder"] = folder_bytes(folder)
    estimated = (info.get("estimated_error") or {}).get("linear")
    prov = info.get("provenance") or {}
    return {"path": str(folder), "kind": "compressed", "format": FORMAT,
            "solver": info.get("solver"), "codec": c.codec, "k": c.k, "samples": c.n_samples,
            "width": c.width, "height": c.height, "bytes": sizes,
            "estimated_error": ({"percent": estimated.get("percent"), "rmse": estimated.get("rmse"),
                                 "psnr_db": estimated.get("psnr_db"), "domain": "linear"} if estimated else None),
            "working_space": c.working_space, "ocio_config": c.ocio_config,
            "source": {"color_space": c.source.get("color_space"), "bit_depth": c.source.get("bit_depth"),
                       "path": prov.get("source", c.source.get("path"))},
            "usdbtf_version": prov.get("version")}


def btf_summary(path) -> dict:
    """What a measured BTF input holds: samples, size, encoding, directions."""
    from .io import open_btf

    btf = open_btf(path)
    return {"path": str(path), "kind": "btf", "samples": btf.n_samples, "width": btf.width, "height": btf.height,
            "bit_depth": btf.bit_depth, "color_space": btf.color_space,
            "views": len({tuple(v) for v in btf.sampling.view}), "lights": len({tuple(v) for v in btf.sampling.light}),
            "interpolated": int(btf.interpolated.sum())}
