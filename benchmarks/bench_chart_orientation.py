#!/usr/bin/env python
"""Chart borders on the scene benchmark's meshes (issue 31): what turning the charts
(:mod:`usdbtf.unwrap.orient`) and continuing each border through a one-texel band
(:mod:`usdbtf.quilt.atlas`) do, against the charts as cut and quilted before, in one run.

For each mesh of ``bench_scene_build.py`` (sphere / pebbles, cylinder / fuzzy moss, box / ridged
fabric), its UVs as a user brings them (``usdbtf unwrap`` at 640 texels/m with the charts as
xatlas cut them), kept at the material's density (``--keep-uvs``), three ways:

as cut      the charts as the user's UVs orient them, no border band (usdbtf before this work);
turned      the charts turned by quarter turns (the share of border length whose texture axes
            continue, before and after, is printed);
turned + band  and each later-quilted chart continuing its neighbour through the border itself.

Measured per way and seed: seams inside charts and across chart boundaries over the material's
natural neighbour difference (``bench_scene_build.seams``'s metrics), the share of border length
whose texture axes continue (turn within 45 degrees of none, measured on the atlas), and the
quilt's wall time.

Usage (repository root)::

    .venv/bin/python benchmarks/bench_chart_orientation.py            # 64² materials, seeds 0 1, ~3 min
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "pipeline"))
import usdbtf  # noqa: E402,F401  (pins the numeric platform before numpy's BLAS loads)
from bench_scene_build import MATERIALS, _meshes  # noqa: E402
from common import OUT, format_machine, machine_info, median, timestamp, write_json  # noqa: E402


def _user_mesh(mesh):
    """The mesh with its UVs as a user brings them: unwrapped at 640 texels/m, charts as cut."""
    from usdbtf.mesh import Mesh
    from usdbtf.unwrap import UnwrapOptions, unwrap

    cut = unwrap(Mesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)),
                 UnwrapOptions(texels_per_metre=640.0, orient_charts=False)).mesh
    return Mesh(cut.points, cut.triangles, uv=cut.uv)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=64, help="synthetic sample side in texels (default 64)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    args = p.parse_args()
    import usdbtf.quilt.atlas as atlas_module
    from usdbtf.cli import main as cli
    from usdbtf.compress import read_compressed
    from usdbtf.mesh import weld
    from usdbtf.quilt import QuiltOptions, quilt
    from usdbtf.quilt.atlas import chart_border_error, face_neighbours
    from usdbtf.quilt.features import image_features
    from usdbtf.quilt.seams import natural_neighbour_error, seam_error_all_samples
    from usdbtf.unwrap import UnwrapOptions, texel_density, unwrap
    from usdbtf.unwrap.orient import aligned_share, chart_turns

    band = atlas_module._BAND
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_chart_orientation_") as tmp:
        for (name, preset), (mesh_name, (mesh, _)) in zip(MATERIALS, _meshes().items()):
            raw, comp = Path(tmp) / f"{name}_raw", Path(tmp) / name
            assert cli(["synth", preset, "-o", str(raw), "--sampling", "tiny", "--size", str(args.size), "-q"]) == 0
            assert cli(["compress", "-q", str(raw), "-o", str(comp), "--k", "6", "--codec", "png"]) == 0
            cbtf = read_compressed(comp)
            features, S, ws = image_features(cbtf), cbtf.n_samples, cbtf.width
            natural = natural_neighbour_error(features, ws, cbtf.height, S)
            user = _user_mesh(mesh)
            for way, orient, with_band in (("as cut", False, False), ("turned", True, False),
                                           ("turned + band", True, True)):
                unwrapped = unwrap(user, UnwrapOptions(texels_per_metre=texel_density(cbtf), keep_uvs=True,
                                                       orient_charts=orient))
                layer = unwrapped.mesh
                neighbours = face_neighbours(weld(layer.points)[layer.triangles])
                atlas_module._BAND = band if with_band else 0.0
                per_seed = []
                for seed in args.seeds:
                    t = time.perf_counter()
                    result = quilt(cbtf, QuiltOptions(seed=seed), atlas=unwrapped)
                    seconds = time.perf_counter() - t
                    per_seed.append({
                        "seed": seed, "quilt_s": seconds,
                        "in_charts": seam_error_all_samples(result.positions, features, ws, S,
                                                            labels=unwrapped.chart_map) / natural,
                        "boundary": chart_border_error(result.positions, layer, neighbours, features, ws, S) / natural})
                atlas_module._BAND = band
                a = unwrapped.atlas
                turns = chart_turns(layer.points[a.vertex_of], a.faces, a.st * [a.width, a.height], a.face_chart)
                rows.append({"mesh": mesh_name, "material": preset, "way": way, "atlas": a.width,
                             "charts": a.charts, "aligned": aligned_share(turns, np.zeros(a.charts, np.int64)),
                             "seeds": per_seed})
    machine = machine_info()
    path = write_json(OUT / f"chart_orientation_{timestamp()}.json",
                      {"machine": machine, "size": args.size, "rows": rows})
    print(format_machine(machine))
    print(f"\ninputs: synth pebbles / fuzzy_moss / ridged_fabric, sampling tiny, {args.size}^2, k 6; the meshes "
          f"of bench_scene_build.py with their UVs as cut (usdbtf unwrap at 640 texels/m, charts not turned), "
          f"kept at the material's density; seeds {args.seeds}\n")
    print("| mesh (material) | way | atlas | border length aligned | seams in charts / natural | "
          "chart boundaries / natural | quilt s (median) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        ins = ", ".join(f"{s['in_charts']:.2f}" for s in r["seeds"])
        bnd = ", ".join(f"{s['boundary']:.2f}" for s in r["seeds"])
        aligned = f"{r['aligned']:.0%}"
        print(f"| {r['mesh']} ({r['material']}) | {r['way']} | {r['atlas']}² | {aligned} | {ins} | {bnd} | "
              f"{median([s['quilt_s'] for s in r['seeds']]):.1f} |")
    print(f"\n{path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
