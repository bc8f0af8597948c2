"""Example meshes for the quilt / unwrap / render examples: sphere, capped cylinder, torus knot.

    python examples/shapes.py torus_knot -o knot.obj [--scale 1.0]

Written as OBJ with per-vertex normals (the cylinder's caps have their own vertices, so its
rims stay sharp).  Sizes are in metres: a 5 cm sphere, a 6 cm x 12 cm cylinder, and a
(2, 3) torus knot about 10 cm across -- a few hundred texels across at a 5 cm / 128 texel
sample, like the objects of the paper's Fig. 5.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def sphere(radius: float = 0.05, subdivisions: int = 4):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions, radius=radius)
    points = np.asarray(m.vertices)
    return points, np.asarray(m.faces), points / radius


def _grid_faces(rows: int, cols: int, offset: int = 0, closed_u: bool = True) -> np.ndarray:
    """Quads of a (rows + 1) x cols vertex grid (columns wrap when closed_u), as triangles."""
    faces = []
    span = cols if closed_u else cols - 1
    for i in range(rows):
        for j in range(span):
            a = offset + i * cols + j
            b = offset + i * cols + (j + 1) % cols
            c, d = a + cols, b + cols
            faces += [[a, b, d], [a, d, c]]
    return np.asarray(faces)


def cylinder(radius: float = 0.03, height: float = 0.12, sections: int = 96, rings: int = 24):
    """Side, top and bottom with separate vertices (sharp rims), axis along Y."""
    phi = 2 * np.pi * np.arange(sections) / sections
    ys = np.linspace(-height / 2, height / 2, rings + 1)
    side = np.stack([np.tile(radius * np.cos(phi), rings + 1), np.repeat(ys, sections),
                     np.tile(-radius * np.sin(phi), rings + 1)], axis=1)
    side_n = np.stack([side[:, 0] / radius, np.zeros(len(side)), side[:, 2] / radius], axis=1)
    faces = [_grid_faces(rings, sections)]
    points, normals = [side], [side_n]
    for y, up in ((height / 2, 1.0), (-height / 2, -1.0)):
        base = sum(len(p) for p in points)
        rim = np.stack([radius * np.cos(phi), np.full(sections, y), -radius * np.sin(phi)], axis=1)
        cap = np.vstack([[0.0, y, 0.0], rim])
        fan = np.stack([np.zeros(sections, int), 1 + np.arange(sections), 1 + (np.arange(sections) + 1) % sections], 1)
        faces.append(base + (fan if up > 0 else fan[:, [0, 2, 1]]))
        points.append(cap)
        normals.append(np.tile([0.0, up, 0.0], (len(cap), 1)))
    return np.vstack(points), np.vstack(faces), np.vstack(normals)


def torus_knot(p: int = 2, q: int = 3, scale: float = 0.03, tube: float = 0.011, segments: int = 360,
               sides: int = 24):
    """A (p, q) torus knot tube; the centre line lies on a torus of radii 2 x scale and scale."""
    t = 2 * np.pi * np.arange(segments) / segments

    def centre(t):
        r = scale * (2 + np.cos(q * t))
        return np.stack([r * np.cos(p * t), scale * np.sin(q * t), r * np.sin(p * t)], axis=-1)

    c = centre(t)
    tangent = centre(t + 1e-4) - centre(t - 1e-4)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.cross(tangent, [0.0, 1.0, 0.0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)
    a = 2 * np.pi * np.arange(sides) / sides
    ring = np.cos(a)[None, :, None] * normal[:, None, :] + np.sin(a)[None, :, None] * binormal[:, None, :]
    points = (c[:, None, :] + tube * ring).reshape(-1, 3)
    normals = ring.reshape(-1, 3)
    faces = []
    for i in range(segments):
        for j in range(sides):
            a0 = i * sides + j
            b0 = i * sides + (j + 1) % sides
            a1 = ((i + 1) % segments) * sides + j
            b1 = ((i + 1) % segments) * sides + (j + 1) % sides
            faces += [[a0, b0, b1], [a0, b1, a1]]
    faces = np.asarray(faces)
    # Outward winding (the normals point away from the tube's centre line).
    p0 = points[faces]
    if np.einsum("fd,fd->f", np.cross(p0[:, 1] - p0[:, 0], p0[:, 2] - p0[:, 0]), normals[faces].sum(1)).mean() < 0:
        faces = faces[:, [0, 2, 1]]
    return points, faces, normals


SHAPES = {"sphere": sphere, "cylinder": cylinder, "torus_knot": torus_knot}


def write_obj(path: Path, points, faces, normals) -> Path:
    lines = [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in points]
    lines += [f"vn {x:.6g} {y:.6g} {z:.6g}" for x, y, z in normals]
    lines += [f"f {a}//{a} {b}//{b} {c}//{c}" for a, b, c in np.asarray(faces) + 1]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("shape", choices=sorted(SHAPES))
    p.add_argument("-o", "--output", type=Path, required=True)
    p.add_argument("--scale", type=float, default=1.0, help="multiply every size (default 1)")
    args = p.parse_args(argv)
    points, faces, normals = SHAPES[args.shape]()
    write_obj(args.output, points * args.scale, faces, normals)
    print(f"{args.shape}: {len(points)} vertices, {len(faces)} triangles -> {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
