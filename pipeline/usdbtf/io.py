"""One entry point for every BTF input format: :func:`open_btf`.

Accepted inputs
---------------
* a btf-manifest/1 folder (one holding ``btf.json``) or the ``btf.json`` file itself
  -> :func:`usdbtf.manifest.read_manifest`;
* a UBO2003 / UTIA / ATRIUM zip archive, or a folder of ``tv###_pv###`` view folders
  (directly or under one top-level folder) -> :func:`usdbtf.ubo.read_ubo`;
* a Bonn binary BTF file (``.btf``: UBO2014's DFMF and its FMF/PVF/BDI siblings, recognised
  by its signature) -> :func:`usdbtf.ubo2014.read_ubo2014`.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

from . import manifest, ubo, ubo2014
from .errors import BTFError, link_error
from .model import BTF

__all__ = ["open_btf", "open_compressed", "ACCEPTED"]

ACCEPTED = ("a btf-manifest/1 folder (with btf.json) or its btf.json file; "
            "a UBO2003-layout .zip archive (UBO2003, UTIA, ATRIUM); a folder of tv###_pv### view folders "
            "(UBO2003 layout); or a Bonn .btf file (UBO2014 DFMF, FMF, PVF, BDI)")


def open_btf(path, *, color_space: str | None = None, **kw) -> BTF:
    """Open any supported BTF input as a streaming :class:`~usdbtf.model.BTF`.

    Parameters
    ----------
    path : folder, ``btf.json`` file, ``.zip`` archive or ``.btf`` file (see the module docstring).
    color_space : override of the files' encoding; UBO/UTIA/ATRIUM and ``.btf`` data only (a manifest declares
        its own, and a conflicting override would silently mis-decode it).
    kw : ``ocio_config``, ``working_space`` -- passed to the reader.

    Raises BTFError naming ``path`` when it does not exist or is none of the accepted formats.
    The BTF's ``path`` is ``path`` as given.
    """
    p = Path(path)
    btf = _read(p, color_space, kw)
    btf.path = str(p)
    return btf


def _read(p: Path, color_space: str | None, kw: dict) -> BTF:
    """The reader for ``p`` (see :func:`open_btf`)."""
    # A link that cannot be followed (a loop, a dangling target) reads as absent to exists()
    # and is_file(): say so, naming the link, rather than "missing" or "unrecognised".
    for link in (p, p / manifest.MANIFEST):
        error = link_error(link)
        if error is not None:
            raise error
    if not p.exists():
        raise BTFError(f"{p}: no such file or folder")
    is_manifest = (p.is_dir() and (p / manifest.MANIFEST).is_file()) or (p.is_file() and p.suffix.lower() == ".json")
    if is_manifest:
        if color_space is not None:
            raise BTFError(f"{p}: a manifest declares its own color_space; the override {color_space!r} "
                           "applies to UBO2003 data only")
        return manifest.read_manifest(p, **kw)
    # A file named .btf goes to the Bonn reader even when damaged, so the error says why.
    if p.is_file() and (p.suffix.lower() == ".btf" or ubo2014.is_ubo2014(p)):
        return ubo2014.read_ubo2014(p, color_space=color_space, **kw)
    # A file named .zip goes to the UBO reader even when damaged, so the error says "corrupt zip".
    if p.is_file() and (p.suffix.lower() == ".zip" or zipfile.is_zipfile(p)):
        return ubo.read_ubo(p, color_space=color_space, **kw)
    if p.is_dir() and ubo.is_ubo(p):
        return ubo.read_ubo(p, color_space=color_space, **kw)
    kind = "folder" if p.is_dir() else "file"
    raise BTFError(f"{p}: unrecognised BTF input ({kind}); accepted: {ACCEPTED}")


def open_compressed(path, *, material: str | None = None, lod: str | None = None, lazy: bool = False):
    """A :class:`~usdbtf.compress.format.CompressedBTF` from a compressed folder or a
    packaged USD asset (.usda/.usdc/.usd/.usdz; ``material`` picks one of several BTF
    materials, ``lod`` a level-of-detail variant; ``lazy``: an asset's coefficients read when
    asked for, :func:`usdbtf.usd.material.read_btf`)."""
    p = Path(path)
    from .usd.read import load_btf
    from .usdstage import USD_SUFFIXES

    if p.suffix.lower() in USD_SUFFIXES:
        return load_btf(p, material=material, lod=lod, lazy=lazy)
    if material is not None or lod is not None:
        raise BTFError(f"{p}: --material and --lod apply to USD assets only")
    from .compress.format import read_compressed

    return read_compressed(p)
