"""The btf-manifest/1 format: a folder with ``btf.json`` and one image per sample.

``btf.json``::

    {"format": "btf-manifest/1", "color_space": "<OCIO name>", "width": W, "height": H,
     "samples": [{"image": "<file>", "view": [theta, phi], "light": [theta, phi]}, ...]}

Angles in degrees; images in any format OpenImageIO reads; extra keys are kept
(per sample, e.g. ``"interpolated": true``; top level, e.g. ``"physical_size_m"``).

A sample may name a mask, ``"mask": "<file>"`` (``usdbtf rectify`` writes one for every sample
whose frame clipped under the window): a W x H single-channel 8-bit PNG in the ``Raw`` colour
space (data, not colour: OpenImageIO writes no colour chunk for it, and the text chunk
``usdbtf:colorSpace = "Raw"`` says so, since a PNG without one reads as sRGB), 255 where the
texel was not recorded (the sensor clipped within a pixel of its footprint: its value is not
a measurement), 0 elsewhere.  A sample without one
was recorded everywhere.  :func:`read_manifest` checks every mask's header and
:func:`read_masks` its pixels.
"""
from __future__ import annotations

import contextlib
import contextvars
import os
from pathlib import Path, PurePosixPath
from typing import Iterable

import numpy as np

from . import color, jsontext
from .atomic import atomic_dir
from .errors import BTFError
from .imageio import numpy_dtype, read_attribute, read_image, read_info, write_image
from .model import FileBTF, validate_sampling
from .outputs import MANIFEST as _MANIFEST_KIND
from .sampling import Sampling

__all__ = ["FORMAT", "MANIFEST", "read_manifest", "read_masks", "write_manifest", "encode_for_file",
           "FORMAT_ATTRIBUTES", "MASK_SPACE", "outside_paths_allowed", "outside_paths_are_allowed"]

FORMAT = "btf-manifest/1"
MANIFEST = "btf.json"
_RESERVED = {"format", "color_space", "width", "height", "samples"}
#: The colour space a sample's mask declares: data, no colour transform applies.
MASK_SPACE = "Raw"
#: The PNG text chunk that declares it (OpenImageIO reads a PNG without colour chunks as sRGB).
MASK_SPACE_ATTRIBUTE = "usdbtf:colorSpace"
_MASK_ON = 255

# Writer options per file extension: fast lossless PNG (the zlib level barely changes size on
# noisy texture data, but level 9 is 10x slower to write), lossless zip EXR, raw TIFF.
FORMAT_ATTRIBUTES = {
    "png": {"png:compressionLevel": 3},
    "exr": {"compression": "zip"},
    "tif": {"compression": "none"},   # uncompressed: ~5x faster to decode than PNG, 1.7x the bytes
    "jpg": {"Compression": "jpeg:95"},
}


def _angle_pair(value, key, label, path):
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise BTFError(f"{path}: sample {label}: {key!r} must be [theta, phi] in degrees, got {value!r}")
    return [float(value[0]), float(value[1])]


_OUTSIDE = contextvars.ContextVar("usdbtf_outside_paths_allowed", default=False)


@contextlib.contextmanager
def outside_paths_allowed(allowed: bool = True):
    """Within the block, manifests may name images outside their folder
    (``--allow-outside-paths``)."""
    token = _OUTSIDE.set(bool(allowed))
    try:
        yield
    finally:
        _OUTSIDE.reset(token)


def outside_paths_are_allowed() -> bool:
    """True inside :func:`outside_paths_allowed` (a process that re-opens a manifest, such as
    a Dask worker, passes this on)."""
    return _OUTSIDE.get()


def _image_path(folder: Path, real_folder: str, name: str, manifest: Path, label: str, outside: bool) -> str:
    """The image file of a sample, confined to the manifest's folder unless ``outside``:
    no absolute names, no ``..``, no symbolic link that leads out."""
    if not name or "\0" in name:
        raise BTFError(f"{manifest}: sample {label}: \"image\" must be a file name")
    if not outside and "/" not in name and name not in (".", ".."):
        # A plain name in the folder: confined unless it is itself a link (one lstat, not the
        # lstat per path component of realpath -- 10,800 samples read in a tenth of the time).
        path = os.path.join(os.fspath(folder), name)
        if not os.path.islink(path):
            return path
    path = os.fspath(folder / name)
    if outside:
        return path
    parts = PurePosixPath(name).parts
    if PurePosixPath(name).is_absolute() or ".." in parts:
        raise BTFError(f"{manifest}: sample {label}: image {name!r} is outside the manifest's folder "
                       "(absolute or '..'); pass --allow-outside-paths to read it anyway")
    real = os.path.realpath(path)
    if not real.startswith(real_folder + os.sep):
        raise BTFError(f"{manifest}: sample {label}: image {name!r} leads outside the manifest's folder (through "
                       "a symbolic link); pass --allow-outside-paths to read it anyway")
    return path


def read_manifest(folder, *, ocio_config: str | None = None, working_space: str = color.WORKING_SPACE,
                  allow_outside_paths: bool | None = None) -> FileBTF:
    """Open a manifest folder as a streaming :class:`FileBTF` (pixels are read on demand).

    Every image must lie inside the manifest's folder unless ``allow_outside_paths``
    (default: :func:`outside_paths_allowed`).  The first image's header must agree with
    the declared size, so nothing is allocated for a size the files do not have.
    """
    outside = _OUTSIDE.get() if allow_outside_paths is None else bool(allow_outside_paths)
    folder = Path(folder)
    path = folder / MANIFEST if folder.is_dir() else folder
    folder = path.parent
    if not os.path.lexists(path):
        raise BTFError(f"{path}: manifest not found")
    doc = jsontext.load(path, "JSON manifest")
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise BTFError(f"{path}: \"format\" must be {FORMAT!r}, got {doc.get('format') if isinstance(doc, dict) else doc!r}")
    for key in ("width", "height"):
        if not isinstance(doc.get(key), int) or isinstance(doc.get(key), bool) or doc[key] <= 0:
            raise BTFError(f"{path}: {key!r} must be a positive integer, got {doc.get(key)!r}")
    space = doc.get("color_space")
    if not isinstance(space, str) or not space:
        raise BTFError(f"{path}: \"color_space\" must name an OCIO colour space")
    try:
        space = color.resolve_space(space, ocio_config)
    except BTFError as exc:
        raise BTFError(f"{path}: {exc}") from None
    samples = doc.get("samples")
    if not isinstance(samples, list) or not samples:
        raise BTFError(f"{path}: \"samples\" is empty or missing; a BTF needs at least one sample")
    views, lights, paths, names, interp = [], [], [], [], []
    real_folder = os.path.realpath(folder)
    for i, s in enumerate(samples):
        label = f"#{i}"
        if not isinstance(s, dict) or not isinstance(s.get("image"), str):
            raise BTFError(f"{path}: sample {label} needs an \"image\" file name")
        label = f"#{i} ({s['image']})"
        views.append(_angle_pair(s.get("view"), "view", label, path))
        lights.append(_angle_pair(s.get("light"), "light", label, path))
        paths.append(_image_path(folder, real_folder, s["image"], path, label, outside))
        names.append(s["image"])
        interp.append(bool(s.get("interpolated", False)))
        if "mask" in s:
            _check_mask(_mask_path(folder, real_folder, s, path, label, outside), doc, label)
    sampling = Sampling(np.array(views), np.array(lights))
    validate_sampling(sampling, [f"{path.name} sample #{i} ({n})" for i, n in enumerate(names)])
    extra = {k: v for k, v in doc.items() if k not in _RESERVED}
    first = read_info(paths[0])
    if (first.width, first.height) != (doc["width"], doc["height"]):
        raise BTFError(f"{paths[0]}: image is {first.width}x{first.height}, but {path} declares "
                       f"{doc['width']}x{doc['height']}")
    btf = FileBTF.probe(paths, sampling, space, width=doc["width"], height=doc["height"], names=names,
                        interpolated=np.array(interp), ocio_config=ocio_config, working_space=working_space,
                        metadata=extra)
    return btf


def _mask_path(folder: Path, real_folder: str, sample: dict, manifest: Path, label: str, outside: bool) -> str:
    if not isinstance(sample["mask"], str):
        raise BTFError(f"{manifest}: sample {label}: \"mask\" must be a file name, got {sample['mask']!r}")
    return _image_path(folder, real_folder, sample["mask"], manifest, label + " mask", outside)


def _check_mask(path: str, doc: dict, label: str) -> None:
    """A mask's header: the manifest's size, one 8-bit channel, the Raw colour space."""
    if not os.path.isfile(path):
        raise BTFError(f"{path}: sample {label}: mask not found")
    info = read_info(path)
    if (info.width, info.height) != (doc["width"], doc["height"]):
        raise BTFError(f"{path}: sample {label}: mask is {info.width}x{info.height}, but the manifest declares "
                       f"{doc['width']}x{doc['height']}")
    if info.channels != 1 or info.bit_depth != "uint8":
        raise BTFError(f"{path}: sample {label}: a mask must be one 8-bit channel, got {info.channels} "
                       f"{info.bit_depth} channel(s)")
    declared = read_attribute(path, MASK_SPACE_ATTRIBUTE)
    if declared != MASK_SPACE:
        raise BTFError(f"{path}: sample {label}: a mask is data and declares {MASK_SPACE_ATTRIBUTE} = "
                       f"{MASK_SPACE!r}, got {declared or info.color_space!r}")


def read_masks(folder, *, allow_outside_paths: bool | None = None) -> dict[int, np.ndarray]:
    """{sample index: (H, W) bool, True where the texel was not recorded} for every sample of
    the manifest at ``folder`` that names a mask (the others were recorded everywhere).

    Each mask is checked (:func:`read_manifest`'s header checks, then only the values 0 and 255),
    and where the manifest's ``rectify.saturated`` report gives the sample's flagged share, the
    mask must hold that share (to the report's 6 decimals)."""
    outside = _OUTSIDE.get() if allow_outside_paths is None else bool(allow_outside_paths)
    folder = Path(folder)
    path = folder / MANIFEST if folder.is_dir() else folder
    folder = path.parent
    doc = jsontext.load(path, "JSON manifest")
    if not isinstance(doc, dict) or not isinstance(doc.get("samples"), list):
        raise BTFError(f"{path}: not a {FORMAT} manifest")
    report = doc.get("rectify") if isinstance(doc.get("rectify"), dict) else {}
    shares = {e.get("index"): e.get("share") for e in report.get("saturated") or [] if isinstance(e, dict)}
    real_folder = os.path.realpath(folder)
    out = {}
    for i, s in enumerate(doc["samples"]):
        if not isinstance(s, dict) or "mask" not in s:
            continue
        label = f"#{i} ({s.get('image')})"
        mask_file = _mask_path(folder, real_folder, s, path, label, outside)
        _check_mask(mask_file, doc, label)
        pixels, _ = read_image(mask_file)
        values = pixels[..., 0]
        if not np.isin(values, (0, _MASK_ON)).all():
            raise BTFError(f"{mask_file}: sample {label}: a mask holds only 0 (recorded) and {_MASK_ON} (not "
                           f"recorded), found {sorted(set(np.unique(values).tolist()) - {0, _MASK_ON})[:3]}")
        mask = values == _MASK_ON
        share = shares.get(i)
        if isinstance(share, (int, float)) and abs(float(mask.mean()) - share) > 6e-7:
            raise BTFError(f"{mask_file}: sample {label}: the mask flags {mask.mean():.6f} of the texels, the "
                           f"manifest's rectify.saturated says {share}")
        out[i] = mask
    return out


def encode_for_file(linear: np.ndarray, processor: color.Processor, bit_depth: str) -> np.ndarray:
    """Working-space float (..., 3) -> file values in ``processor.dst`` at ``bit_depth``.

    Integer depths clip to [0, 1] and round to nearest; float depths clamp below at 0 and
    are stored as is above: radiance is never negative, and every reader refuses negative
    values (:func:`usdbtf.model.check_finite`), so a reconstruction's ringing below zero or
    an out-of-gamut colour in the file's primaries must not make an unreadable file.
    """
    enc = processor.apply(linear)
    dtype = numpy_dtype(bit_depth)
    if np.dtype(dtype).kind == "u":
        top = np.iinfo(dtype).max
        return np.rint(np.clip(enc, 0.0, 1.0) * top).astype(dtype)
    return np.maximum(enc, 0.0).astype(dtype)


def _sample_file(i: int, view, light, ext: str) -> str:
    return f"{i:05d}_tv{view[0]:05.1f}_pv{view[1]:05.1f}_tl{light[0]:05.1f}_pl{light[1]:05.1f}.{ext}"


def write_manifest(folder, sampling: Sampling, images: Iterable[np.ndarray], *, color_space: str,
                   bit_depth: str = "uint8", ext: str = "png", array_space: str = color.WORKING_SPACE,
                   ocio_config: str | None = None, interpolated=None, metadata: dict | None = None,
                   attributes: dict | None = None, masks: dict | None = None) -> Path:
    """Write a manifest folder atomically.

    Parameters
    ----------
    images : iterable of S arrays (H, W, 3), float, scene-linear in ``array_space``, in sample order.
    color_space : OCIO space the files are encoded in (e.g. "sRGB Encoded Rec.709 (sRGB)" for 8-bit).
    bit_depth : "uint8", "uint16", "half" or "float".
    ext : file extension, picks the OIIO writer.
    interpolated : optional (S,) bool, marks filled samples.
    metadata : extra top-level keys (e.g. {"physical_size_m": [0.05, 0.05]}).
    masks : optional {sample index: (H, W) bool, True where not recorded}: each written beside
        its sample as ``<sample file stem>_mask.png`` (see the module docstring).
    """
    space = color.resolve_space(color_space, ocio_config)
    proc = color.processor(array_space, space, ocio_config)
    attrs = dict(FORMAT_ATTRIBUTES.get(ext, {}), **(attributes or {}))
    interpolated = np.zeros(len(sampling), bool) if interpolated is None else np.asarray(interpolated, bool)
    entries = []
    width = height = None
    with atomic_dir(folder, kind=_MANIFEST_KIND) as tmp:
        count = 0
        for i, img in enumerate(images):
            if i >= len(sampling):
                raise BTFError(f"more images than the {len(sampling)} samples of the sampling")
            img = np.asarray(img)
            if img.ndim != 3 or img.shape[2] != 3:
                raise BTFError(f"sample #{i}: expected an (H, W, 3) image, got {img.shape}")
            if width is None:
                height, width = img.shape[:2]
            elif img.shape[:2] != (height, width):
                raise BTFError(f"sample #{i}: image is {img.shape[1]}x{img.shape[0]}, expected {width}x{height}")
            if not np.isfinite(img).all():
                raise BTFError(f"sample #{i}: pixel values include NaN or Inf")
            name = _sample_file(i, sampling.view[i], sampling.light[i], ext)
            write_image(tmp / name, encode_for_file(img, proc, bit_depth), color_space=space, attributes=attrs)
            entry = {"image": name, "view": [float(x) for x in sampling.view[i]],
                     "light": [float(x) for x in sampling.light[i]]}
            if interpolated[i]:
                entry["interpolated"] = True
            if masks and i in masks:
                mask = np.asarray(masks[i], bool)
                if mask.shape != (height, width):
                    raise BTFError(f"sample #{i}: mask is {mask.shape}, expected {(height, width)}")
                entry["mask"] = f"{Path(name).stem}_mask.png"
                write_image(tmp / entry["mask"], np.where(mask, _MASK_ON, 0).astype(np.uint8),
                            color_space=MASK_SPACE,
                            attributes={**FORMAT_ATTRIBUTES["png"], MASK_SPACE_ATTRIBUTE: MASK_SPACE})
            entries.append(entry)
            count += 1
        if count != len(sampling):
            raise BTFError(f"got {count} images for {len(sampling)} samples")
        doc = {"format": FORMAT, "color_space": space, "width": width, "height": height}
        doc.update(metadata or {})
        doc["samples"] = entries
        (tmp / MANIFEST).write_text(jsontext.dumps(doc) + "\n")
    return Path(folder)
