"""Shared inputs for the quilt / unwrap / render tests (issue 5): real files made by the CLI.

* a synthetic pebbles BTF, 13 x 13 samples ("small"), 48 x 48 texels, float32 EXR in linear
  Rec.709 (so ``usdbtf decompress`` writes float files and comparisons are not limited by
  8-bit rounding), 0.05 m across, compressed to k = 24;
* meshes written as files: an icosphere (OBJ), a plane with texture coordinates, and a
  plane with a box floating above it (for cast shadows).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from usdbtf.cli import main

PHYSICAL_SIZE = 0.05        # metres across the 48-texel sample -> 960 texels per metre
SIZE = 48


def cli(*argv) -> None:
    code = main([str(a) for a in argv])
    assert code == 0, f"usdbtf {' '.join(map(str, argv))} exited {code}"


@pytest.fixture(scope="module")
def work(request, tmp_path_factory) -> Path:
    """A scratch folder per test module (import this fixture into the module)."""
    return tmp_path_factory.mktemp(request.module.__name__.removeprefix("test_"))


@pytest.fixture(scope="module")
def pebbles(work) -> Path:
    """The compressed pebbles sample (module docstring), made once per test module."""
    return compressed_pebbles(work)


def compressed_pebbles(folder: Path, k: int = 24) -> Path:
    """The compressed BTF described in the module docstring (raw manifest at folder/raw)."""
    raw, out = folder / "raw", folder / "pebbles_c"
    cli("synth", "pebbles", "-o", raw, "--sampling", "small", "--size", SIZE, "--format", "exr",
        "--bit-depth", "float", "--physical-size", PHYSICAL_SIZE, "--seed", 3, "-q")
    cli("compress", raw, "-o", out, "--k", k, "-q")
    return out


def write_sphere(path: Path, radius: float = 0.03, subdivisions: int = 3) -> Path:
    import trimesh

    trimesh.creation.icosphere(subdivisions, radius=radius).export(str(path))
    return path


def plane_with_uv(size_m: float, n: int = 4, *, z: float = 0.0):
    """An n x n grid in the XY plane facing +Z, st = (x, y) / size + 0.5 (image right = +X, up = +Y).
    Returns (points (N, 3), faces (F, 3), uv (N, 2))."""
    g = np.linspace(-size_m / 2, size_m / 2, n + 1)
    x, y = np.meshgrid(g, g)
    points = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)
    uv = points[:, :2] / size_m + 0.5
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v0 = (i * (n + 1) + j).ravel()
    faces = np.concatenate([np.stack([v0, v0 + 1, v0 + n + 2], 1), np.stack([v0, v0 + n + 2, v0 + n + 1], 1)])
    return points, faces, uv


def write_obj(path: Path, points, faces, uv=None, normals=None) -> Path:
    """A plain OBJ writer (positions, optional texture coordinates and normals per vertex)."""
    lines = [f"v {p[0]:.9g} {p[1]:.9g} {p[2]:.9g}" for p in points]
    if uv is not None:
        lines += [f"vt {t[0]:.9g} {t[1]:.9g}" for t in uv]
    if normals is not None:
        lines += [f"vn {v[0]:.9g} {v[1]:.9g} {v[2]:.9g}" for v in normals]
    for f in np.asarray(faces) + 1:
        if uv is not None and normals is not None:
            lines.append("f " + " ".join(f"{v}/{v}/{v}" for v in f))
        elif uv is not None:
            lines.append("f " + " ".join(f"{v}/{v}" for v in f))
        else:
            lines.append("f " + " ".join(str(v) for v in f))
    path.write_text("\n".join(lines) + "\n")
    return path
