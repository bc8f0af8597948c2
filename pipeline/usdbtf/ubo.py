"""Read-only access to BTFs in the Bonn UBO2003 layout (also used by UTIA and ATRIUM).

Layout
------
A zip archive or a folder holding one folder per view direction, one image per
light direction inside it::

    UBO_CORDUROY256/                       (optional top-level folder)
        tv000_pv000/00000 tl000 pl000 tv000 pv000.jpg
        ...
        tv030_pv030/00008 tl000 pl000 tv030 pv030.jpg
        ...

Angles are integer degrees in the file name: ``tl``/``pl`` light theta/phi,
``tv``/``pv`` view theta/phi (theta from the normal, phi the azimuth).  Spaces
or underscores separate the fields.  The angles come from the file *name*; the
view folder, when named ``tv###_pv###``, must agree with it.  The standard set
is 81 views x 81 lights (rings 0/15/30/45/60/75 deg with 1/6/12/18/20/24
azimuths) of 256 x 256 8-bit sRGB JPEGs; ATRIUM also ships ``.hdr``/``.exr``
variants.  Any image extension OpenImageIO reads is accepted.

Zip archives are extracted up front (at :func:`read_ubo` time, so a corrupt
member is reported at once) into a private ``tempfile.mkdtemp`` folder under
the system temp directory (``$TMPDIR``).  That folder is removed when the
returned BTF object is garbage-collected or at interpreter exit, whichever comes
first (``weakref.finalize``), or earlier by calling :meth:`UBOBTF.close`.  Its
``paths`` point into that folder, so do not keep them beyond the object's life.
"""
from __future__ import annotations

import functools
import os
import re
import shutil
import tempfile
import weakref
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np
import OpenImageIO as oiio

from . import colour
from .errors import BTFError
from .imageio import read_info
from .model import FileBTF, validate_sampling
from .sampling import Sampling

__all__ = ["read_ubo", "is_ubo", "UBOBTF", "parse_name", "DEFAULT_INTEGER_SPACE", "DEFAULT_FLOAT_SPACE"]

# Colour spaces assumed when the caller names none: UBO2003 JPEGs are 8-bit sRGB; float files
# (ATRIUM HDR) are taken to be in the working space already.
DEFAULT_INTEGER_SPACE = "sRGB Encoded Rec.709 (sRGB)"
DEFAULT_FLOAT_SPACE = "scene_linear"

_ANGLE = r"(\d+(?:\.\d+)?)"  # 3-digit integers in practice; a decimal part costs nothing to accept
_SEP = r"[ _]+"
_NAME_RE = re.compile(rf"tl{_ANGLE}{_SEP}pl{_ANGLE}{_SEP}tv{_ANGLE}{_SEP}pv{_ANGLE}", re.IGNORECASE)
_VIEW_DIR_RE = re.compile(rf"tv{_ANGLE}{_SEP}pv{_ANGLE}", re.IGNORECASE)
# A file name that looks like it meant to carry angles (used to tell near-misses from previews).
_ANGLE_HINT_RE = re.compile(r"t[lv][ _]?\d", re.IGNORECASE)
_EXAMPLE = "tv030_pv030/00008 tl000 pl000 tv030 pv030.jpg"


@functools.lru_cache(maxsize=1)
def _image_extensions() -> frozenset:
    """Lower-case file extensions (no dot) that this OpenImageIO build can read."""
    exts = set()
    for entry in oiio.get_string_attribute("extension_list").split(";"):
        fmt, _, names = entry.partition(":")
        if fmt in ("null", "term"):  # pseudo-formats, not files on disk
            continue
        exts.update(n.lower() for n in names.split(",") if n)
    return frozenset(exts)


def _is_image(name: str) -> bool:
    return PurePosixPath(name).suffix[1:].lower() in _image_extensions()


def _is_junk(parts) -> bool:
    """Hidden files and macOS resource forks (``__MACOSX/``, ``._name``) that zips often carry."""
    return any(p.startswith(".") or p == "__MACOSX" for p in parts)


def parse_name(name: str):
    """Angles from a UBO2003 file name.

    Returns ``(view (theta, phi), light (theta, phi))`` in degrees, or None when the
    name holds no ``tl### pl### tv### pv###`` group.
    """
    m = _NAME_RE.search(PurePosixPath(name).stem)
    if m is None:
        return None
    tl, pl, tv, pv = (float(g) for g in m.groups())
    return (tv, pv), (tl, pl)


def _select(members, where: str):
    """Pick the sample images among ``members`` (posix paths relative to the dataset root).

    Returns a list of ``(view, light, member)`` in view-major order.  Images inside a
    ``tv###_pv###`` folder must parse and agree with the folder; images elsewhere that
    do not parse (previews, thumbnails) are ignored, unless nothing parses at all.
    """
    entries, ignored = [], []
    for member in members:
        parts = PurePosixPath(member).parts
        if not parts or _is_junk(parts) or not _is_image(member):
            continue
        name = parts[-1]
        folder = _VIEW_DIR_RE.fullmatch(parts[-2]) if len(parts) > 1 else None
        parsed = parse_name(name)
        if parsed is None:
            if folder is not None or _ANGLE_HINT_RE.search(name):
                raise BTFError(f"{where}: {member}: cannot parse angles from the file name "
                               f"(expected 'tl### pl### tv### pv###', e.g. {_EXAMPLE!r})")
            ignored.append(member)
            continue
        view, light = parsed
        if folder is not None:
            fview = (float(folder.group(1)), float(folder.group(2)))
            if fview != view:
                raise BTFError(f"{where}: {member}: view in the file name (tv {view[0]:g}, pv {view[1]:g}) "
                               f"disagrees with its folder {parts[-2]!r} (tv {fview[0]:g}, pv {fview[1]:g})")
        entries.append((view, light, member))
    if not entries:
        hint = f"; {len(ignored)} other image(s) ignored, e.g. {ignored[0]!r}" if ignored else ""
        raise BTFError(f"{where}: no UBO2003 images found (expected files named like {_EXAMPLE!r}){hint}")

    # View-major order on the canonical directions (phi in [0, 360), phi = 0 at the pole) so
    # that the order does not depend on file-name prefixes or on how the pole's phi is spelt.
    def key(entry):
        (tv, pv), (tl, pl), member = entry
        pv = 0.0 if tv == 0 else pv % 360.0
        pl = 0.0 if tl == 0 else pl % 360.0
        return (tv, pv, tl, pl, member)

    entries.sort(key=key)
    return entries


def _sampling(entries, where: str):
    """(Sampling, names) for the selected entries, directions checked (range, duplicates)."""
    sampling = Sampling(np.array([e[0] for e in entries], np.float64), np.array([e[1] for e in entries], np.float64))
    names = [e[2] for e in entries]
    try:
        validate_sampling(sampling, names)
    except BTFError as exc:
        raise BTFError(f"{where}: {exc}") from None
    return sampling, names


@dataclass
class UBOBTF(FileBTF):
    """A :class:`FileBTF` read from a UBO2003 zip or folder.

    Attributes (beyond FileBTF)
    ---------------------------
    source : str, the zip archive or folder the data came from.
    members : list[str], per sample, its path inside ``source`` (posix separators).
    cache_dir : str or None, the temporary extraction folder (zip input only).
    """

    source: str = ""
    members: list = field(default_factory=list)
    cache_dir: str | None = None

    def read_one(self, i: int, rows=None) -> np.ndarray:
        try:
            return super().read_one(i, rows)
        except BTFError as exc:
            raise BTFError(self._explain(str(exc), i)) from None

    def _explain(self, message: str, i: int) -> str:
        """Put ``source:member`` in place of a cache path, so the user sees the file they own."""
        if self.cache_dir is None:
            return message  # folder input: the path already names the folder and the member
        return message.replace(self.paths[i], f"{self.source}:{self.members[i]}")

    def __getstate__(self):
        # A pickled copy (e.g. sent to a worker process) reads the same cache but must not own it.
        state = dict(self.__dict__)
        state.pop("_finalizer", None)
        return state

    def close(self) -> None:
        """Remove the extraction folder now (idempotent); the object cannot read pixels after."""
        fin = getattr(self, "_finalizer", None)
        if fin is not None:
            fin()


def _remove_cache(path: str, owner_pid: int) -> None:
    # A forked worker holds a copy of the object; its garbage collection must not delete the
    # parent's files, so only the creating process cleans up.
    if os.getpid() == owner_pid:
        shutil.rmtree(path, ignore_errors=True)


def _zip_members(path: Path):
    """Open the archive; return (ZipFile, {member name with '/' separators: ZipInfo})."""
    if not zipfile.is_zipfile(path):
        raise BTFError(f"{path}: not a zip archive (or the archive is truncated or corrupt)")
    try:
        zf = zipfile.ZipFile(path)
        infos = {}
        for info in zf.infolist():
            name = info.filename.replace("\\", "/")
            if info.is_dir():
                continue
            if name in infos:  # a dict would silently keep one of the two
                zf.close()
                raise BTFError(f"{path}: member {name!r} is stored twice in the archive")
            infos[name] = info
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise BTFError(f"{path}: corrupt zip archive ({exc})") from None
    return zf, infos


def _extract(zf: zipfile.ZipFile, infos, names, path: Path, cache: str):
    """Copy members ``names`` to flat files in ``cache``; returns their paths in order."""
    out = []
    for k, member in enumerate(names):
        # Flat, index-prefixed names: no member path (``..``, absolute, backslashes) can
        # escape the cache, and the original base name keeps the extension OIIO dispatches on.
        dst = os.path.join(cache, f"{k:05d}_{PurePosixPath(member).name}")
        try:
            with zf.open(infos[member]) as src, open(dst, "wb") as f:
                shutil.copyfileobj(src, f, 1 << 20)
        except (zipfile.BadZipFile, zlib.error, EOFError, RuntimeError, NotImplementedError, ValueError) as exc:
            # BadZipFile: bad CRC / header; RuntimeError: encrypted; NotImplementedError: compression method.
            raise BTFError(f"{path}: member {member!r} cannot be extracted ({exc})") from None
        except OSError as exc:
            raise BTFError(f"{path}: member {member!r}: cannot write to the temporary folder {cache} ({exc})") from None
        out.append(dst)
    return out


def _folder_members(folder: Path):
    members = []
    for root, dirs, files in os.walk(folder):
        dirs.sort()
        rel = Path(root).relative_to(folder)
        members.extend((rel / f).as_posix() for f in sorted(files))
    return members


def read_ubo(path, *, color_space: str | None = None, ocio_config: str | None = None,
             working_space: str = colour.WORKING_SPACE) -> UBOBTF:
    """Open a UBO2003 zip archive or folder as a streaming :class:`FileBTF` (a :class:`UBOBTF`).

    Parameters
    ----------
    path : a ``.zip`` archive or a folder (with or without one top-level folder inside).
    color_space : OCIO name of the files' encoding.  Default: "sRGB Encoded Rec.709 (sRGB)"
        for integer (8/16-bit) files, "scene_linear" for half/float files.
    ocio_config, working_space : where decoded pixels go (see :class:`usdbtf.model.BTF`).

    Returns
    -------
    UBOBTF with S samples in view-major order (view theta, view phi, light theta, light phi),
    angles in degrees, ``names`` the member paths.  Pixels are read on demand; images
    of the wrong size or bit depth raise BTFError when read.

    Raises BTFError naming ``path`` (and the member) for: a missing path, a file that is not
    a readable zip, no matching images, unparseable names, a view folder that disagrees with
    a file name, repeated (view, light) pairs, theta outside [0, 90].
    """
    path = Path(path)
    if path.is_dir():
        entries = _select(_folder_members(path), str(path))
        sampling, names = _sampling(entries, str(path))
        paths = [os.fspath(path / n) for n in names]
        return _probe(paths, sampling, names, path, None, color_space, ocio_config, working_space)
    if not path.exists():
        raise BTFError(f"{path}: no such file or folder")
    zf, infos = _zip_members(path)
    with zf:
        entries = _select(list(infos), str(path))
        sampling, names = _sampling(entries, str(path))
        cache = tempfile.mkdtemp(prefix=f"usdbtf-ubo-{path.stem[:40]}-")
        try:
            paths = _extract(zf, infos, names, path, cache)
            btf = _probe(paths, sampling, names, path, cache, color_space, ocio_config, working_space)
        except BaseException:
            shutil.rmtree(cache, ignore_errors=True)
            raise
    btf._finalizer = weakref.finalize(btf, _remove_cache, cache, os.getpid())
    return btf


def _probe(paths, sampling, names, source: Path, cache, color_space, ocio_config, working_space) -> UBOBTF:
    try:
        info = read_info(paths[0])
        if color_space is None:
            color_space = DEFAULT_INTEGER_SPACE if info.bit_depth in ("uint8", "uint16") else DEFAULT_FLOAT_SPACE
        space = colour.resolve_space(color_space, ocio_config)
        return UBOBTF.probe(paths, sampling, space, names=names, ocio_config=ocio_config,
                            working_space=working_space, source=os.fspath(source), members=list(names),
                            cache_dir=cache)
    except BTFError as exc:
        msg = str(exc)
        if cache:  # name the member the user knows, not its copy in the cache
            msg = msg.replace(paths[0], f"{source}:{names[0]}")
        if os.fspath(source) not in msg:
            msg = f"{source}: {msg}"
        raise BTFError(msg) from None


def is_ubo(path) -> bool:
    """Cheap sniff: does ``path`` look like UBO2003 data?  Never raises.

    True for a zip whose member list (central directory only; nothing is decompressed)
    has an image named ``... tl### pl### tv### pv###``, and for a folder that has
    ``tv###_pv###`` subfolders (directly or under one top-level folder) or such images
    directly inside.
    """
    path = Path(path)
    try:
        if path.is_dir():
            return _folder_looks_ubo(path, depth=1)
        if path.is_file() and zipfile.is_zipfile(path):
            with zipfile.ZipFile(path) as zf:
                return any(_is_image(n) and parse_name(PurePosixPath(n.replace("\\", "/")).name) is not None
                           for n in zf.namelist())
    except (OSError, zipfile.BadZipFile, ValueError):
        pass
    return False


def _folder_looks_ubo(folder: Path, depth: int) -> bool:
    with os.scandir(folder) as it:
        entries = [e for e in it if not e.name.startswith(".")]
    for e in entries:
        if e.is_dir() and _VIEW_DIR_RE.fullmatch(e.name):
            return True
        if e.is_file() and _is_image(e.name) and parse_name(e.name) is not None:
            return True
    if depth > 0:
        return any(_folder_looks_ubo(Path(e.path), depth - 1) for e in entries if e.is_dir())
    return False
