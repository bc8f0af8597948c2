"""The working domain: a per-channel transfer curve the basis is fitted and quantised in.

A least-squares fit on scene-linear values spends its components on the brightest texels
(the paper's metric is an L1 sum, and a few clipped highlights decide what a linear basis
represents).  Fitting and quantising ``d = f(x)`` instead, with ``x`` the scene-linear
working-space value of one colour channel, spreads the components over the whole range
(issue 16's research, ``benchmarks/probes/research/``: at the paper's bytes the error fell by
up to half, in both error domains).

Every consumer reconstructs ``x = f^-1(M . sum_i U[s, i] c_i)``: the dot product and the
colour matrix in the domain, **then** the inverse curve, per channel.  Interpolated
directions blend basis rows before the inverse; a light's intensity multiplies after it.

Curves (``Domain.curve``):

``linear``  f(x) = x (every output before issue 16; a folder without a ``domain`` key).
``power``   f(x) = x^(1/gamma), gamma in [1, 4].
``srgb``    the IEC 61966-2-1 sRGB encoding curve (linear toe below 0.0031308), continued
            above 1 by the same formula (HDR values stay finite and monotone).

Negative values: ``forward`` clamps negative scene-linear input to 0 (a power curve has no
real value there), ``inverse`` clamps negative reconstructions to 0 before the curve (one
``max`` per value in a shader; the truth is never negative in such a domain, so the clamp
only removes error).  ``linear`` leaves negatives as they are.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import BTFError, UsageError

__all__ = ["Domain", "LINEAR", "parse_domain", "domain_from_metadata", "AUTO_CANDIDATES", "DOMAIN_CHOICES",
           "GAMMA_RANGE"]

#: The exponents a power curve may have (whitelisted for files and options).
GAMMA_RANGE = (1.0, 4.0)
#: What ``--domain`` accepts (plus ``gamma:G``).
DOMAIN_CHOICES = ("auto", "linear", "srgb")

_SRGB_CUT = 0.0031308          # scene-linear value where the sRGB toe ends
_SRGB_CUT_ENCODED = 0.04045    # its encoded value


@dataclass(frozen=True)
class Domain:
    """One working-domain curve.

    Attributes
    ----------
    curve : "linear", "power" or "srgb".
    gamma : the exponent of a power curve (f(x) = x^(1/gamma)); 1.0 otherwise.
    """

    curve: str = "linear"
    gamma: float = 1.0

    def __post_init__(self):
        if self.curve not in ("linear", "power", "srgb"):
            raise ValueError(f"unknown domain curve {self.curve!r}")
        if self.curve == "power" and not (GAMMA_RANGE[0] <= self.gamma <= GAMMA_RANGE[1]):
            raise ValueError(f"power-curve gamma {self.gamma} outside {GAMMA_RANGE}")

    @property
    def is_linear(self) -> bool:
        return self.curve == "linear" or (self.curve == "power" and self.gamma == 1.0)

    @property
    def name(self) -> str:
        """``linear``, ``srgb`` or ``gamma:G`` (what ``--domain`` accepts)."""
        return "linear" if self.is_linear else ("srgb" if self.curve == "srgb" else f"gamma:{self.gamma:g}")

    @property
    def shader_code(self) -> tuple[int, float]:
        """(curve id, gamma) as shaders read them: 0 linear, 1 power, 2 sRGB."""
        return (0, 1.0) if self.is_linear else ((1, float(self.gamma)) if self.curve == "power" else (2, 1.0))

    def forward(self, x: np.ndarray, out: np.ndarray | None = None, *, nonnegative: bool = False) -> np.ndarray:
        """Scene-linear -> domain values, float32, same shape (negatives -> 0 unless linear).
        ``out``: a float32 array of the same shape to write into (may be ``x`` itself).
        ``nonnegative``: the caller knows ``x >= 0`` (no clamp: the same values, one pass less)."""
        x = np.asarray(x, np.float32)
        if self.is_linear:
            if out is None or out is x:
                return x
            out[...] = x
            return out
        # In place on one array (fresh large arrays cost page faults): the same values as
        # the plain expressions, operation for operation.
        if not nonnegative:
            x = np.maximum(x, np.float32(0.0), out=out)
        elif out is None:
            x = x.copy()
        elif out is not x:
            out[...] = x
            x = out
        if self.curve == "power":
            return _power(x, np.float32(1.0 / self.gamma))
        toe, low = _toe(x, np.float32(_SRGB_CUT), np.float32(12.92))
        _power(x, np.float32(1 / 2.4))
        x *= np.float32(1.055)
        x -= np.float32(0.055)
        _put_toe(x, toe, low)
        return x

    def inverse(self, d: np.ndarray) -> np.ndarray:
        """Domain values -> scene-linear, float32, same shape (negatives -> 0 unless linear)."""
        d = np.asarray(d, np.float32)
        if self.is_linear:
            return d
        d = np.maximum(d, np.float32(0.0))
        if self.curve == "power":
            return _power(d, np.float32(self.gamma))
        toe, low = _toe(d, np.float32(_SRGB_CUT_ENCODED), np.float32(1 / 12.92))
        d += np.float32(0.055)
        d *= np.float32(1 / 1.055)
        _power(d, np.float32(2.4))
        _put_toe(d, toe, low)
        return d

    def metadata(self) -> dict:
        """The ``domain`` entry of ``btf-compressed.json``."""
        if self.is_linear:
            return {"curve": "linear"}
        if self.curve == "srgb":
            return {"curve": "srgb"}
        return {"curve": "power", "gamma": float(self.gamma)}


def _toe(x: np.ndarray, cut: np.float32, slope: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """The sRGB curve's linear toe of float32 ``x``: (where the values ``<= cut`` are, those
    values times ``slope``), taken before the power branch overwrites ``x``.

    Where: flat indices for a C-contiguous ``x`` (a boolean mask otherwise).  A masked gather
    and scatter each cost a pass over every value; indices cost one pass to find and then only
    the toe's values (about 2 % of a material's): 1.10 -> 0.52 ns a value at paper scale.  The
    same products and the same assignments either way, so the same bits."""
    if not x.flags.c_contiguous:
        toe = x <= cut
        return toe, x[toe] * slope
    flat = x.reshape(-1)
    toe = np.flatnonzero(flat <= cut)
    return toe, flat[toe] * slope


def _put_toe(x: np.ndarray, toe: np.ndarray, low: np.ndarray) -> None:
    """Write the toe's values (:func:`_toe`) back into ``x``, over the power branch's."""
    if toe.dtype == bool:
        x[toe] = low
    else:
        x.reshape(-1)[toe] = low


def _power(x: np.ndarray, exponent: np.float32) -> np.ndarray:
    """``x **= exponent`` in place for float32 ``x >= 0`` (-0.0 allowed, 0 ** e = +0), exponent > 0.

    Computed as ``exp(exponent * log(x))`` with numpy's float32 ``log`` and ``exp``, over one
    contiguous run of values, because each value's bits must not depend on where it sits in
    the array: the same sample compressed in a Dask chunk, a streaming block or a test's slice
    gives the same bytes.  Neither library's ``pow`` keeps that: OpenCV 5.1's ``pow`` rounds
    values in a partial SIMD vector, and vectors holding a zero or a denormal, another way than
    full ones (found when CI installed OpenCV 5.1; 5.0 did not), and numpy's ``power`` goes to
    SVML on AVX-512 CPUs and to libm elsewhere.  numpy's float32 ``log`` and ``exp`` are its own
    SIMD code: the same bits with AVX2 and AVX-512 and at every offset (checked at every
    offset 0-69, with zeros, -0.0 and denormals in the run; ``tests/test_domain.py``), libm's
    on a CPU below x86-64-v3 (its own platform, :mod:`usdbtf.numeric`).  Within 5e-6 relative
    of a float64 power wherever the result is a normal float32 (OpenCV's: 2e-5), 1 ** e = 1
    exactly; 1 ns a value with AVX-512, 3.5 ns with AVX2 (OpenCV: 1.0-1.6 ns).  Bulk 8-bit
    inputs never come here: their curve is folded into the decode table."""
    flat = x.reshape(-1) if x.flags.c_contiguous else np.ascontiguousarray(x).reshape(-1)
    with np.errstate(divide="ignore"):      # log(0) = -inf, and exp(-inf) = +0: what 0 ** e is
        np.log(flat, out=flat)
    flat *= exponent
    np.exp(flat, out=flat)
    if not x.flags.c_contiguous:        # powered in a contiguous copy: back into x
        x[...] = flat.reshape(x.shape)
    return x


LINEAR = Domain()

#: The curves ``--domain auto`` chooses from.  In the research three curves covered every
#: per-material choice (x^(1/1.6): pebbles, fabric, moss, stones, velvet; x^(1/2.2): satin;
#: sRGB: metallic flakes); linear comes first so that data a linear basis reconstructs
#: exactly (low rank: rendered, HDR test patterns) keeps it (ties go to the first).
#: x^(1/3) was added for issue 39: metal_flakes' scores still fell past sRGB (paper scale, fine
#: pass: sRGB 4.676, x^(1/2.6) 4.642, x^(1/3) 4.596, x^(1/3.5) 4.584, x^(1/4) 4.608), and in its
#: packaged asset at the paper's bytes x^(1/3) lowers the error to 0.643 / 0.704 of the paper's
#: (encoded / linear) from sRGB's 0.688 / 0.721; every other preset scores it 0.12-1.03 behind
#: its choice (benchmarks/RESULTS.md, "What the packaged asset ships").  One more candidate costs
#: the coarse pass ~0.7 s at paper scale (benchmarks/probes/domain_curves.py: 0.74 s a curve).
AUTO_CANDIDATES = (LINEAR, Domain("power", 1.6), Domain("power", 2.2), Domain("srgb"), Domain("power", 3.0))


def parse_domain(text: str) -> Domain | None:
    """``--domain`` text -> Domain; None for ``auto``.  Raises UsageError for anything else
    than auto, linear, srgb or gamma:G (G a number in [1, 4])."""
    t = str(text).strip().lower()
    if t == "auto":
        return None
    if t == "linear":
        return LINEAR
    if t == "srgb":
        return Domain("srgb")
    if t.startswith("gamma:"):
        try:
            g = float(t[6:])
        except ValueError:
            g = math.nan
        if math.isfinite(g) and GAMMA_RANGE[0] <= g <= GAMMA_RANGE[1]:
            return LINEAR if g == 1.0 else Domain("power", g)
    raise UsageError(f"--domain: {text!r} is not one of auto, linear, srgb, gamma:G (G in "
                     f"{GAMMA_RANGE[0]:g}..{GAMMA_RANGE[1]:g})")


def domain_from_metadata(entry, where: str) -> Domain:
    """The ``domain`` entry of a metadata file -> Domain (absent: linear, the format before
    issue 16).  Raises BTFError naming ``where`` for anything outside the whitelist."""
    if entry is None:
        return LINEAR
    if not isinstance(entry, dict) or entry.get("curve") not in ("linear", "power", "srgb"):
        raise BTFError(f"{where}: domain: must be {{\"curve\": \"linear\"|\"power\"|\"srgb\"}}, got {entry!r:.80}")
    extra = set(entry) - {"curve", "gamma"}
    if extra:
        raise BTFError(f"{where}: domain: unknown keys {sorted(extra)}")
    if entry["curve"] != "power":
        if "gamma" in entry:
            raise BTFError(f"{where}: domain: gamma is only for the power curve")
        return LINEAR if entry["curve"] == "linear" else Domain("srgb")
    g = entry.get("gamma")
    if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(g) \
            or not GAMMA_RANGE[0] <= g <= GAMMA_RANGE[1]:
        raise BTFError(f"{where}: domain.gamma: must be a number in {GAMMA_RANGE[0]:g}..{GAMMA_RANGE[1]:g}, got {g!r}")
    return Domain("power", float(g))
