"""Capture plans: which samples to shoot, in which order, and which the arm obstructs.

A plan starts from a :class:`~usdbtf.sampling.Sampling` (the paper's 90 views x 120
lights by default) and adds, per sample, the head and arm positions that realise it
(:mod:`usdbtf.rig.kinematics`), whether the arm blocks the camera there, and an order
to shoot the rest in.

Obstruction model (:class:`ArmGeometry`)
----------------------------------------
The light is an LED held ``led_distance_m`` from the sample centre by an arm that
reaches in radially (a link ``wrist_m`` long behind the LED) from a shoulder fixed in
the lab (beside the head, on the camera's right and a little behind the sample, by
default; with the paper's sampling this hides about 5% of the samples).  The LED and both links are capsules.  A sample
is *obstructed* when any capsule comes within its radius of a camera ray to the sample
window (the rays to the window's centre, corners and edge midpoints).  Obstructed
samples are not shot; they are listed as missing and filled later (:mod:`usdbtf.fill`),
as Koudelka et al. did.

Ordering (``order="travel"``)
-----------------------------
Head moves are slow, so each view is shot once with all its lights.  Views follow a
short tour of head moves (nearest neighbour + 2-opt over the time both head axes need,
``max(|d tilt|, |d pan|)``).  Within a view the lights follow one short closed tour of
the light directions (2-opt over great-circle angles), entered at the light nearest the
arm's current position and run in the direction that is shorter to start; since the
head turns the whole light hemisphere rigidly, angles between lights, and so the tour,
are the same for every view.  ``order="sampling"`` keeps the sampling's own order.
:func:`arm_travel` measures what an order costs.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

import numpy as np

from ..sampling import Sampling, to_vectors
from . import ORDERS
from . import kinematics as K

__all__ = ["ArmGeometry", "CapturePlan", "make_plan", "obstructed", "arm_travel", "head_travel", "ORDERS"]



@dataclass(frozen=True)
class ArmGeometry:
    """Lab geometry of the camera, sample window and light arm (metres).

    camera_distance_m : camera to sample centre.
    window_half_m : half the side of the sample window (rays are cast to it).
    led_distance_m : LED to sample centre.
    led_radius_m, link_radius_m : capsule radii of the LED housing and the arm links.
    wrist_m : length of the radial link behind the LED.
    shoulder_m : lab position of the arm's shoulder (the far end of the second link).
    """

    camera_distance_m: float = 1.0
    window_half_m: float = 0.033
    led_distance_m: float = 0.5
    led_radius_m: float = 0.03
    link_radius_m: float = 0.03
    wrist_m: float = 0.15
    shoulder_m: tuple = (0.9, 0.3, -0.4)


def _segment_distance(p0, p1, q0, q1) -> np.ndarray:
    """Shortest distance between segments p0-p1 and q0-q1, all (..., 3), broadcast."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("...i,...i", d1, d1)
    e = np.einsum("...i,...i", d2, d2)
    f = np.einsum("...i,...i", d2, r)
    c = np.einsum("...i,...i", d1, r)
    b = np.einsum("...i,...i", d1, d2)
    denom = a * e - b * b
    s = np.where(denom > 1e-12, np.clip((b * f - c * e) / np.where(denom > 1e-12, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / np.where(e > 1e-12, e, 1.0)
    # Clamp t to the segment and recompute s for the clamped t (standard closest-point routine).
    t_lo, t_hi = t < 0, t > 1
    t = np.clip(t, 0.0, 1.0)
    s = np.where(t_lo, np.clip(-c / np.where(a > 1e-12, a, 1.0), 0.0, 1.0), s)
    s = np.where(t_hi, np.clip((b - c) / np.where(a > 1e-12, a, 1.0), 0.0, 1.0), s)
    closest = (p0 + s[..., None] * d1) - (q0 + t[..., None] * d2)
    return np.linalg.norm(closest, axis=-1)


def obstructed(head_deg: np.ndarray, arm_deg: np.ndarray, geometry: ArmGeometry = ArmGeometry()) -> np.ndarray:
    """(N,) bool: does the arm block the camera's view of the sample window?

    head_deg, arm_deg : (N, 2) positions in degrees (see :mod:`usdbtf.rig.kinematics`).
    """
    g = geometry
    head = np.asarray(head_deg, np.float64).reshape(-1, 2)
    led_dir = to_vectors(np.asarray(arm_deg, np.float64).reshape(-1, 2))                 # (N, 3)
    h = g.window_half_m
    window = np.array([[0, 0], [h, h], [-h, h], [h, -h], [-h, -h], [h, 0], [-h, 0], [0, h], [0, -h]], np.float64)
    rot = K.rotation(head)                                                              # (N, 3, 3)
    targets = np.einsum("nij,kj->nki", rot[:, :, :2], window)                           # (N, 9, 3)
    camera = np.array([0.0, 0.0, g.camera_distance_m])
    led = g.led_distance_m * led_dir
    wrist = (g.led_distance_m + g.wrist_m) * led_dir
    shoulder = np.broadcast_to(np.asarray(g.shoulder_m, np.float64), led.shape)
    blocked = np.zeros(len(head), bool)
    for a, b, radius in ((led, led, g.led_radius_m), (led, wrist, g.link_radius_m), (wrist, shoulder, g.link_radius_m)):
        dist = _segment_distance(camera, targets, a[:, None, :], b[:, None, :])         # (N, 9)
        blocked |= (dist < radius).any(axis=1)
    return blocked


def _pan_delta(a, b):
    d = np.abs(np.asarray(a) - np.asarray(b)) % 360.0
    return np.minimum(d, 360.0 - d)


def head_travel(head_deg: np.ndarray) -> float:
    """Total head time-proxy of visiting positions in order: sum of max(|d tilt|, |d pan|), degrees."""
    h = np.asarray(head_deg, np.float64).reshape(-1, 2)
    if len(h) < 2:
        return 0.0
    return float(np.maximum(np.abs(np.diff(h[:, 0])), _pan_delta(h[1:, 1], h[:-1, 1])).sum())


def arm_travel(arm_deg: np.ndarray) -> float:
    """Total great-circle angle (degrees) the LED sweeps visiting arm positions in order."""
    v = to_vectors(np.asarray(arm_deg, np.float64).reshape(-1, 2))
    if len(v) < 2:
        return 0.0
    return float(K.angle_between(v[1:], v[:-1]).sum())


def _tour_length(dist: np.ndarray, tour: np.ndarray, closed: bool) -> float:
    legs = dist[tour[:-1], tour[1:]].sum()
    return float(legs + (dist[tour[-1], tour[0]] if closed else 0.0))


def _two_opt(dist: np.ndarray, tour: np.ndarray, max_passes: int = 50) -> np.ndarray:
    """Improve a closed tour by 2-opt moves (reverse a stretch when that shortens it)."""
    tour = tour.copy()
    n = len(tour)
    if n < 4:
        return tour
    for _ in range(max_passes):
        improved = False
        for i in range(n - 2):
            a, b = tour[i], tour[i + 1]
            c = tour[i + 2:]
            d = np.roll(tour, -1)[i + 2:]
            if i == 0:
                c, d = c[:-1], d[:-1]           # do not break the edge (last, first) twice
            gain = dist[a, b] + dist[c, d] - dist[a, c] - dist[b, d]
            if len(gain) and gain.max() > 1e-9:
                j = i + 2 + int(np.argmax(gain))
                tour[i + 1:j + 1] = tour[i + 1:j + 1][::-1]
                improved = True
        if not improved:
            break
    return tour


def _nearest_neighbour_tour(dist: np.ndarray, start: int = 0) -> np.ndarray:
    n = len(dist)
    seen = np.zeros(n, bool)
    tour = [start]
    seen[start] = True
    for _ in range(n - 1):
        d = np.where(seen, np.inf, dist[tour[-1]])
        nxt = int(np.argmin(d))
        tour.append(nxt)
        seen[nxt] = True
    return np.array(tour, np.int64)


def _short_tour(dist: np.ndarray, start: int = 0) -> np.ndarray:
    return _two_opt(dist, _nearest_neighbour_tour(dist, start))


def _open_path(dist: np.ndarray, start: int) -> np.ndarray:
    """A short open path through every node, beginning at ``start``.

    A 2-opt closed tour from ``start`` (2-opt never moves position 0), walked in whichever
    direction is shorter once the closing edge is not paid.
    """
    fwd = _short_tour(dist, start)
    rev = np.concatenate([fwd[:1], fwd[1:][::-1]])
    return fwd if _tour_length(dist, fwd, False) <= _tour_length(dist, rev, False) else rev


@dataclass
class CapturePlan:
    """A capture plan over ``sampling`` (its order defines the plan indices).

    head, arm : (S, 2) degrees, the positions realising each sample.
    obstructed : (S,) bool, samples the arm hides (not shot, listed as missing).
    order : (K,) int, plan indices to shoot, in shooting order (K = S - obstructed).
    """

    sampling: Sampling
    head: np.ndarray
    arm: np.ndarray
    obstructed: np.ndarray
    order: np.ndarray
    ordering: str
    geometry: ArmGeometry | None

    def fingerprint(self) -> str:
        """sha256 over everything that decides what is shot where (resume checks it)."""
        h = hashlib.sha256()
        for arr in (self.sampling.view, self.sampling.light, self.head, self.arm):
            h.update(np.round(np.asarray(arr, np.float64), 6).tobytes())
        h.update(self.obstructed.tobytes())
        h.update(self.order.astype(np.int64).tobytes())
        h.update(json.dumps(asdict(self.geometry) if self.geometry else None, sort_keys=True).encode())
        return h.hexdigest()

    def arm_travel_deg(self) -> float:
        return arm_travel(self.arm[self.order])

    def head_travel_deg(self) -> float:
        return head_travel(self.head[self.order])


def _light_tour(lights_deg: np.ndarray) -> np.ndarray:
    vec = to_vectors(lights_deg)
    dist = np.degrees(np.arccos(np.clip(vec @ vec.T, -1.0, 1.0)))
    return _short_tour(dist)


def make_plan(sampling: Sampling, *, ordering: str = "travel", geometry: ArmGeometry | None = ArmGeometry()) -> CapturePlan:
    """Plan ``sampling``; ``geometry=None`` switches the obstruction model off."""
    if ordering not in ORDERS:
        raise ValueError(f"unknown ordering {ordering!r}; choose from {', '.join(ORDERS)}")
    head = K.head_for_view(sampling.view)
    arm = K.arm_for_light(head, sampling.light)
    blocked = obstructed(head, arm, geometry) if geometry is not None else np.zeros(len(sampling), bool)
    if ordering == "sampling":
        order = np.flatnonzero(~blocked)
        return CapturePlan(sampling, head, arm, blocked, order, ordering, geometry)
    # Group samples by head position (one group per view).
    key = np.round(head, 6)
    uniq, group_of = np.unique(key, axis=0, return_inverse=True)
    group_of = group_of.reshape(-1)
    tilt, pan = uniq[:, 0], uniq[:, 1]
    head_dist = np.maximum(np.abs(tilt[:, None] - tilt[None, :]), _pan_delta(pan[:, None], pan[None, :]))
    start = int(np.argmin(tilt + 1e-3 * _pan_delta(pan, 0.0)))       # nearest to home (tilt 0)
    view_order = _open_path(head_dist, start)
    tours: dict = {}
    order = []
    arm_now = np.array([0.0, 0.0])
    for g in view_order:
        members = np.flatnonzero((group_of == g) & ~blocked)
        if len(members) == 0:
            continue
        lights = np.round(sampling.light[members], 6)
        lkey = lights.tobytes()
        if lkey not in tours:
            tours[lkey] = _light_tour(lights)
        tour = members[tours[lkey]]
        # Enter the tour at the light nearest the arm, run it in the direction whose first
        # step is shorter.
        arm_vec = to_vectors(arm_now)[0]
        first = int(np.argmax(to_vectors(arm[tour]) @ arm_vec))
        ring = np.roll(tour, -first)
        alt = np.concatenate([ring[:1], ring[1:][::-1]])
        ring = ring if arm_travel(arm[ring]) <= arm_travel(arm[alt]) else alt
        order.extend(ring.tolist())
        arm_now = arm[ring[-1]]
    return CapturePlan(sampling, head, arm, blocked, np.array(order, np.int64), ordering, geometry)
