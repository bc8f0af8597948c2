"""Direction sets: which (view, light) pairs a BTF is sampled at.

Angles are degrees at this interface: ``theta`` from the surface normal, ``phi``
the azimuth in the sample's tangent frame (x = image right, y = image up on the
rectified sample, z = normal).  Samples are ordered view-major: all lights of
view 0, then all lights of view 1, ...

Presets
-------
``paper``  90 views x 120 lights (Koudelka et al. 2003): views on 5 polar rings
           (10, 25, 40, 55, 70 deg) x 18 azimuths at 20 deg; lights on 5 rings
           (15, 30, 45, 60, 75 deg) x 24 azimuths at 15 deg.  The paper gives the
           step sizes and counts, not the ring placement; these rings are ours.
``ubo81``  the Bonn UBO2003 set used for both view and light: rings at
           0/15/30/45/60/75 deg with 1/6/12/18/20/24 azimuths (81 x 81 samples).
``ubo151`` UBO2014's size: 151 views x 151 lights (22,801 samples), the same set for
           both, rings at 0/15/30/45/60/75 deg with 1/12/23/32/39/44 azimuths (about
           proportional to each ring's circumference).  Bonn's own positions are in
           the files (:mod:`usdbtf.ubo2014`); this set has their count and extent.
``small``  13 views x 13 lights (rings 0/30/60 with 1/6/6 azimuths).
``tiny``   4 views x 6 lights, for unit tests.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Sampling", "rings", "cross", "preset", "PRESETS", "to_vectors", "Coverage", "COVERAGE_FORMAT",
           "read_coverage", "coverage_json", "match_directions", "DIRECTION_TOLERANCE"]

#: The coverage file's format tag (:func:`read_coverage`).
COVERAGE_FORMAT = "usdbtf-coverage/1"
#: Two directions are the same when they are less than this many degrees apart (angle between
#: the unit vectors): coverage files written with rounded angles still name measured ones.
DIRECTION_TOLERANCE = 0.01


@dataclass(frozen=True)
class Sampling:
    """A list of (view, light) direction pairs.

    Attributes
    ----------
    view, light : (S, 2) float64 arrays, degrees, columns (theta, phi).
    """

    view: np.ndarray
    light: np.ndarray

    def __post_init__(self):
        import numpy as np   # here, not at module level: the command line lists PRESETS without numpy

        view = np.asarray(self.view, dtype=np.float64).reshape(-1, 2)
        light = np.asarray(self.light, dtype=np.float64).reshape(-1, 2)
        if view.shape != light.shape:
            raise ValueError(f"view and light lists differ in length: {len(view)} vs {len(light)}")
        object.__setattr__(self, "view", view)
        object.__setattr__(self, "light", light)

    def __len__(self) -> int:
        return len(self.view)

    def subset(self, indices) -> "Sampling":
        """The samples at ``indices`` (any numpy index), same order."""
        return Sampling(self.view[indices], self.light[indices])


def rings(thetas, counts, phi_offset=0.0) -> np.ndarray:
    """Directions on polar rings: ring r has ``counts[r]`` equally spaced azimuths.

    Returns (N, 2) degrees.  A ring at theta == 0 must have count 1 (the pole).
    """
    import numpy as np

    out = []
    for theta, count in zip(thetas, counts):
        if theta == 0 and count != 1:
            raise ValueError("the pole (theta = 0) has a single direction")
        for m in range(count):
            out.append((float(theta), (phi_offset + 360.0 * m / count) % 360.0))
    return np.asarray(out, dtype=np.float64)


def cross(views: np.ndarray, lights: np.ndarray) -> Sampling:
    """Every light for every view, view-major."""
    import numpy as np

    views = np.asarray(views, dtype=np.float64).reshape(-1, 2)
    lights = np.asarray(lights, dtype=np.float64).reshape(-1, 2)
    return Sampling(np.repeat(views, len(lights), axis=0), np.tile(lights, (len(views), 1)))


_UBO_RINGS = ((0, 15, 30, 45, 60, 75), (1, 6, 12, 18, 20, 24))
_UBO151_RINGS = ((0, 15, 30, 45, 60, 75), (1, 12, 23, 32, 39, 44))

PRESETS = {
    "paper": lambda: cross(rings((10, 25, 40, 55, 70), (18,) * 5), rings((15, 30, 45, 60, 75), (24,) * 5)),
    "ubo81": lambda: cross(rings(*_UBO_RINGS), rings(*_UBO_RINGS)),
    "ubo151": lambda: cross(rings(*_UBO151_RINGS), rings(*_UBO151_RINGS)),
    "small": lambda: cross(rings((0, 30, 60), (1, 6, 6)), rings((0, 30, 60), (1, 6, 6), phi_offset=30.0)),
    "tiny": lambda: cross(rings((0, 45), (1, 3)), rings((20, 60), (3, 3), phi_offset=30.0)),
}


def preset(name: str) -> Sampling:
    """A named sampling (see module docstring)."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown sampling preset {name!r}; choose from {', '.join(PRESETS)}") from None


def to_vectors(directions_deg: np.ndarray) -> np.ndarray:
    """(N, 2) degrees (theta, phi) -> (N, 3) unit vectors in the tangent frame."""
    import numpy as np

    d = np.radians(np.asarray(directions_deg, dtype=np.float64).reshape(-1, 2))
    st = np.sin(d[:, 0])
    return np.stack([st * np.cos(d[:, 1]), st * np.sin(d[:, 1]), np.cos(d[:, 0])], axis=1)


@dataclass(frozen=True, eq=False)      # arrays: identity, not an ambiguous elementwise ==
class Coverage:
    """The (view, light) directions a build keeps of a BTF: every listed light at every
    listed view (``compress --coverage``).

    Attributes
    ----------
    views : (V, 2) float64 degrees (theta, phi), directions of the input's own view set.
    lights : (L, 2) float64 degrees (theta, phi), directions of the input's own light set.
    path : the file it was read from, for messages ("" when made in memory).
    """

    views: np.ndarray
    lights: np.ndarray
    path: str = ""

    def __post_init__(self):
        import numpy as np

        for name in ("views", "lights"):
            value = np.asarray(getattr(self, name), dtype=np.float64)
            if value.size == 0 or value.ndim != 2 or value.shape[1] != 2:
                raise ValueError(f"coverage {name}: expected a non-empty list of [theta, phi] pairs")
            if not np.isfinite(value).all():
                raise ValueError(f"coverage {name}: directions must be finite numbers")
            object.__setattr__(self, name, value)


def coverage_json(coverage: Coverage) -> str:
    """The text of a coverage file (``usdbtf-coverage/1``): one direction per line, so a
    build's file (a SCons source) changes exactly when the directions do."""
    from . import jsontext

    return jsontext.dumps({"format": COVERAGE_FORMAT, "views": coverage.views.tolist(),
                           "lights": coverage.lights.tolist()}) + "\n"


def read_coverage(path) -> Coverage:
    """Read a coverage file written by :func:`coverage_json` (or by hand).

    Raises BTFError naming the file and the key at fault (exit status 65)."""
    from . import jsontext
    from .errors import BTFError

    doc = jsontext.load(path, "coverage file")
    if not isinstance(doc, dict) or doc.get("format") != COVERAGE_FORMAT:
        raise BTFError(f"{path}: not a coverage file (format must be {COVERAGE_FORMAT!r})")
    try:
        return Coverage(_pairs(doc.get("views"), "views"), _pairs(doc.get("lights"), "lights"), str(path))
    except ValueError as exc:
        raise BTFError(f"{path}: {exc}") from None


def _pairs(value, name: str) -> list:
    """A JSON list of [theta, phi] number pairs, checked (ValueError names ``name``)."""
    ok = isinstance(value, list) and value and all(
        isinstance(p, list) and len(p) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                    for x in p) for p in value)
    if not ok:
        raise ValueError(f"coverage {name}: expected a non-empty list of [theta, phi] pairs (degrees)")
    return value


def match_directions(wanted, available, tolerance: float = DIRECTION_TOLERANCE):
    """Index into ``available`` of each direction of ``wanted``, within ``tolerance`` degrees.

    Parameters
    ----------
    wanted, available : (n, 2) and (m, 2) degrees (theta, phi).
    tolerance : largest angle (degrees) between a wanted direction and its match.

    Returns
    -------
    (n,) int64 indices; -1 where no available direction is that close.
    """
    import numpy as np

    a, b = to_vectors(wanted), to_vectors(available)
    angle = np.degrees(np.arccos(np.clip(a @ b.T, -1.0, 1.0)))       # (n, m)
    best = np.argmin(angle, axis=1)
    return np.where(angle[np.arange(len(a)), best] <= tolerance, best, -1).astype(np.int64)
