"""A writer of Bonn binary BTF files (``.btf``) for tests only: independent of usdbtf.

It writes the layouts documented by cgbonn/btflib's writers (``write_common_header.m``,
``write_meta_data.m``, ``write_bidir_sampling.m``, ``write_ubo_dfmf.m``,
``write_ubo_fmf.m``, ``write_bdi_header.m``) and its readers for the formats it has no
writer for (PVF), so that a file both this writer's reference values and an independent
reader (btf-extractor) agree on is evidence the format is understood.  Nothing here
imports usdbtf: the forward colour model, the SVD and the expected images are computed
here in float64.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

# btflib undecorrelate.m's YUV -> RGB matrix; its inverse is the encoder's RGB -> YUV.
YUV_TO_RGB = np.array([[1.0, 0.0, 1.13983], [1.0, -0.39465, -0.5806], [1.0, 2.03211, 0.0]])
RGB_TO_YUV = np.linalg.inv(YUV_TO_RGB)
EPS = 1e-5
SCALAR = {2: "<f2", 4: "<f4", 8: "<f8"}


def u32(*values) -> bytes:
    return struct.pack(f"<{len(values)}I", *values)


def f32(values) -> bytes:
    return np.asarray(values, "<f4").tobytes()


def meta_block(*, version: int = 4, channel_names=("R", "G", "B"), cosine_flag: int = 0, ppmm: float = 10.0,
               xml: bytes = b"<measurement/>", setup: bytes = b"test rig", size_delta: int = 0) -> bytes:
    """The meta-data block; ``size_delta`` corrupts its size field."""
    body = u32(version) + setup.ljust(80, b"\0") + b"camera".ljust(80, b"\0") + b"led".ljust(80, b"\0")
    body += f32([ppmm]) + f32([1.0, 1.0, 1.0])
    if version > 1:
        body += u32(cosine_flag)
    if version > 2:
        body += u32(len(xml)) + xml
    if version > 3:
        body += u32(len(channel_names)) + b"".join(u32(len(c)) + c.encode() for c in channel_names)
    return u32(len(body) + 4 + size_delta) + body


def directions_block(views_rad, lights_rad) -> bytes:
    """btflib write_bidir_sampling: per view its (theta, phi) then the whole light list."""
    lights_rad = np.asarray(lights_rad, float)
    out = u32(len(views_rad))
    for v in np.asarray(views_rad, float):
        out += f32(v) + u32(len(lights_rad)) + f32(lights_rad.reshape(-1))
    return out


def common_header(signature: str, views_rad, lights_rad, width: int, height: int, *, rotations=0, **meta) -> bytes:
    out = signature.encode() + meta_block(**meta) + directions_block(views_rad, lights_rad) + u32(width, height)
    if signature.endswith("R"):
        out += u32(rotations) + f32(np.tile(np.eye(3), (rotations, 1, 1)).reshape(-1))
    return out


# --------------------------------------------------------------------------- colour and factors


def rgb_to_model11(rgb: np.ndarray) -> np.ndarray:
    """Forward of btflib's colour model 11: (log(Y + eps), U / (Y + eps), V / (Y + eps))."""
    yuv = rgb @ RGB_TO_YUV.T
    y = yuv[..., 0] + EPS
    return np.stack([np.log(y), yuv[..., 1] / y, yuv[..., 2] / y], axis=-1)


def model11_to_rgb_btflib(c: np.ndarray) -> np.ndarray:
    y = np.exp(c[..., 0]) - EPS
    yuv = np.stack([y, c[..., 1] * (y + EPS), c[..., 2] * (y + EPS)], axis=-1)
    return yuv @ YUV_TO_RGB.T


def model11_to_rgb_zeroeffects(c: np.ndarray) -> np.ndarray:
    """zeroeffects/btf's inverse: chroma times Y, plus eps, and RGB clamped to [0, 1]."""
    y = np.exp(c[..., 0]) - EPS
    yuv = np.stack([y, c[..., 1] * y + EPS, c[..., 2] * y + EPS], axis=-1)
    return np.clip(yuv @ YUV_TO_RGB.T, 0.0, 1.0)


def factorise(matrix: np.ndarray, k: int):
    """Truncated SVD of (S, T) ``matrix``: (singular values (k,), U (S, k), S*V (T, k))."""
    u, s, vt = np.linalg.svd(matrix, full_matrices=False)
    return s[:k], u[:, :k], (vt[:k].T * s[:k])


def stored(values, scalar_size: int) -> np.ndarray:
    """Values as the file stores them (rounded to the scalar type), back in float64."""
    return np.asarray(values, SCALAR[scalar_size]).astype(np.float64)


# --------------------------------------------------------------------------- formats


def dfmf_file(path: Path, channels, *, views_rad, lights_rad, width, height, model=11, signature="!DFMF08FCR",
              k_max=None, mean=(0, 0, 0), matrix=np.eye(3), scalar_size=2, over_samples=True, **meta) -> Path:
    """``channels``: per channel (singular values, U (S, k), S*V (T, k)) -- U over samples
    (rows view-major v nL + l), S*V over texels (rows y W + x, y = 0 the top row).
    ``over_samples=False`` writes the transposed arrangement (U over texels)."""
    k_max = max(u.shape[1] for _, u, _ in channels) if k_max is None else k_max
    out = common_header(signature, views_rad, lights_rad, width, height, **meta)
    out += u32(k_max) + struct.pack("<i", model) + f32(mean) + f32(np.asarray(matrix).reshape(-1))
    dt = SCALAR[scalar_size]
    for s, u, sxv in channels:
        if not over_samples:
            u, sxv = sxv, u
        out += struct.pack("<B", scalar_size) + u32(u.shape[1], u.shape[0], sxv.shape[0])
        out += np.asarray(s, dt).tobytes() + np.asarray(u, dt).tobytes() + np.asarray(sxv, dt).tobytes()
    path.write_bytes(out)
    return path


def fmf_file(path: Path, s, u, sxv, *, views_rad, lights_rad, width, height, signature="!FMF12FCER",
             header_version=2, drr=0, height_map=(0, 0), scalar_size=2, k_repeat=None, **meta) -> Path:
    """One factorisation of all channels: U (nC S, k) rows c + nC s, S*V (T, k)."""
    out = common_header(signature, views_rad, lights_rad, width, height, **meta)
    if "12FCE" in signature:
        out += struct.pack("<B", header_version)
        if header_version >= 1:
            out += u32(drr)
        if header_version >= 2:
            out += u32(*height_map) + np.zeros(height_map[0] * height_map[1], "<f2").tobytes()
    dt = SCALAR[scalar_size]
    k = u.shape[1]
    out += u32(k) + struct.pack("<B", scalar_size) + u32(k if k_repeat is None else k_repeat, u.shape[0], sxv.shape[0])
    out += np.asarray(s, dt).tobytes() + np.asarray(u, dt).tobytes() + np.asarray(sxv, dt).tobytes()
    path.write_bytes(out)
    return path


def pvf_file(path: Path, per_view, *, views_rad, lights_rad, width, height, signature="!PVF06FCR", legacy=False,
             scalar_size=4, **meta) -> Path:
    """``per_view``: per view (eigenvalues (k,), mean (dim,), C (dim, k), W (n, k))."""
    k = max(c.shape[1] for _, _, c, _ in per_view)
    if legacy:
        out = signature.encode() + struct.pack("<i", 301074) + u32(k, width, height, len(per_view))
        out += directions_block(views_rad, lights_rad)
    else:
        out = common_header(signature, views_rad, lights_rad, width, height, **meta) + u32(k, len(per_view))
    dt = SCALAR[scalar_size]
    for ev, mean, comp, weights in per_view:
        out += struct.pack("<B", scalar_size) + u32(comp.shape[1], weights.shape[0], comp.shape[0])
        out += b"".join(np.asarray(a, dt).tobytes() for a in (ev, mean, comp, weights))
    path.write_bytes(out)
    return path


def bdi_file(path: Path, abrdfs: np.ndarray, *, views_rad, lights_rad, width, height, mask=None, lines=2,
             compression=None, **meta) -> Path:
    """``abrdfs``: (H, W, nV, nL, nC) values; stored as half floats, texel order y W + x,
    chunks of W * lines ABRDFs; a ``mask`` (H, W) of False texels makes a sparse BDI."""
    full = mask is None
    mask = np.ones((height, width), bool) if full else np.asarray(mask, bool)
    compression = (0 if full else 2) if compression is None else compression
    out = b"!BDIF06R2!" + meta_block(**meta) + directions_block(views_rad, lights_rad) + u32(width, height, lines)
    out += struct.pack("<B", compression) + mask.astype(np.uint8).tobytes() + u32(0)
    flat = abrdfs.reshape(height * width, -1)
    kept = flat if full else flat[mask.reshape(-1)]
    per = width * lines
    for a in range(0, len(kept), per):
        chunk = np.asarray(kept[a:a + per], "<f2").tobytes()
        out += u32(len(chunk)) + chunk
    path.write_bytes(out)
    return path
