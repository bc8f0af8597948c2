"""What usdbtf writes, and how to recognise a previous output of each kind.

``--force`` replaces an existing output only when it is a previous usdbtf output of the
same kind, recognised here by the format's own marker *and* by holding nothing the
format does not account for (a compressed folder into which someone copied their notes
is not replaced).  This module only reads: it knows each format's marker file or
attribute, not how to write one, so it sits below every writer.

============================  =======  ==========================================================
kind                          what     recognised by
============================  =======  ==========================================================
``btf-manifest/1``            folder   ``btf.json`` with that ``format``; only the listed images
                                       (and masks)
``btf-compressed/1``          folder   ``btf-compressed.json`` with that ``format``; only the
                                       basis, coefficient, error-curve and position-map files
``usdbtf-unwrap``             folder   ``unwrap.json`` with ``"tool": "usdbtf unwrap"``; only
                                       ``mesh.usda``, ``charts.png``, ``unwrap.json``
``usdbtf-capture``            folder   ``journal.jsonl``; only capture files (``frames/``, ...)
``usdbtf-sim-frames``         folder   only the simulator's frame files (``latest.tif``, ...)
``usdbtf-bench``              folder   ``results.json`` and ``report.md`` of ``usdbtf bench``
``usdbtf-bench-baseline/1``   folder   ``baseline.json`` with that ``format``: a benchmark
                                       baseline's storage (``usdbtf.bench.baselines``); only
                                       ``video.mp4`` (``video``), or one ``btf-compressed/1``
                                       folder ``viewNNNN`` per view it names (``pca-view``)
``usdbtf-asset``              file     a USD layer (or usdz) whose layer metadata holds
                                       ``customLayerData = {"usdbtf": {"output": ...}}``
``usdbtf-built-stage``        file     a USD layer whose layer metadata holds ``customLayerData =
                                       {"usdbtf": {"output": "usdbtf-built-stage"}}``: the stage
                                       ``usdbtf build`` writes to open (the scene, bound meshes
                                       quilted at measured scale)
``usdbtf-asset-textures``     folder   ``<stem>_textures`` beside a usdbtf asset; only packaged
                                       texture names (BTF codes, GPU tables and pages, the
                                       fallback's maps, the thumbnail; any texture format)
``usdbtf-render``             file     EXR/PNG with the image attribute ``usdbtf:output``
``usdbtf-board-image``        file     PNG with the image attribute ``usdbtf:output``
``usdbtf-board/1``            file     board JSON with that ``format``
``usdbtf-port``               file     one line naming a rig port (``/dev/...``, ``socket://...``,
                                       or a pty link)
``usdbtf-pty-link``           link     a symbolic link to ``/dev/pts/N``
============================  =======  ==========================================================
"""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

__all__ = ["MANIFEST", "COMPRESSED", "UNWRAP", "CAPTURE", "SIM_FRAMES", "BENCH", "BENCH_BASELINE", "ASSET",
           "ASSET_TEXTURES", "BUILT_STAGE", "RENDER", "BOARD_IMAGE", "BOARD", "PORT", "PTY_LINK", "OWNED", "FOLDER_KINDS",
           "RESUMABLE_KINDS", "IMAGE_ATTRIBUTE", "USD_MARKER_KEY", "identify", "is_kind", "usd_marker"]

MANIFEST = "btf-manifest/1"
COMPRESSED = "btf-compressed/1"
#: Every ``format`` a compressed folder may declare: ``/1.1`` adds a working-domain curve
#: (``domain``; written only when it is not linear, so older readers refuse such a folder
#: instead of reconstructing it without the curve).
COMPRESSED_FORMATS = ("btf-compressed/1", "btf-compressed/1.1")
UNWRAP = "usdbtf-unwrap"
CAPTURE = "usdbtf-capture"
SIM_FRAMES = "usdbtf-sim-frames"
BENCH = "usdbtf-bench"
BENCH_BASELINE = "usdbtf-bench-baseline/1"
ASSET = "usdbtf-asset"
ASSET_TEXTURES = "usdbtf-asset-textures"
BUILT_STAGE = "usdbtf-built-stage"
RENDER = "usdbtf-render"
BOARD_IMAGE = "usdbtf-board-image"
BOARD = "usdbtf-board/1"
PORT = "usdbtf-port"
PTY_LINK = "usdbtf-pty-link"
#: Not a recognised kind: a file its writer owns for its own reasons (the manifest inside
#: a capture folder the writer holds, a generated file of the repository).
OWNED = "owned"

FOLDER_KINDS = {MANIFEST, COMPRESSED, UNWRAP, CAPTURE, SIM_FRAMES, BENCH, BENCH_BASELINE, ASSET_TEXTURES}
#: Kinds a command continues in place instead of replacing (capture resumes, the simulator
#: keeps serving frames into its folder).
RESUMABLE_KINDS = {CAPTURE, SIM_FRAMES}

#: Image attribute (EXR header, PNG text chunk) naming the kind of a usdbtf-written image.
IMAGE_ATTRIBUTE = "usdbtf:output"
#: Key of the layer metadata (customLayerData) dictionary that marks a usdbtf-written layer.
USD_MARKER_KEY = "usdbtf"

# Marker file names, as the formats define them (tests check they match manifest.MANIFEST,
# compress.format.METADATA, unwrap's RECORD, ...; importing those modules here would make
# this module depend on every writer).
_MANIFEST_FILE = "btf.json"
_COMPRESSED_FILE = "btf-compressed.json"
_COMPRESSED_EXTRAS = {"error_curve.csv", "error_curve.png", "quilt_positions.exr"}
_UNWRAP_FILES = {"mesh.usda", "charts.png", "unwrap.json"}
_CAPTURE_FILES = re.compile(r"(btf\.json|journal\.jsonl|flat\.exr|\.lock|\.(tmp|hook)-.*|frames/[^/]*)")
# A benchmark baseline's record and stored files (usdbtf.bench.baselines: RECORD, VIDEO_FILE,
# VIEW_FOLDER).
_BASELINE_FILE = "baseline.json"
_BASELINE_VIDEO = "video.mp4"
_BASELINE_VIEW = "view{:04d}"
_SIM_FRAME_FILES = re.compile(r"(latest|s\d+|flat\d+|\.tmp-[^/]*)\.tif|\.[^/]*\.tmp-[^/]*")
# preview_albedo.png: the flat fallback of assets written before the fitted one; thumbnail.png:
# the thumbnail before issue 39's JPEG one.
_TEXTURE_FILES = re.compile(r"(basis\.\w+|coeff/c\d+\.\w+|preview_albedo\.png|gpu/[\w.-]+|thumbnail\.(png|jpg)"
                            r"|fallback/(diffuse|specular|roughness|normal)\.\w+"
                            r"|fallback/openpbr_(base|specular|fuzz|params|lobes|tangent|normal)\.\w+)")
#: Root and payload layer names a texture folder ``<stem>_textures`` sits beside.
_ASSET_LAYERS = ("_payload.usdc", "_payload.usda", ".usda", ".usdc", ".usd")
_PORT_TEXT = re.compile(r"(/dev/\S+|socket://\S+)\n?")
_MAX_MARKER_BYTES = 256 << 20   # a marker JSON larger than this is not one of ours


def usd_marker(kind: str = ASSET) -> dict:
    """The customLayerData entry a usdbtf writer puts on its USD layers."""
    return {USD_MARKER_KEY: {"output": kind}}


def _json(path: Path):
    try:
        if not path.is_file() or path.is_symlink() or path.stat().st_size > _MAX_MARKER_BYTES:
            return None
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _files(folder: Path) -> set[str] | None:
    """Every entry below ``folder`` as a relative POSIX path (folders only when empty);
    None when a symbolic link or something unreadable is in it."""
    out = set()
    try:
        for d, dirs, fs in os.walk(folder, onerror=_raise):
            base = Path(d)
            for name in dirs + fs:
                p = base / name
                if p.is_symlink():
                    return None
            if not dirs and not fs and base != folder:
                out.add(base.relative_to(folder).as_posix() + "/")
            out.update((base / f).relative_to(folder).as_posix() for f in fs)
    except OSError:
        return None
    return out


def _raise(exc):
    raise exc


def _only(folder: Path, allowed) -> bool:
    files = _files(folder)
    if files is None:
        return False
    if callable(allowed):
        return all(allowed(f) for f in files)
    return files <= set(allowed)


def _manifest(folder: Path) -> bool:
    doc = _json(folder / _MANIFEST_FILE)
    if not isinstance(doc, dict) or doc.get("format") != MANIFEST or not isinstance(doc.get("samples"), list):
        return False
    images = {s.get(key) for s in doc["samples"] if isinstance(s, dict) for key in ("image", "mask")}
    return _only(folder, {_MANIFEST_FILE} | {i for i in images if isinstance(i, str)})


def _compressed(folder: Path) -> bool:
    doc = _json(folder / _COMPRESSED_FILE)
    if not isinstance(doc, dict) or doc.get("format") not in COMPRESSED_FORMATS:
        return False
    entries = [doc.get("basis")] + list(doc.get("coefficients") or [])
    names = {e.get("file") for e in entries if isinstance(e, dict)}
    return _only(folder, {_COMPRESSED_FILE} | _COMPRESSED_EXTRAS | {n for n in names if isinstance(n, str)})


def _unwrap(folder: Path) -> bool:
    doc = _json(folder / "unwrap.json")
    return isinstance(doc, dict) and doc.get("tool") == "usdbtf unwrap" and _only(folder, _UNWRAP_FILES)


def _capture(folder: Path) -> bool:
    return (folder / "journal.jsonl").is_file() and _only(folder, _CAPTURE_FILES.fullmatch)


def _sim_frames(folder: Path) -> bool:
    return _only(folder, _SIM_FRAME_FILES.fullmatch)


def _bench(folder: Path) -> bool:
    doc = _json(folder / "results.json")
    return isinstance(doc, dict) and "machine" in doc and "sections" in doc and (folder / "report.md").is_file()


def _bench_baseline(folder: Path) -> bool:
    doc = _json(folder / _BASELINE_FILE)
    if not isinstance(doc, dict) or doc.get("format") != BENCH_BASELINE:
        return False
    if doc.get("baseline") == "video":
        return _only(folder, {_BASELINE_FILE, _BASELINE_VIDEO})
    views = doc.get("views")
    if doc.get("baseline") != "pca-view" or not isinstance(views, int) or not 0 < views < 100_000:
        return False
    # Exactly the views the record names, each a compressed folder holding only its own files.
    names = {_BASELINE_VIEW.format(v) for v in range(views)}
    try:
        found = {p.name for p in folder.iterdir()} - {_BASELINE_FILE}
    except OSError:
        return False
    return found == names and all(not (folder / n).is_symlink() and _compressed(folder / n) for n in names)


def _asset_textures(folder: Path) -> bool:
    if not folder.name.endswith("_textures"):
        return False
    stem = folder.name[:-len("_textures")]
    beside = [folder.parent / f"{stem}{suffix}" for suffix in _ASSET_LAYERS]
    return any(_usd_layer(p) == ASSET for p in beside) and _only(folder, _TEXTURE_FILES.fullmatch)


def _usd_layer(path: Path) -> str | None:
    if not path.is_file() or path.is_symlink():
        return None
    try:
        from pxr import Sdf, Tf
    except ImportError:      # pragma: no cover - usd-core is a dependency
        return None
    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path), metadataOnly=True)
    except Tf.ErrorException:
        return None
    if layer is None:
        return None
    mark = dict(layer.customLayerData).get(USD_MARKER_KEY)
    return mark.get("output") if isinstance(mark, dict) else None


def _image_kind(path: Path) -> str | None:
    if not path.is_file() or path.is_symlink():
        return None
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()      # clear it: OIIO prints unretrieved errors at exit
        return None
    try:
        return inp.spec().get_string_attribute(IMAGE_ATTRIBUTE, "") or None
    finally:
        inp.close()


def _port(path: Path) -> bool:
    """One line naming a port: a device, a socket URL, or the pty link rig-sim keeps."""
    try:
        if not path.is_file() or path.is_symlink() or path.stat().st_size >= 4096:
            return False
        text = path.read_text()
    except (OSError, UnicodeDecodeError):
        return False
    line = text[:-1] if text.endswith("\n") else text
    return _PORT_TEXT.fullmatch(text) is not None or (
        bool(line) and "\n" not in line and "\0" not in line and os.path.islink(line))


_FOLDERS = [(CAPTURE, _capture), (MANIFEST, _manifest), (COMPRESSED, _compressed), (UNWRAP, _unwrap),
            (BENCH, _bench), (BENCH_BASELINE, _bench_baseline), (ASSET_TEXTURES, _asset_textures),
            (SIM_FRAMES, _sim_frames)]


def identify(path) -> str | None:
    """The kind of usdbtf output at ``path`` (see the module table), or None when it is
    not one: missing, written by something else, or holding files the format does not
    account for."""
    path = Path(path)
    if path.is_symlink():
        try:
            return PTY_LINK if re.fullmatch(r"/dev/pts/\d+", os.readlink(path)) else None
        except OSError:
            return None
    if path.is_dir():
        if not any(path.iterdir()):
            return None
        return next((kind for kind, test in _FOLDERS if test(path)), None)
    if not path.is_file():
        return None
    suffix = path.suffix.lower()
    if suffix in (".usda", ".usdc", ".usd", ".usdz"):
        kind = _usd_layer(path)
        return kind if kind in (ASSET, BUILT_STAGE) else None
    if suffix in (".exr", ".png"):
        kind = _image_kind(path)
        return kind if kind in (RENDER, BOARD_IMAGE) else None
    if suffix == ".json":
        doc = _json(path)
        return BOARD if isinstance(doc, dict) and doc.get("format") == BOARD else None
    return PORT if _port(path) else None


def is_kind(path, kind: str) -> bool:
    """``identify(path) == kind``, checking only that kind (cheaper)."""
    path = Path(path)
    if kind in FOLDER_KINDS:
        test = dict(_FOLDERS)[kind]
        return path.is_dir() and not path.is_symlink() and any(path.iterdir()) and test(path)
    return identify(path) == kind
