"""Colour conversion through OpenColorIO: every decode and encode in usdbtf goes through here.

The working space is the OCIO config's ``scene_linear`` role (ACEScg in the
built-in default config ``ocio://default``) unless a caller names another.

Integer images are decoded through a lookup table that OCIO itself evaluates:
for an 8- or 16-bit source, OCIO is run once over every code value, and if the
transform is "per-channel curve, then a 3x3 matrix" (true of every display-
referred -> scene-linear pair in common configs: sRGB, gamma 2.2, Rec.1886 ...)
the decode is a table lookup plus an optional matrix.  The factorisation is
verified against OCIO on a random set of colours; if it does not hold to 1e-5
the full OCIO processor runs on every pixel instead.  Same numbers, far fewer
cycles for the 10,000-image datasets this project reads.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import PyOpenColorIO as ocio

from .errors import BTFError

__all__ = [
    "DEFAULT_CONFIG", "WORKING_SPACE", "get_config", "resolve_space", "Processor", "processor",
    "IntegerDecoder", "integer_decoder", "usd_color_space", "mix_rgb", "mix_channel",
    "RENDERING_SPACE", "rendering_space", "linear_matrix",
]

DEFAULT_CONFIG = "ocio://default"
WORKING_SPACE = "scene_linear"
#: The rendering space a packaged BTF's shaders return by default (issue 40): linear Rec.709, what
#: UsdPreviewSurface colours mean and what Storm's, Blender's and MaterialX's frames hold.
RENDERING_SPACE = "Linear Rec.709 (sRGB)"
_VERIFY_TOLERANCE = 1e-5


@functools.lru_cache(maxsize=8)
def get_config(path: str | None = None) -> ocio.Config:
    """The OCIO config at ``path`` (file, or ``ocio://`` built-in URI); default ``ocio://default``."""
    try:
        return ocio.Config.CreateFromFile(path or DEFAULT_CONFIG)
    except Exception as exc:  # OCIO raises its own exception type with a useful message
        raise BTFError(f"cannot load OCIO config {path or DEFAULT_CONFIG!r}: {exc}") from None


def resolve_space(name: str, config: str | None = None) -> str:
    """Canonical colour-space name for ``name`` (a space name, alias or role) in the config.

    Raises BTFError naming the config when the space is unknown.
    """
    cs = get_config(config).getColorSpace(name)
    if cs is None:
        raise BTFError(f"colour space {name!r} is not in OCIO config {config or DEFAULT_CONFIG!r}")
    return cs.getName()


@dataclass(frozen=True)
class Processor:
    """A CPU colour transform ``src`` -> ``dst`` on float RGB arrays."""

    src: str
    dst: str
    config: str | None = None

    @functools.cached_property
    def _cpu(self):
        cfg = get_config(self.config)
        return cfg.getProcessor(resolve_space(self.src, self.config), resolve_space(self.dst, self.config)).getDefaultCPUProcessor()

    @property
    def is_identity(self) -> bool:
        return resolve_space(self.src, self.config) == resolve_space(self.dst, self.config)

    def apply(self, rgb: np.ndarray) -> np.ndarray:
        """(..., 3) float -> (..., 3) float32, a new array."""
        out = np.ascontiguousarray(rgb, dtype=np.float32).copy()
        if out.shape[-1] != 3:
            raise ValueError(f"expected (..., 3) RGB, got shape {out.shape}")
        if not self.is_identity and out.size:
            self._cpu.applyRGB(out.reshape(-1))
        return out


@functools.lru_cache(maxsize=32)
def processor(src: str, dst: str = WORKING_SPACE, config: str | None = None) -> Processor:
    return Processor(src, dst, config)


@dataclass(frozen=True, eq=False)
class IntegerDecoder:
    """Integer code values -> working space, as OCIO would compute them.

    Attributes
    ----------
    lut : (3, 2**bits) float32, per-channel curve applied to normalised code values.
    matrix : (3, 3) float32 or None, applied after the curve (``rgb_out = matrix @ rgb``).
    exact : bool, False when the transform did not factor and ``decode`` runs OCIO per pixel.
    """

    bits: int
    lut: np.ndarray
    matrix: np.ndarray | None
    exact: bool
    proc: Processor

    def decode_curves(self, codes: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(..., 3) integer codes -> (..., 3) float32 after the per-channel curves only.

        A 2-D (rows, 3 n) array (channels interleaved, rows possibly strided) is accepted
        as is, which lets callers decode column blocks of a data matrix without a copy.
        ``out``: a contiguous float32 array of the same shape to write into (returned).
        """
        if self.bits == 8 and codes.ndim >= 2 and codes.shape[-1] % 3 == 0:
            import cv2  # SIMD table lookup; numpy's take is ~4x slower on 500M-value datasets

            if self.shared_curve:
                flat = codes.reshape(-1, codes.shape[-1]) if codes.ndim != 2 else codes
                if flat.strides[-1] == 1 and flat.shape[0] < 2**31:
                    dst = None if out is None else out.reshape(flat.shape)
                    return _written(cv2.LUT(flat, self.lut[0], dst=dst), out).reshape(codes.shape)
            else:
                flat = np.ascontiguousarray(codes).reshape(-1, 1, 3)
                dst = None if out is None else out.reshape(flat.shape)
                return _written(cv2.LUT(flat, np.ascontiguousarray(self.lut.T).reshape(256, 1, 3), dst=dst),
                                out).reshape(codes.shape)
        n = codes.shape[-1]
        out = np.empty(codes.shape, np.float32) if out is None else out
        for c in range(3):
            out[..., c::3] = self.lut[c][codes[..., c::3]] if n > 3 else self.lut[c][codes[..., c:c + 1]]
        return out

    @functools.cached_property
    def shared_curve(self) -> bool:
        """True when all three channels use the same curve (one table lookup serves all)."""
        return bool(np.array_equal(self.lut[0], self.lut[1]) and np.array_equal(self.lut[0], self.lut[2]))

    def decode(self, codes: np.ndarray) -> np.ndarray:
        """(..., 3) integer codes -> (..., 3) float32 in the working space."""
        if not self.exact:
            return self.proc.apply(codes.astype(np.float32) / float(2**self.bits - 1))
        lin = self.decode_curves(codes)
        return lin if self.matrix is None else mix_rgb(lin, self.matrix)


def mix_rgb(rgb: np.ndarray, matrix: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``rgb @ matrix.T`` for (..., 3) float32 colours (or a (rows, 3 n) interleaved block):
    a new float32 array of the same shape, or ``out`` (contiguous, same shape) written.

    OpenCV's SIMD ``transform`` is ~4x faster than numpy's matmul with an inner dimension
    of 3 (0.03 s against 0.10 s for 33 M values); both are exact per element up to float32
    rounding, and each is deterministic for a given array shape.
    """
    import cv2  # lazily, like decode_curves: plain colour queries need no OpenCV

    x = np.ascontiguousarray(rgb, np.float32)
    m = np.asarray(matrix, np.float32)
    if x.size == 0 or x.size // 3 >= 2**31:
        return _written((x.reshape(-1, 3) @ m.T).reshape(x.shape), out)
    dst = None if out is None else out.reshape(-1, 1, 3)
    return _written(cv2.transform(x.reshape(-1, 1, 3), m, dst=dst), out).reshape(x.shape)


def mix_channel(rgb: np.ndarray, weights: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``rgb @ weights`` for (..., 3) float32 colours (or a (rows, 3 n) interleaved block): one
    channel per colour, a float32 array of shape (...) (or (rows, n)), or ``out`` written.

    One row of :func:`mix_rgb`'s matrix, planar: OpenCV's ``transform`` with a 1 x 3 matrix
    (0.2 ns a colour; numpy's matmul with an inner dimension of 3 for all three planes costs
    5-20x that).  Deterministic for a given array shape (its bits may differ from the same
    row of :func:`mix_rgb`'s 3 x 3 kernel: another SIMD kernel).
    """
    import cv2

    x = np.ascontiguousarray(rgb, np.float32)
    w = np.asarray(weights, np.float32).reshape(1, 3)
    shape = x.shape[:-1] + (x.shape[-1] // 3,)
    if x.size == 0 or x.size // 3 >= 2**31:
        return _written((x.reshape(-1, 3) @ w.T).reshape(shape), out)
    dst = None if out is None else out.reshape(-1, 1, 1)
    return _written(cv2.transform(x.reshape(-1, 1, 3), w, dst=dst), out).reshape(shape)


def _written(result: np.ndarray, out: np.ndarray | None) -> np.ndarray:
    """``out`` holding ``result`` (an OpenCV call given ``dst=out`` writes it in place; were
    it ever to allocate instead, the values are copied), or ``result`` when no ``out``."""
    if out is None:
        return result
    if not np.shares_memory(result, out):
        out[...] = result.reshape(out.shape)
    return out


@functools.lru_cache(maxsize=32)
def integer_decoder(src: str, bits: int, dst: str = WORKING_SPACE, config: str | None = None) -> IntegerDecoder:
    """Build (and verify) the table decode for ``bits``-bit images in colour space ``src``."""
    proc = processor(src, dst, config)
    n = 2**bits
    codes = np.linspace(0.0, 1.0, n, dtype=np.float32)
    # Per-channel ramps with the other channels at zero: f(v e_c) = A[:, c] * l_c(v) when l_c(0) == 0.
    ramps = np.zeros((3, n, 3), np.float32)
    for c in range(3):
        ramps[c, :, c] = codes
    resp = proc.apply(ramps)  # (3, n, 3)
    black = proc.apply(np.zeros((1, 3), np.float32))[0]
    matrix = np.stack([resp[c, -1] - black for c in range(3)], axis=1)  # column c = image of (1 on channel c)
    lut = np.empty((3, n), np.float32)
    for c in range(3):
        dom = int(np.argmax(np.abs(matrix[:, c])))
        lut[c] = (resp[c, :, dom] - black[dom]) / matrix[dom, c]
    if all(np.allclose(lut[0], lut[c], rtol=1e-6, atol=1e-9) for c in (1, 2)):
        lut[:] = lut.mean(axis=0)  # one shared curve (exact up to float rounding; verified below)
    if np.allclose(matrix, np.eye(3), atol=1e-7):
        matrix_or_none = None
    else:
        matrix_or_none = matrix.astype(np.float32)
    # Verify on random colours that curve-then-matrix reproduces OCIO (plus the black offset, expected 0).
    rng = np.random.default_rng(12345)
    sample = rng.integers(0, n, size=(4096, 3))
    want = proc.apply(sample.astype(np.float32) / (n - 1))
    got = np.stack([lut[c][sample[:, c]] for c in range(3)], axis=-1)
    if matrix_or_none is not None:
        got = got @ matrix_or_none.T
    scale = np.maximum(np.abs(want), 1.0)
    exact = bool(np.all(np.abs(black) < 1e-7) and np.all(np.abs(got - want) <= _VERIFY_TOLERANCE * scale))
    return IntegerDecoder(bits, lut, matrix_or_none, exact, proc)


# OCIO names of the built-in config -> the colour-space tokens USD understands (Gf.ColorSpaceNames).
_USD_NAMES = {
    "ACEScg": "lin_ap1_scene",
    "ACES2065-1": "lin_ap0_scene",
    "Linear Rec.709 (sRGB)": "lin_rec709_scene",
    "Linear P3-D65": "lin_p3d65_scene",
    "Linear Rec.2020": "lin_rec2020_scene",
    "Linear AdobeRGB": "lin_adobergb_scene",
    "sRGB Encoded Rec.709 (sRGB)": "srgb_rec709_scene",
    "Gamma 2.2 Encoded Rec.709": "g22_rec709_scene",
    "Gamma 1.8 Encoded Rec.709": "g18_rec709_scene",
    "sRGB Encoded AP1": "srgb_ap1_scene",
    "Gamma 2.2 Encoded AP1": "g22_ap1_scene",
    "sRGB Encoded P3-D65": "srgb_p3d65_scene",
    "Gamma 2.2 Encoded AdobeRGB": "g22_adobergb_scene",
    "Raw": "raw",
}


def usd_color_space(name: str, config: str | None = None) -> str | None:
    """The USD colour-space token for an OCIO space, or None if USD has no equivalent."""
    return _USD_NAMES.get(resolve_space(name, config))


def rendering_space(name: str, config: str | None = None) -> str:
    """Canonical OCIO name of a rendering space given as an OCIO name, alias or role, or as a
    USD colour-space token (``lin_rec709_scene``, ``lin_ap1_scene``, ...: Gf.ColorSpaceNames)."""
    ocio_name = {usd: name_ for name_, usd in _USD_NAMES.items()}.get(name, name)
    return resolve_space(ocio_name, config)


def linear_matrix(src: str, dst: str, config: str | None = None) -> np.ndarray:
    """(3, 3) float64 M with ``rgb_dst = M @ rgb_src``: OCIO's transform ``src`` -> ``dst``
    taken as a matrix (OCIO evaluated on the unit colours), checked to be one.

    Between scene-linear spaces (ACEScg, linear Rec.709, ...) OCIO's transform is a 3 x 3 matrix
    (chromatic adaptation included).  A transform that is not (an encoded space, a look) raises
    BTFError naming both spaces: a shader cannot apply it after its own linear colour matrix.
    """
    proc = processor(src, dst, config)
    basis = proc.apply(np.eye(3, dtype=np.float32)).astype(np.float64)     # row c: the image of e_c
    matrix = basis.T
    rng = np.random.default_rng(12345)
    probe = rng.uniform(-0.5, 4.0, size=(256, 3)).astype(np.float32)
    want = proc.apply(probe).astype(np.float64)
    if not np.allclose(probe.astype(np.float64) @ matrix.T, want, rtol=1e-4, atol=1e-5):
        raise BTFError(f"colour transform {src!r} -> {dst!r} is not a 3 x 3 matrix: choose a scene-linear "
                       "rendering space")
    return matrix
