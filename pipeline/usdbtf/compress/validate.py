"""Validation of ``btf-compressed.json`` before anything is read or allocated.

:func:`check_metadata` turns the parsed document into typed, checked values, or raises
:class:`~usdbtf.errors.BTFError` naming the file and the key: types, lengths, finite
scales and biases, k against the texture files present, direction counts and ranges,
texture files confined to the folder, and the memory the textures will take.
:func:`usdbtf.compress.format.read_compressed` calls it; it knows nothing about writing.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np

from ..errors import BTFError
from ..imageio import BIT_DEPTHS
from ..model import validate_sampling
from ..resources import require_memory
from ..sampling import Sampling
from ..outputs import COMPRESSED_FORMATS
from .codecs import CODECS, Codec
from .domain import LINEAR, Domain, domain_from_metadata

__all__ = ["Metadata", "TextureEntry", "check_metadata", "MAX_SIDE", "MAX_K"]

#: Largest texture side and basis count a compressed BTF may declare.
MAX_SIDE = 65536
MAX_K = 4096
_KNOWN = {"format", "domain", "usdbtf_version", "width", "height", "k", "n_samples", "codec", "working_space",
          "ocio_config", "source", "color_matrix", "basis", "coefficients", "samples"}


@dataclass(frozen=True)
class TextureEntry:
    """One stored texture: its file (absolute, inside the folder) and de-quantisation."""

    file: Path
    name: str
    scale: np.ndarray
    bias: np.ndarray
    bit_depth: str | None


@dataclass
class Metadata:
    """The checked contents of ``btf-compressed.json``."""

    width: int
    height: int
    k: int
    codec: Codec
    sampling: Sampling
    interpolated: np.ndarray
    basis: TextureEntry
    layout: dict
    coefficients: list
    color_matrix: np.ndarray
    working_space: str
    ocio_config: str | None
    source: dict
    info: dict = field(default_factory=dict)
    domain: Domain = LINEAR


class _Doc:
    """Typed access to one JSON document, every error naming the file and the key."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, key: str, problem: str):
        raise BTFError(f"{self.path}: {key}: {problem}")

    def get(self, obj: dict, key: str, where: str = ""):
        name = f"{where}{key}"
        if not isinstance(obj, dict):
            self.fail(where.rstrip(".") or "document", f"must be an object, got {_kind(obj)}")
        if key not in obj:
            self.fail(name, "missing")
        return obj[key]

    def integer(self, value, key: str, lo: int, hi: int) -> int:
        if not isinstance(value, int) or isinstance(value, bool):
            self.fail(key, f"must be an integer, got {_short(value)}")
        if not lo <= value <= hi:
            self.fail(key, f"must be in {lo}..{hi}, got {value}")
        return value

    def string(self, value, key: str, *, optional: bool = False) -> str | None:
        if value is None and optional:
            return None
        if not isinstance(value, str) or not value:
            self.fail(key, f"must be a non-empty string, got {_short(value)}")
        return value

    def numbers(self, value, key: str, length: int | None = None) -> np.ndarray:
        if not isinstance(value, list) or not all(_number(v) for v in value):
            self.fail(key, f"must be a list of numbers, got {_short(value)}")
        if length is not None and len(value) != length:
            self.fail(key, f"must have {length} entries, got {len(value)}")
        arr = np.asarray(value, np.float64)
        bad = np.flatnonzero(~np.isfinite(arr))
        if len(bad):
            self.fail(f"{key}[{bad[0]}]", f"is {value[bad[0]]}, not a finite number")
        return arr

    def file(self, folder: Path, value, key: str) -> Path:
        name = self.string(value, key)
        pure = PurePosixPath(name)
        if "\0" in name or pure.is_absolute() or ".." in pure.parts:
            self.fail(key, f"{name!r} is not a file name inside the folder")
        path = folder / name
        real, root = os.path.realpath(path), os.path.realpath(folder)
        if not real.startswith(root + os.sep):
            self.fail(key, f"{name!r} leads outside the folder (symbolic link)")
        if not os.path.isfile(path):
            self.fail(key, f"texture file {name} is missing")
        return path


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _kind(v) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean", type(None): "null"}.get(
        type(v), type(v).__name__)


def _short(v) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def _directions(doc: _Doc, samples, key: str) -> np.ndarray:
    value = doc.get(samples, key, "samples.")
    name = f"samples.{key}"
    if not isinstance(value, list) or not value:
        doc.fail(name, f"must be a non-empty list of [theta, phi] pairs, got {_short(value)}")
    for i, pair in enumerate(value):
        if not (isinstance(pair, list) and len(pair) == 2 and all(_number(x) for x in pair)):
            doc.fail(f"{name}[{i}]", f"must be [theta, phi] in degrees, got {_short(pair)}")
        if not all(math.isfinite(x) for x in pair):
            doc.fail(f"{name}[{i}]", f"{pair} is not finite")
        if not 0.0 <= pair[0] <= 90.0:
            doc.fail(f"{name}[{i}]", f"theta {pair[0]} is outside [0, 90] degrees")
    return np.asarray(value, np.float64)


def _layout(doc: _Doc, value, k: int, n: int) -> dict:
    if value is None:
        return {"kind": "columns"}
    if not isinstance(value, dict) or value.get("kind") not in ("columns", "tiles"):
        doc.fail("basis.layout", f"must be {{\"kind\": \"columns\"}} or a tiles layout, got {_short(value)}")
    if value["kind"] == "columns":
        return {"kind": "columns"}
    views = doc.integer(value.get("views"), "basis.layout.views", 1, n)
    lights = doc.integer(value.get("lights"), "basis.layout.lights", 1, n)
    grid = value.get("grid")
    if not (isinstance(grid, list) and len(grid) == 2):
        doc.fail("basis.layout.grid", f"must be [rows, cols], got {_short(grid)}")
    rows = doc.integer(grid[0], "basis.layout.grid[0]", 1, MAX_K)
    cols = doc.integer(grid[1], "basis.layout.grid[1]", 1, MAX_K)
    if views * lights != n:
        doc.fail("basis.layout", f"{views} views x {lights} lights is not the {n} samples")
    if rows * cols < k:
        doc.fail("basis.layout.grid", f"{rows} x {cols} tiles cannot hold k = {k} vectors")
    return {"kind": "tiles", "views": views, "lights": lights, "grid": [rows, cols]}


def _texture(doc: _Doc, folder: Path, entry, key: str, channels: int) -> TextureEntry:
    if not isinstance(entry, dict):
        doc.fail(key, f"must be an object, got {_short(entry)}")
    path = doc.file(folder, doc.get(entry, "file", key + "."), key + ".file")
    scale = doc.numbers(doc.get(entry, "scale", key + "."), key + ".scale", channels)
    bias = doc.numbers(doc.get(entry, "bias", key + "."), key + ".bias", channels)
    depth = entry.get("bit_depth")
    if depth is not None and depth not in ("uint8", "uint16", "float16", "half", "float32", "float"):
        doc.fail(key + ".bit_depth", f"{_short(depth)} is not a stored bit depth")
    return TextureEntry(path, entry["file"], scale, bias, depth)


def check_metadata(doc, folder, path) -> Metadata:
    """Check the parsed ``btf-compressed.json`` of ``folder`` (at ``path``); see the module docstring."""
    folder, path = Path(folder), Path(path)
    d = _Doc(path)
    if not isinstance(doc, dict):
        d.fail("document", f"must be a JSON object, got {_kind(doc)}")
    if doc.get("format") not in COMPRESSED_FORMATS:
        d.fail("format", f"{_short(doc.get('format'))} is not {' or '.join(map(repr, COMPRESSED_FORMATS))}")
    domain = domain_from_metadata(doc.get("domain"), str(path))
    if doc["format"] == COMPRESSED_FORMATS[0] and not domain.is_linear:
        d.fail("domain", f"a {domain.name} working domain needs format {COMPRESSED_FORMATS[1]!r}")
    codec_name = d.string(d.get(doc, "codec"), "codec")
    if codec_name not in CODECS:
        d.fail("codec", f"unknown codec {codec_name!r} (known: {', '.join(CODECS)})")
    width = d.integer(d.get(doc, "width"), "width", 1, MAX_SIDE)
    height = d.integer(d.get(doc, "height"), "height", 1, MAX_SIDE)
    k = d.integer(d.get(doc, "k"), "k", 1, MAX_K)

    samples = d.get(doc, "samples")
    if not isinstance(samples, dict):
        d.fail("samples", f"must be an object with view and light lists, got {_kind(samples)}")
    views, lights = _directions(d, samples, "view"), _directions(d, samples, "light")
    if len(views) != len(lights):
        d.fail("samples", f"{len(views)} views but {len(lights)} lights; one of each per sample")
    n = len(views)
    if "n_samples" in doc:
        d.integer(doc["n_samples"], "n_samples", n, n)
    sampling = Sampling(views, lights)
    try:
        validate_sampling(sampling, [f"#{i}" for i in range(n)])
    except BTFError as exc:
        d.fail("samples", str(exc))
    interp = np.zeros(n, bool)
    listed = samples.get("interpolated", [])
    if not isinstance(listed, list) or not all(isinstance(i, int) and not isinstance(i, bool) for i in listed):
        d.fail("samples.interpolated", f"must be a list of sample indices, got {_short(listed)}")
    for i in listed:
        d.integer(i, "samples.interpolated[]", 0, n - 1)
        interp[i] = True

    matrix = d.get(doc, "color_matrix")
    if not (isinstance(matrix, list) and len(matrix) == 3):
        d.fail("color_matrix", f"must be 3 rows of 3 numbers, got {_short(matrix)}")
    matrix = np.stack([d.numbers(row, f"color_matrix[{r}]", 3) for r, row in enumerate(matrix)])

    b = d.get(doc, "basis")
    basis = _texture(d, folder, b, "basis", k)
    layout = _layout(d, b.get("layout"), k, n)
    coeffs = d.get(doc, "coefficients")
    if not isinstance(coeffs, list):
        d.fail("coefficients", f"must be a list of k = {k} texture entries, got {_kind(coeffs)}")
    if len(coeffs) != k:
        d.fail("coefficients", f"lists {len(coeffs)} coefficient textures for k = {k}")
    entries = [_texture(d, folder, e, f"coefficients[{i}]", 3) for i, e in enumerate(coeffs)]

    working = d.string(d.get(doc, "working_space"), "working_space")
    ocio_config = d.string(doc.get("ocio_config"), "ocio_config", optional=True)
    source = doc.get("source", {})
    if not isinstance(source, dict):
        d.fail("source", f"must be an object, got {_kind(source)}")
    if source.get("color_space") is not None:
        d.string(source["color_space"], "source.color_space")
    if source.get("bit_depth") is not None and source["bit_depth"] not in BIT_DEPTHS:
        d.fail("source.bit_depth", f"{_short(source['bit_depth'])} is not one of {', '.join(BIT_DEPTHS)}")

    if "coverage" in doc:      # a partial compress's record (.coverage), checked where it is read
        from .coverage import read_coverage_record

        read_coverage_record(doc, str(path))

    # Stored textures: up to 2 bytes a channel, plus the float32 de-quantised copies readers make.
    require_memory(k * width * height * 3 * (2 + 4) + n * k * 8, f"{path} (k = {k}, {width}x{height} texels)")
    info = {key: v for key, v in doc.items() if key not in _KNOWN}
    info["usdbtf_version"] = doc.get("usdbtf_version")
    return Metadata(width, height, k, CODECS[codec_name], sampling, interp, basis, layout, entries, matrix,
                    working, ocio_config, source, info, domain)
