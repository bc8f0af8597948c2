"""Open a Bonn ``.btf`` file as a lazy :class:`~usdbtf.model.BTF` (see the package docstring)."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import color
from ..errors import BTFError
from ..model import BTF
from ..sampling import cross
from .binary import MAX_SIGNATURE, SIGNATURES, BonnHeader, Cursor, sniff_signature
from .color_models import MODEL_NAMES, restore_dynamic_range, undecorrelate
from .formats import PARSERS, Factorisation

__all__ = ["UBO2014BTF", "read_ubo2014", "is_ubo2014", "bonn_to_tangent_degrees", "DEFAULT_SPACE"]

#: The files hold linear camera RGB, calibrated (UBO2014 is distributed as HDR radiance); no
#: file names primaries, so Rec.709/sRGB primaries are assumed.  Override with ``color_space``.
DEFAULT_SPACE = "Linear Rec.709 (sRGB)"
#: Theta within this many degrees past 90 (float32 radians of pi/2) is taken as 90.
_HORIZON_SLACK_DEG = 1e-3


def bonn_to_tangent_degrees(angles_rad: np.ndarray) -> np.ndarray:
    """(N, 2) Bonn (theta, phi) in radians -> (N, 2) usdbtf (theta, phi) in degrees.

    Bonn's frame (btflib ``sph2cart2``: x = sin t cos p, y = sin t sin p, z = cos t) is
    right-handed with z the normal; with x along the image's columns (left to right) and file
    row 0 the top row (btflib), y points to the image's top: exactly usdbtf's tangent frame
    (x = image right, y = image up), so the mapping is the identity up to units and the
    canonical form (phi in [0, 360), theta in [0, 90]).  See docs/ubo2014-frame.md.

    The angles go through the unit vector, as btflib does, so theta < 0 or phi outside
    [0, 2 pi) land on the same direction; a direction below the horizon raises BTFError.
    """
    a = np.asarray(angles_rad, np.float64).reshape(-1, 2)
    st = np.sin(a[:, 0])
    x, y, z = st * np.cos(a[:, 1]), st * np.sin(a[:, 1]), np.cos(a[:, 0])
    theta = np.degrees(np.arctan2(np.hypot(x, y), z))
    phi = np.mod(np.degrees(np.arctan2(y, x)), 360.0)
    bad = theta > 90.0 + _HORIZON_SLACK_DEG
    if bad.any():
        i = int(np.argmax(bad))
        raise BTFError(f"direction {i}: theta {theta[i]:.4f} deg is below the horizon")
    theta = np.minimum(theta, 90.0)
    phi[(theta < 1e-9) | (phi > 360.0 - 1e-9)] = 0.0  # the pole's azimuth, and 2 pi - rounding
    return np.stack([theta, phi], axis=1)


def _available_bytes() -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


@dataclass
class UBO2014BTF(BTF):
    """A BTF decoded lazily from a Bonn ``.btf`` file (DFMF, FMF, PVF or BDI).

    Pixels are multiplied out on demand for any samples and rows (``read_encoded``);
    ``factors`` gives DFMF/FMF factors without expanding anything.  Values are float32
    linear RGB in ``color_space`` after the file's colour model is inverted, negative
    values (truncated factorisations ring below zero) are clamped to 0, and with the
    file's cosine flag set the light's cos(theta) is divided out (as btflib does).

    Attributes (beyond BTF)
    -----------------------
    source : str, the file.
    header : :class:`~.binary.BonnHeader`.
    """

    source: str = ""
    header: BonnHeader | None = field(default=None, repr=False)
    decoder: object = field(default=None, repr=False)

    @property
    def format(self) -> str:
        return self.header.format

    @property
    def signature(self) -> str:
        return self.header.signature

    @property
    def factors(self) -> Factorisation | None:
        """The DFMF/FMF factorisation (None for PVF and BDI files)."""
        return getattr(self.decoder, "factors", None)

    def __reduce__(self):
        # Memory maps do not pickle as maps: a copy sent to a worker reopens the file.
        return (_reopen, (self.source, self.color_space, self.ocio_config, self.working_space))

    def read_encoded(self, indices, rows=None) -> np.ndarray:
        """(n, h, W, 3) float32 linear RGB of samples ``indices``, rows y0..y1 (default all)."""
        idx = np.atleast_1d(np.arange(self.n_samples)[indices]).astype(np.int64)
        y0, y1 = (0, self.height) if rows is None else (int(rows[0]), int(rows[1]))
        if not 0 <= y0 < y1 <= self.height:
            raise BTFError(f"{self.source}: rows {y0}..{y1} are outside the image's 0..{self.height}")
        n, h, w = len(idx), y1 - y0, self.width
        # Output plus the per-channel product and colour temporaries: about 3 x the output.
        need = 3 * n * h * w * 3 * 4
        have = _available_bytes()
        if have is not None and need > have:
            raise BTFError(f"{self.source}: expanding {n} samples x {h} rows needs about {need / 1e9:.1f} GB "
                           f"of memory, {have / 1e9:.1f} GB is available; read fewer samples or rows at a time")
        planes = self.channels_to_rgb(self.decoder.channels(idx, y0 * w, y1 * w), idx)   # (3, n, h W)
        rgb = np.empty((n, h * w, 3), np.float32)
        for c in range(3):
            rgb[..., c] = planes[c]
        return rgb.reshape(n, h, w, 3)

    def channels_to_rgb(self, planes: np.ndarray, samples: np.ndarray, *, clamp: bool = True) -> np.ndarray:
        """What follows the factor product: channel planes -> linear RGB planes in ``color_space``.

        The colour model's inverse, the dynamic-range restore, the light cosine (cosine flag)
        and, with ``clamp``, negative values set to 0 -- the steps ``read_encoded`` applies,
        exposed so that a caller multiplying the factors itself (a transcoder) decodes the same
        values.

        Parameters
        ----------
        planes : (3, n, T') float32 channel values of samples ``samples`` (modified in place
            where possible).
        samples : (n,) int sample indices (v nL + l) of the planes' rows.
        clamp : set negative results to 0 (truncated factorisations ring below zero).

        Returns
        -------
        (3, n, T') float32 RGB planes.
        """
        f = self.factors
        if f is not None:
            planes = undecorrelate(planes, f.color_model, mean=f.color_mean, matrix=f.color_matrix, axis=0)
            planes = restore_dynamic_range(planes, f.dynamic_range_reduction)
        if self.header.cosine_flag:
            planes /= self._cos_light[np.asarray(samples) % self.header.n_lights][None, :, None]
        if clamp:
            np.maximum(planes, 0.0, out=planes)  # NaN stays NaN, and decode() reports it
        return planes

    @property
    def _cos_light(self) -> np.ndarray:
        return np.cos(self.header.lights[:, 0]).astype(np.float32)

    def describe(self) -> dict:
        """What ``usdbtf info`` prints: format, signature, directions, size, colour model,
        component counts (per channel; per view for PVF), scalar type."""
        h = self.header
        d = {"format": h.format, "signature": h.signature, "views": h.n_views, "lights": h.n_lights,
             "width": h.width, "height": h.height, "channels": h.channel_names, "cosine_flag": h.cosine_flag,
             "rotations": 0 if h.rotations is None else len(h.rotations), "ppmm": h.ppmm,
             "file_bytes": os.path.getsize(self.source) if os.path.exists(self.source) else None}
        d.update(self.decoder.describe())
        d["color_model_name"] = MODEL_NAMES.get(d["color_model"], "?")
        return d


def _reopen(path, color_space, ocio_config, working_space):
    return read_ubo2014(path, color_space=color_space, ocio_config=ocio_config, working_space=working_space)


def is_ubo2014(path) -> bool:
    """Cheap sniff: does ``path`` start with a Bonn BTF signature?  Never raises."""
    try:
        with open(path, "rb") as f:
            return sniff_signature(f.read(MAX_SIGNATURE)) is not None
    except OSError:
        return False


def read_ubo2014(path, *, color_space: str | None = None, ocio_config: str | None = None,
                 working_space: str = color.WORKING_SPACE) -> UBO2014BTF:
    """Open a Bonn binary BTF (``.btf``: DFMF, FMF, PVF or BDI) as a lazy :class:`UBO2014BTF`.

    Parameters
    ----------
    path : the ``.btf`` file.
    color_space : OCIO name of the decoded values; default "Linear Rec.709 (sRGB)".
    ocio_config, working_space : where decoded pixels go (see :class:`usdbtf.model.BTF`).

    Returns
    -------
    UBO2014BTF with nV x nL samples in the file's view-major order (sample v nL + l),
    angles in degrees in usdbtf's tangent frame, names ``"<file>[view v, light l]"``.

    Raises BTFError naming the file and the block for: an unknown signature, a truncated
    or over-long file, counts that disagree with the header, NaN or Inf in a factor or
    direction, an unsupported colour model or compression, theta below the horizon.
    Nothing is allocated before the header has been checked against the file size.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(MAX_SIGNATURE)
    except FileNotFoundError:
        raise BTFError(f"{path}: no such file") from None
    except OSError as exc:
        raise BTFError(f"{path}: cannot read ({exc.strerror or exc})") from None
    sig = sniff_signature(head)
    if sig is None:
        raise BTFError(f"{path}: not a Bonn BTF file: it starts with {head!r}, expected one of "
                       f"{', '.join(SIGNATURES)}")
    fmt, flag = SIGNATURES[sig]
    cur = Cursor(path, np.memmap(path, np.uint8, mode="r", shape=(size,)))
    cur.pos = len(sig)
    header = BonnHeader(sig, fmt, flag)
    decoder = PARSERS[fmt](cur, header)
    where = f"{path}: direction table"
    for name, table in (("views", header.views), ("lights", header.lights)):
        if not np.isfinite(table).all():
            raise BTFError(f"{where}: {name} hold NaN or Inf")
    try:
        views = bonn_to_tangent_degrees(header.views)
        lights = bonn_to_tangent_degrees(header.lights)
    except BTFError as exc:
        raise BTFError(f"{where}: {exc}") from None
    if header.cosine_flag and (np.cos(header.lights[:, 0]) < 1e-6).any():
        raise BTFError(f"{path}: meta data block: cosine flag set, but a light lies at the horizon "
                       "(cannot divide by cos(theta) = 0)")
    decoder.check_finite(cur)
    try:
        space = color.resolve_space(color_space or DEFAULT_SPACE, ocio_config)
    except BTFError as exc:
        raise BTFError(f"{path}: {exc}") from None
    nl = header.n_lights
    names = [f"{path.name}[view {s // nl}, light {s % nl}]" for s in range(header.n_views * nl)]
    metadata = {"format": f"UBO2014 {fmt}", "signature": sig}
    if np.isfinite(header.ppmm) and header.ppmm > 0:
        metadata["physical_size_m"] = [header.width / header.ppmm / 1000.0, header.height / header.ppmm / 1000.0]
    try:
        return UBO2014BTF(sampling=cross(views, lights), width=header.width, height=header.height,
                          color_space=space, bit_depth="float", names=names, working_space=working_space,
                          ocio_config=ocio_config, metadata=metadata, source=os.fspath(path), header=header,
                          decoder=decoder)
    except BTFError as exc:
        raise BTFError(f"{path}: direction table: {exc}") from None
