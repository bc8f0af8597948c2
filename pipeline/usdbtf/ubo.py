"""Read-only access to BTFs in the Bonn UBO2003 layout, also used by UTIA and ATRIUM.

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
view folder, when named ``tv###_pv###``, must agree with it.  Any image extension
OpenImageIO reads is accepted.

The datasets that use it, and where each convention comes from
---------------------------------------------------------------
* **UBO2003** (Bonn): 81 views x 81 lights (rings 0/15/30/45/60/75 deg with
  1/6/12/18/20/24 azimuths), 256 x 256 8-bit sRGB JPEGs named
  ``tv030_pv030/00008 tl000 pl000 tv030 pv030.jpg`` (an index, then the angles: the
  archives on the Bonn BTF database's UBO2003 download page; btf-extractor's ``ubo2003.py``
  parses the same names, by position from the end).
* **UTIA** (Prague, btf.utia.cas.cz, "Data description"): file names follow Bonn's
  with underscores and no index, ``tv000_pv000/tl000_pl000_tv000_pv000.png``; images
  are "PNG (colour space sRGB 8-bits/channel) or HDR OpenEXR (colour space XYZ (illum.
  D65) half-float/channel)".  An OpenEXR file that does not declare its colour space
  is therefore read as CIE XYZ D65 (OCIO's "CIE XYZ-D65 - Scene-referred", alias
  ``cie_xyz_d65_scene``), never through a hand-written matrix.  UTIA notes that where
  light and camera coincide the light was moved to a nearby direction listed on its
  site; file names keep the nominal angles, and so does usdbtf.
* **ATRIUM** (Bonn): 81 x 81 at 800 x 800, 8-bit and HDR; btf-extractor's
  ``AtriumHdr`` reads zips of Radiance ``.hdr`` files named ``tl000 pl000 tv000 pv000.hdr``
  whose resolution line is ``+X 256 -Y 256``.  Per the Radiance format that is a
  column-major image (X the slow axis); OpenImageIO reads it as such and reports EXIF
  orientation 5, which usdbtf applies (``ImageBufAlgo.reorient``).  btf-extractor
  instead rewrites the line to ``-Y 256 +X 256`` and flips the rows, which yields the
  same image rotated by 90 degrees; with no published ground truth usdbtf follows the
  file's declared orientation.  Radiance files are read as linear Rec.709 (their
  default primaries).

Colour spaces when the caller names none: integer files (JPEG, PNG) sRGB; float files
the space the file declares (``oiio:ColorSpace``, EXR chromaticities of CIE XYZ), else
XYZ D65 for OpenEXR (UTIA), linear Rec.709 for Radiance ``.hdr`` (ATRIUM), the working
space for anything else.

Zip archives are read in place
------------------------------
Nothing is extracted: each member is decompressed when its sample is read, into an
anonymous in-memory file (``memfd_create``; elsewhere an already-unlinked temporary
file) that OpenImageIO reads by its ``/proc/self/fd`` path.  Nothing is ever written
under ``$TMPDIR``, so a killed run leaves nothing behind.  A corrupt member (bad CRC)
is reported, naming ``archive:member``, when its sample is read.

Members never vanish silently: an absolute or ``..`` member name is an error naming
the member; a member stored twice is an error; members that are not samples (text
files, previews, macOS resource forks) are listed in :attr:`UBOBTF.ignored` and by
``usdbtf info``.  In a folder, a file or linked folder that resolves outside the
folder is an error.
"""
from __future__ import annotations

import contextlib
import functools
import os
import re
import tempfile
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np
import OpenImageIO as oiio

from . import color
from .errors import BTFError
from .imageio import native_stderr_captured, oiio_error, read_info
from .model import BTF, FileBTF, validate_sampling
from .sampling import Sampling

__all__ = ["read_ubo", "is_ubo", "UBOBTF", "parse_name", "DEFAULT_INTEGER_SPACE", "DEFAULT_FLOAT_SPACE",
           "UTIA_EXR_SPACE", "RADIANCE_SPACE"]

# Colour spaces assumed when the caller names none and the file declares none (module docstring).
DEFAULT_INTEGER_SPACE = "sRGB Encoded Rec.709 (sRGB)"
DEFAULT_FLOAT_SPACE = "scene_linear"
UTIA_EXR_SPACE = "CIE XYZ-D65 - Scene-referred"
RADIANCE_SPACE = "Linear Rec.709 (sRGB)"
_XYZ_CHROMATICITIES = (1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1 / 3, 1 / 3)

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

    Returns ``(entries, ignored)``: entries a list of ``(view, light, member)`` in view-major
    order; ignored the members that are not samples (non-images, hidden files, images outside
    view folders whose names carry no angles, such as previews).  Images inside a
    ``tv###_pv###`` folder must parse and agree with the folder; when nothing parses at all
    the dataset is refused.
    """
    entries, ignored = [], []
    for member in members:
        parts = PurePosixPath(member).parts
        if not parts or _is_junk(parts) or not _is_image(member):
            ignored.append(member)
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
        images = [m for m in ignored if _is_image(m) and not _is_junk(PurePosixPath(m).parts)]
        hint = f"; {len(images)} other image(s) ignored, e.g. {images[0]!r}" if images else ""
        raise BTFError(f"{where}: no UBO2003 images found (expected files named like {_EXAMPLE!r}){hint}")

    # View-major order on the canonical directions (phi in [0, 360), phi = 0 at the pole) so
    # that the order does not depend on file-name prefixes or on how the pole's phi is spelt.
    def key(entry):
        (tv, pv), (tl, pl), member = entry
        pv = 0.0 if tv == 0 else pv % 360.0
        pl = 0.0 if tl == 0 else pl % 360.0
        return (tv, pv, tl, pl, member)

    entries.sort(key=key)
    return entries, ignored


def _sampling(entries, where: str):
    """(Sampling, names) for the selected entries, directions checked (range, duplicates)."""
    sampling = Sampling(np.array([e[0] for e in entries], np.float64), np.array([e[1] for e in entries], np.float64))
    names = [e[2] for e in entries]
    try:
        validate_sampling(sampling, names)
    except BTFError as exc:
        raise BTFError(f"{where}: {exc}") from None
    return sampling, names


@contextlib.contextmanager
def _member_file(zf: zipfile.ZipFile, arcname: str, label: str):
    """A path OpenImageIO can open holding zip member ``arcname``'s bytes, in memory only.

    Linux: an anonymous ``memfd`` read through ``/proc/self/fd/N``; elsewhere an unlinked
    temporary file through ``/dev/fd/N``.  Either way nothing is left on disk, even after
    kill -9.  ``label`` (``archive:member``) names the member in errors.
    """
    try:
        with zf.open(arcname) as src:
            data = src.read()
    except (zipfile.BadZipFile, zlib.error, EOFError, RuntimeError, NotImplementedError, ValueError, KeyError) as exc:
        # BadZipFile: bad CRC / header; RuntimeError: encrypted; NotImplementedError: compression method.
        raise BTFError(f"{label}: cannot read this member of the archive ({exc})") from None
    except OSError as exc:
        raise BTFError(f"{label}: cannot read the archive ({exc.strerror or exc})") from None
    if hasattr(os, "memfd_create"):
        fd = os.memfd_create("usdbtf-zip-member", getattr(os, "MFD_CLOEXEC", 0))
        try:
            with open(fd, "wb", closefd=False) as f:
                f.write(data)
            yield f"/proc/self/fd/{fd}"
        finally:
            os.close(fd)
    else:  # pragma: no cover - non-Linux
        with tempfile.TemporaryFile() as f:
            f.write(data)
            f.flush()
            f.seek(0)
            yield f"/dev/fd/{f.fileno()}"


def _header(path: str) -> tuple[int, tuple | None]:
    """(EXIF orientation, EXR chromaticities or None) from an image file's header."""
    inp = oiio.ImageInput.open(path)
    if inp is None:
        return 1, None
    try:
        spec = inp.spec()
        chroma = spec.getattribute("chromaticities")
        return spec.get_int_attribute("Orientation", 1), (tuple(float(c) for c in chroma) if chroma else None)
    finally:
        inp.close()


@dataclass
class UBOBTF(FileBTF):
    """A :class:`FileBTF` read from a UBO2003-layout zip or folder (UBO2003, UTIA, ATRIUM).

    Attributes (beyond FileBTF)
    ---------------------------
    source : str, the zip archive or folder the data came from.
    members : list[str], per sample, its path inside ``source`` (posix separators).
    archive : bool, True for a zip read in place; then ``paths`` are the member names in
        the archive (as stored) rather than files on disk.
    ignored : list[str], members that are not samples (see the module docstring).
    orientation : int, EXIF orientation of the files (1 = as stored; ATRIUM's HDRs are 5).
    """

    source: str = ""
    members: list = field(default_factory=list)
    archive: bool = False
    ignored: list = field(default_factory=list)
    orientation: int = 1

    def __post_init__(self):
        if not self.archive:
            super().__post_init__()
            return
        if len(self.paths) != len(self.sampling):
            raise BTFError(f"{len(self.paths)} members for {len(self.sampling)} samples")
        BTF.__post_init__(self)

    def _zipfile(self) -> zipfile.ZipFile:
        # One handle per process: a forked worker must not share the parent's file offset.
        held = self.__dict__.get("_zip")
        if held is None or held[0] != os.getpid():
            try:
                self._zip = (os.getpid(), zipfile.ZipFile(self.source))
            except (OSError, zipfile.BadZipFile) as exc:
                raise BTFError(f"{self.source}: cannot reopen the archive ({exc})") from None
        return self._zip[1]

    def read_one(self, i: int, rows=None) -> np.ndarray:
        label = f"{self.source}:{self.members[i]}" if self.archive else self.paths[i]
        with (_member_file(self._zipfile(), self.paths[i], label) if self.archive
              else contextlib.nullcontext(self.paths[i])) as path:
            try:
                return self.read_file(path, rows)
            except BTFError as exc:
                raise BTFError(str(exc).replace(path, label)) from None

    def read_file(self, path, rows=None) -> np.ndarray:
        if self.orientation == 1:
            return super().read_file(path, rows)
        return _read_reoriented(path, self, rows)

    def __getstate__(self):
        state = dict(self.__dict__)
        state.pop("_zip", None)  # a copy (e.g. in a worker) opens its own handle
        return state

    def close(self) -> None:
        """Close the archive handle (idempotent); a later read reopens it."""
        held = self.__dict__.pop("_zip", None)
        if held is not None and held[0] == os.getpid():
            held[1].close()


def _read_reoriented(path: str, btf: UBOBTF, rows) -> np.ndarray:
    """Read a whole image through OIIO's ImageBuf, apply its EXIF orientation, check it."""
    with native_stderr_captured():
        buf = oiio.ImageBufAlgo.reorient(oiio.ImageBuf(path))
    if buf.has_error:
        raise BTFError(f"{path}: cannot read image ({oiio_error(buf)})")
    spec = buf.spec()
    if (spec.width, spec.height) != (btf.width, btf.height):
        raise BTFError(f"{path}: image is {spec.width}x{spec.height}, expected {btf.width}x{btf.height}")
    if str(spec.format) != btf.bit_depth:
        raise BTFError(f"{path}: bit depth {spec.format} differs from the dataset's {btf.bit_depth}")
    pixels = np.asarray(buf.get_pixels(spec.format))
    pixels = np.repeat(pixels[..., :1], 3, axis=-1) if spec.nchannels == 1 else pixels[..., :3]
    if rows is not None:
        pixels = pixels[rows[0]:rows[1]]
    if pixels.dtype.kind == "f":
        from .model import check_finite

        check_finite(pixels, path)
    return np.ascontiguousarray(pixels)


def _zip_members(path: Path):
    """Open the archive; return (ZipFile, {member name with '/' separators: stored name}).

    Absolute or ``..`` member names and names stored twice are errors naming the member."""
    if not zipfile.is_zipfile(path):
        raise BTFError(f"{path}: not a zip archive (or the archive is truncated or corrupt)")
    try:
        zf = zipfile.ZipFile(path)
        infos = {}
        for info in zf.infolist():
            name = info.filename.replace("\\", "/")
            if info.is_dir():
                continue
            parts = PurePosixPath(name).parts
            if name.startswith("/") or re.match(r"[A-Za-z]:", name) or ".." in parts:
                zf.close()
                raise BTFError(f"{path}: member {info.filename!r} has an absolute or '..' path that points "
                               "outside the archive; refusing the archive")
            if name in infos:  # a dict would silently keep one of the two
                zf.close()
                raise BTFError(f"{path}: member {name!r} is stored twice in the archive")
            infos[name] = info.filename
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise BTFError(f"{path}: corrupt zip archive ({exc})") from None
    return zf, infos


def _folder_members(folder: Path):
    """Files under ``folder`` (posix paths relative to it), following links that stay inside.

    A file or linked folder that resolves outside ``folder`` is an error naming it: it would
    otherwise be read from elsewhere, or (a linked view folder) skipped without a word."""
    root = os.path.realpath(folder)
    members, seen = [], set()
    for top, dirs, files in os.walk(folder, followlinks=True):
        real = os.path.realpath(top)
        if real in seen:  # a link back to a folder already walked
            dirs[:] = []
            continue
        seen.add(real)
        dirs.sort()
        rel = Path(top).relative_to(folder)
        for name in sorted(files) + [d for d in dirs if os.path.islink(os.path.join(top, d))]:
            target = os.path.realpath(os.path.join(top, name))
            if os.path.commonpath([root, target]) != root:
                raise BTFError(f"{folder}: {(rel / name).as_posix()} links to {target}, outside the folder")
        members.extend((rel / f).as_posix() for f in sorted(files))
    return members


def read_ubo(path, *, color_space: str | None = None, ocio_config: str | None = None,
             working_space: str = color.WORKING_SPACE) -> UBOBTF:
    """Open a UBO2003-layout zip archive or folder (UBO2003, UTIA, ATRIUM) as a streaming
    :class:`UBOBTF`.

    Parameters
    ----------
    path : a ``.zip`` archive or a folder (with or without one top-level folder inside).
    color_space : OCIO name of the files' encoding.  Default per the module docstring:
        sRGB for integer files; for float files the declared space, else XYZ D65 (OpenEXR,
        UTIA), linear Rec.709 (Radiance, ATRIUM), the working space otherwise.
    ocio_config, working_space : where decoded pixels go (see :class:`usdbtf.model.BTF`).

    Returns
    -------
    UBOBTF with S samples in view-major order (view theta, view phi, light theta, light phi),
    angles in degrees, ``names`` the member paths.  Pixels are read on demand (zip members in
    place); images of the wrong size or bit depth, or corrupt members, raise BTFError when read.

    Raises BTFError naming ``path`` (and the member) for: a missing path, a file that is not
    a readable zip, an absolute or ``..`` member name, a member stored twice, a link out of
    the folder, no matching images, unparseable names, a view folder that disagrees with a
    file name, repeated (view, light) pairs, theta outside [0, 90].
    """
    path = Path(path)
    if path.is_dir():
        entries, ignored = _select(_folder_members(path), str(path))
        sampling, names = _sampling(entries, str(path))
        paths = [os.fspath(path / n) for n in names]
        return _probe(paths, sampling, names, ignored, path, False, color_space, ocio_config, working_space)
    if not path.exists():
        raise BTFError(f"{path}: no such file or folder")
    zf, infos = _zip_members(path)
    with zf:
        entries, ignored = _select(list(infos), str(path))
        sampling, names = _sampling(entries, str(path))
        btf = _probe([infos[n] for n in names], sampling, names, ignored, path, zf, color_space, ocio_config,
                     working_space)
    btf.close()
    return btf


def _default_space(info, path: str, orientation_chroma) -> str:
    """The colour space of a dataset whose caller named none (see the module docstring)."""
    if info.bit_depth in ("uint8", "uint16"):
        return DEFAULT_INTEGER_SPACE
    ext = PurePosixPath(path).suffix.lower()
    chroma = orientation_chroma[1]
    if chroma is not None and np.allclose(chroma, _XYZ_CHROMATICITIES, atol=1e-4):
        return UTIA_EXR_SPACE
    if info.color_space and ext != ".hdr":  # OIIO labels every .hdr lin_rec709: not a declaration
        return info.color_space
    return {".exr": UTIA_EXR_SPACE, ".hdr": RADIANCE_SPACE}.get(ext, DEFAULT_FLOAT_SPACE)


def _flavour(names, ext: str, width: int) -> str:
    """A label for ``info``: which database the naming and files look like (a guess)."""
    stem = PurePosixPath(names[0]).name.lower()
    if ext == ".hdr" or width == 800:
        return "ATRIUM (UBO2003 layout)"
    if ext == ".exr" or stem.startswith("tl"):
        return "UTIA (UBO2003 layout)"
    return "UBO2003"


def _probe(paths, sampling, names, ignored, source: Path, zf, color_space, ocio_config, working_space) -> UBOBTF:
    label = f"{source}:{names[0]}" if zf else paths[0]
    with (_member_file(zf, paths[0], label) if zf else contextlib.nullcontext(paths[0])) as first:
        try:
            info = read_info(first)
            header = _header(first)
            if header[0] in (5, 6, 7, 8):  # rotated by 90 degrees: width and height swap
                info = type(info)(info.path, info.height, info.width, info.channels, info.bit_depth, info.color_space)
            space = color.resolve_space(color_space or _default_space(info, names[0], header), ocio_config)
            if info.bit_depth not in ("uint8", "uint16", "half", "float"):
                raise BTFError(f"{first}: unsupported bit depth {info.bit_depth}")
            flavour = _flavour(names, PurePosixPath(names[0]).suffix.lower(), info.width)
            btf = UBOBTF(sampling=sampling, width=info.width, height=info.height, color_space=space,
                         bit_depth=info.bit_depth, names=names, working_space=working_space, ocio_config=ocio_config,
                         metadata={"format": flavour}, paths=list(paths), source=os.fspath(source),
                         members=list(names), archive=bool(zf), ignored=list(ignored), orientation=header[0])
            return btf
        except BTFError as exc:
            msg = str(exc).replace(first, label)
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
