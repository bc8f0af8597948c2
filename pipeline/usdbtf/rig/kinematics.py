"""Rig geometry: how a (view, light) sample maps to head and arm positions.

The rig follows Koudelka et al. 2003: the camera is fixed, the sample sits on a
pan/tilt head whose axes meet at the sample surface (giving the view), and a robot arm
carries the light over a sphere around the sample (giving the light).

Lab frame (metres): origin at the sample centre, +Z towards the camera, +Y up, +X to
the camera's right.  The camera is at (0, 0, D) looking down -Z; its image x is lab +X
and its image y is lab -Y.

Head: ``pan`` turns the sample about its own normal (a turntable), then ``tilt`` turns
the turntable about the lab X axis.  Sample -> lab rotation ``R = Rx(tilt) @ Rz(pan)``.
A view (theta_v, phi_v) in the sample frame is reached with ``tilt = theta_v`` and
``pan = 90 - phi_v`` (mod 360): that rotation takes the view direction to +Z.

Arm: the light's lab direction ``R @ l`` in spherical coordinates about the camera
axis: ``arm_theta`` from +Z (0..180 deg), ``arm_phi`` from +X towards +Y.

Angles in degrees at this interface, radians inside.
"""
from __future__ import annotations

import numpy as np

from ..sampling import to_vectors

__all__ = ["head_for_view", "rotation", "arm_for_light", "lab_direction", "view_for_head", "light_for_arm",
           "angle_between"]


def head_for_view(view_deg: np.ndarray) -> np.ndarray:
    """(N, 2) views (theta, phi) deg -> (N, 2) head (tilt, pan) deg; pan in [0, 360)."""
    v = np.asarray(view_deg, np.float64).reshape(-1, 2)
    return np.stack([v[:, 0], np.mod(90.0 - v[:, 1], 360.0)], axis=1)


def rotation(head_deg: np.ndarray) -> np.ndarray:
    """(N, 2) head (tilt, pan) deg -> (N, 3, 3) sample -> lab rotations Rx(tilt) @ Rz(pan)."""
    h = np.radians(np.asarray(head_deg, np.float64).reshape(-1, 2))
    ct, st = np.cos(h[:, 0]), np.sin(h[:, 0])
    cp, sp = np.cos(h[:, 1]), np.sin(h[:, 1])
    zero, one = np.zeros_like(ct), np.ones_like(ct)
    rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, ct, -st], -1), np.stack([zero, st, ct], -1)], 1)
    rz = np.stack([np.stack([cp, -sp, zero], -1), np.stack([sp, cp, zero], -1), np.stack([zero, zero, one], -1)], 1)
    return rx @ rz


def _to_angles(vec: np.ndarray) -> np.ndarray:
    """(N, 3) unit vectors -> (N, 2) (theta from +Z, phi from +X) deg; phi = 0 on the axis."""
    theta = np.degrees(np.arccos(np.clip(vec[:, 2], -1.0, 1.0)))
    phi = np.mod(np.degrees(np.arctan2(vec[:, 1], vec[:, 0])), 360.0)
    on_axis = np.hypot(vec[:, 0], vec[:, 1]) < 1e-9
    phi[on_axis] = 0.0
    return np.stack([theta, phi], axis=1)


def lab_direction(head_deg: np.ndarray, light_deg: np.ndarray) -> np.ndarray:
    """(N, 3) lab unit vectors of sample-frame lights ``light_deg`` under heads ``head_deg``."""
    return np.einsum("nij,nj->ni", rotation(head_deg), to_vectors(light_deg))


def arm_for_light(head_deg: np.ndarray, light_deg: np.ndarray) -> np.ndarray:
    """(N, 2) head and (N, 2) sample-frame lights -> (N, 2) arm (theta, phi) deg."""
    return _to_angles(lab_direction(head_deg, light_deg))


def view_for_head(head_deg: np.ndarray) -> np.ndarray:
    """Inverse of :func:`head_for_view`: the sample-frame direction of the camera."""
    r = rotation(head_deg)
    return _to_angles(r[:, 2, :])  # R^T e_z = third row of R


def light_for_arm(head_deg: np.ndarray, arm_deg: np.ndarray) -> np.ndarray:
    """Inverse of :func:`arm_for_light`: the sample-frame light for an arm position."""
    lab = to_vectors(arm_deg)
    return _to_angles(np.einsum("nji,nj->ni", rotation(head_deg), lab))


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Great-circle angle in degrees between (N, 3) unit vectors a and b (row-wise)."""
    dot = np.clip(np.einsum("ni,ni->n", a, b), -1.0, 1.0)
    # atan2 form: accurate for tiny angles where arccos(dot) loses precision.
    cross = np.linalg.norm(np.cross(a, b), axis=1)
    return np.degrees(np.arctan2(cross, dot))
