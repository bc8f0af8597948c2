"""Machine-readable summaries of BTF inputs and compressed BTFs (``info --json``, ``compress --json``).

Both return plain dicts (JSON types only); the keys are documented in
docs/unattended-runs-errors-outputs.md ("Scripting").  The human-readable ``usdbtf info`` text is written from the same dicts.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["compressed_summary", "btf_summary", "direction_count", "image_size"]


def compressed_summary(folder) -> dict:
    """What a ``btf-compressed/1`` folder holds: k, sizes, error, colour, provenance."""
    from .compress import read_compressed
    from .compress.coverage import coverage_summary, read_coverage_record
    from .compress.format import FORMAT, FORMAT_DOMAIN, METADATA, folder_bytes

    folder = Path(folder)
    c = read_compressed(folder)
    info = c.info
    sizes = dict(info.get("bytes") or {})
    sizes.pop("per_coefficient", None)
    sizes["metadata"] = (folder / METADATA).stat().st_size
    sizes["folder"] = folder_bytes(folder)
    estimated = (info.get("estimated_error") or {}).get("linear")
    prov = info.get("provenance") or {}
    return {"path": str(folder), "kind": "compressed", "format": FORMAT if c.domain.is_linear else FORMAT_DOMAIN,
            "solver": info.get("solver"), "codec": c.codec, "k": c.k, "samples": c.n_samples,
            "domain": c.domain.metadata(),
            "width": c.width, "height": c.height, "bytes": sizes,
            "estimated_error": ({"percent": estimated.get("percent"), "rmse": estimated.get("rmse"),
                                 "psnr_db": estimated.get("psnr_db"), "domain": "linear"} if estimated else None),
            "working_space": c.working_space, "ocio_config": c.ocio_config,
            "source": {"color_space": c.source.get("color_space"), "bit_depth": c.source.get("bit_depth"),
                       "path": prov.get("source", c.source.get("path"))},
            "usdbtf_version": prov.get("version"),
            "coverage": coverage_summary(read_coverage_record(info, str(folder / METADATA)), c.n_samples, c.width,
                                         c.height)}


def direction_count(directions) -> int:
    """Distinct (theta, phi) directions among ``directions`` (N, 2) degrees, to 1e-6."""
    import numpy as np

    return len({tuple(np.round(d, 6)) for d in directions})


def image_size(btf) -> tuple[int, int]:
    """(width, height): the size of the image files themselves when the samples are files on
    disk (a manifest's declared size is checked against them), else the reader's size."""
    from .imageio import read_info

    paths = getattr(btf, "paths", None)
    if paths and Path(paths[0]).is_file():
        first = read_info(paths[0])
        return first.width, first.height
    return btf.width, btf.height


def btf_summary(path, btf=None) -> dict:
    """What a measured BTF input holds: format, samples, size, encoding, directions; for
    Bonn ``.btf`` files also ``file`` (signature, colour model, component counts, ...: the
    reader's ``describe()``).  ``btf``: the opened input, when the caller has it."""
    if btf is None:
        from .io import open_btf

        btf = open_btf(path)
    width, height = image_size(btf)
    describe = getattr(btf, "describe", None)
    ignored = getattr(btf, "ignored", None) or []
    return {"path": str(path), "kind": "btf", "format": btf.metadata.get("format") or "btf-manifest/1",
            "samples": btf.n_samples, "width": width, "height": height,
            "bit_depth": btf.bit_depth, "color_space": btf.color_space,
            "views": direction_count(btf.sampling.view), "lights": direction_count(btf.sampling.light),
            "interpolated": int(btf.interpolated.sum()), "ignored_members": len(ignored),
            "file": describe() if describe else None}
