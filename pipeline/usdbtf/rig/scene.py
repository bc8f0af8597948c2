"""What the simulated camera sees: a fiducial board with a BTF sample in its window.

Pure functions: a :class:`usdbtf.camera.Camera` (:meth:`~usdbtf.camera.Camera.framing`: a pinhole
at (0, 0, D) in the lab frame of :mod:`usdbtf.rig.kinematics` looking at the origin), the
board -> frame homography for a head position, and the frame itself.

Photometry (all scene-linear, linear Rec.709, the units of :mod:`usdbtf.synth`):

* the sample window shows the rectified BTF texture rendered for the commanded view
  and light; each texel is a flat patch of constant radiance (so the area mean of the
  rectified texel *is* the texture value, which makes the ground truth exact);
* the board paper is Lambertian: ``albedo * IRRADIANCE * cos(theta_l) / pi``
  (white 0.86, black ink 0.04);
* the lens vignettes as ``(1 + a (r / f)^2)^-2`` (``a = 1`` is the natural cos^4 law);
* the sensor adds Gaussian noise with variance ``read^2 + shot * signal``, clips to
  [0, 1] and the frame is stored sRGB-encoded (16-bit by default).

Geometry is exact perspective; appearance is the BTF at the nominal view (the view
direction's change across the small sample is ignored, as in a rectified BTF).
Frames are rendered at ``supersample`` x the resolution and box-filtered down, i.e.
every camera pixel integrates its area.
"""
from __future__ import annotations

import numpy as np

from ..camera import Camera
from ..fiducials import Board, board_image, to_cv
from ..synth import IRRADIANCE
from .kinematics import rotation

__all__ = ["frame_homography", "texture_homography", "render_frame", "vignetting", "add_sensor_noise",
           "draw_arm", "PAPER_WHITE", "INK_BLACK", "ARM_GREY"]

PAPER_WHITE = 0.86
INK_BLACK = 0.04
#: Radiance of the (matte black, unlit from the front) robot arm where it hides the view.
ARM_GREY = 0.01


def _board_to_sample(board: Board) -> np.ndarray:
    """3x3: board pixels -> sample-frame (x, y) metres, homogeneous; origin at the window centre."""
    x0, y0, x1, y1 = board.sample_rect
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    sx = board.physical_size_m[0] / board.image_size[0]
    sy = board.physical_size_m[1] / board.image_size[1]
    return np.array([[sx, 0.0, -sx * cx], [0.0, -sy, sy * cy], [0.0, 0.0, 1.0]])


def frame_homography(board: Board, head_deg, camera: Camera) -> np.ndarray:
    """3x3 homography board pixels -> frame pixels (both corner-origin) for one head position."""
    r = rotation(np.asarray(head_deg, np.float64).reshape(1, 2))[0]
    # Camera coordinates of the plane point (x, y, 0): X = lab x, Y = lab y, depth = D - lab z.
    plane = np.array([[r[0, 0], r[0, 1], 0.0], [r[1, 0], r[1, 1], 0.0], [-r[2, 0], -r[2, 1], camera.distance_m]])
    k = np.array([[camera.focal_px, 0.0, camera.width / 2.0], [0.0, -camera.focal_px, camera.height / 2.0],
                  [0.0, 0.0, 1.0]])
    h = k @ plane @ _board_to_sample(board)
    return h / h[2, 2]


def texture_homography(board: Board, size: int) -> np.ndarray:
    """3x3: texel coordinates of an N x N texture (corner origin) -> board pixels of the window."""
    x0, y0, x1, y1 = board.sample_rect
    return np.array([[(x1 - x0) / size, 0.0, x0], [0.0, (y1 - y0) / size, y0], [0.0, 0.0, 1.0]])


def vignetting(camera: Camera) -> np.ndarray:
    """(H, W) float32 lens falloff, 1 at the image centre."""
    y = (np.arange(camera.height) + 0.5 - camera.height / 2.0) / camera.focal_px
    x = (np.arange(camera.width) + 0.5 - camera.width / 2.0) / camera.focal_px
    r2 = y[:, None] ** 2 + x[None, :] ** 2
    return (1.0 + camera.vignetting * r2).astype(np.float32) ** -2


def _warp(src: np.ndarray, h: np.ndarray, size: tuple[int, int], nearest: bool = False) -> np.ndarray:
    import cv2
    flags = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return cv2.warpPerspective(src, to_cv(h), size, flags=flags, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _project(camera: Camera, points: np.ndarray, scale: float):
    """Lab points (n, 3) -> (frame pixels (n, 2) corner origin, depth (n,)), times ``scale``."""
    depth = camera.distance_m - points[:, 2]
    uv = np.stack([camera.width / 2.0 + camera.focal_px * points[:, 0] / depth,
                   camera.height / 2.0 - camera.focal_px * points[:, 1] / depth], axis=1)
    return uv * scale, depth


def draw_arm(frame: np.ndarray, arm_deg, camera: Camera, geometry, scale: float = 1.0) -> np.ndarray:
    """Paint the light arm (the capsules of :class:`usdbtf.rig.plan.ArmGeometry`) into ``frame``.

    Only parts between the sample and the camera are drawn (those are what can hide the
    sample; the rest is behind it or outside the view).  ``scale`` is the frame's
    supersampling factor.
    """
    import cv2
    from ..sampling import to_vectors
    d = to_vectors(np.asarray(arm_deg, np.float64).reshape(1, 2))[0]
    led = geometry.led_distance_m * d
    wrist = (geometry.led_distance_m + geometry.wrist_m) * d
    shoulder = np.asarray(geometry.shoulder_m, np.float64)
    for a, b, radius in ((led, wrist, geometry.link_radius_m), (wrist, shoulder, geometry.link_radius_m),
                         (led, led, geometry.led_radius_m)):
        pts = np.linspace(a, b, 96)
        pts = pts[(pts[:, 2] > 0) & (pts[:, 2] < camera.distance_m - 0.05)]
        if len(pts) == 0:
            continue
        uv, depth = _project(camera, pts, scale)
        for (u, v), z in zip(uv, depth):
            r = camera.focal_px * radius / z * scale
            if -r < u < frame.shape[1] + r and -r < v < frame.shape[0] + r:
                cv2.circle(frame, (int(round(u * 16 - 8)), int(round(v * 16 - 8))), int(round(r * 16)),
                           (ARM_GREY,) * 3, thickness=-1, lineType=cv2.LINE_AA, shift=4)
    return frame


def render_frame(board: Board, texture: np.ndarray, head_deg, light_deg, camera: Camera, *,
                 supersample: int = 2, board_albedo: np.ndarray | None = None, arm=None) -> np.ndarray:
    """The noiseless, unvignetted radiance the camera sees, (H, W, 3) float32 linear Rec.709.

    texture : (N, N, 3) rectified BTF sample for this view and light (synth radiance).
    light_deg : (theta, phi) of the light in the sample frame (shades the paper).
    board_albedo : (Hb, Wb) float32 paper reflectance (default from the board image).
    arm : optional (arm_deg, ArmGeometry): draw the light arm where it is in front of the sample.
    """
    import cv2
    ss = int(supersample)
    size = (camera.width * ss, camera.height * ss)
    scale = np.diag([float(ss), float(ss), 1.0])
    h_board = scale @ frame_homography(board, head_deg, camera)
    if board_albedo is None:
        board_albedo = paper_albedo(board)
    cos_l = max(np.cos(np.radians(float(np.asarray(light_deg).reshape(2)[0]))), 0.0)
    paper = _warp(board_albedo * np.float32(IRRADIANCE * cos_l / np.pi), h_board, size)
    n = texture.shape[0]
    h_tex = h_board @ texture_homography(board, n)
    sample = _warp(np.ascontiguousarray(texture, np.float32), h_tex, size, nearest=True)
    inside = _warp(np.ones((n, n), np.float32), h_tex, size, nearest=True)[..., None]
    frame = paper[..., None] * (1.0 - inside) + sample * inside
    if arm is not None:
        frame = draw_arm(np.ascontiguousarray(frame), arm[0], camera, arm[1], float(ss))
    if ss > 1:
        frame = cv2.resize(frame, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    return frame.astype(np.float32)


def paper_albedo(board: Board) -> np.ndarray:
    """(Hb, Wb) float32 reflectance of the printed board (ink where the image is black)."""
    grey = board_image(board).astype(np.float32) / 255.0
    return INK_BLACK + (PAPER_WHITE - INK_BLACK) * grey


def add_sensor_noise(signal: np.ndarray, camera: Camera, rng: np.random.Generator, clip: bool = True) -> np.ndarray:
    """Noisy, clipped sensor values for a vignetted radiance frame (H, W, 3) float32.

    clip=False keeps the values above the clip level (a sensor that does not saturate: what
    benchmarks/probes/rectify_clipping.py compares the clipping sensor with)."""
    var = camera.read_noise ** 2 + camera.shot_noise * np.maximum(signal, 0.0)
    noisy = signal + np.sqrt(var).astype(np.float32) * rng.standard_normal(signal.shape, dtype=np.float32)
    return np.clip(noisy, 0.0, 1.0 if clip else None)
