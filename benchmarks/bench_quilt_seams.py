#!/usr/bin/env python
"""Quilting seams inside charts against the material's natural neighbour difference (issue 31):
the boundary cut and the overlap width, on the scene benchmark's meshes.

Builds the scene of ``benchmarks/bench_scene_build.py`` (sphere / pebbles, cylinder / fuzzy moss,
box / ridged fabric, tiny sampling, ``--size`` texels, k 6) once with ``usdbtf build``, then
quilts each binding's atlas again (:func:`usdbtf.quilt.atlas.quilt_atlas`, default block) with:

efros-freeman   the baseline, measured in this run: Efros & Freeman's cut (the path of least
                ``|old - new|^2`` over the strip's texels, 8-connected; the cut usdbtf used
                before issue 31), with the previous default overlap, a sixth of the block;
pair            usdbtf's cut (:mod:`usdbtf.quilt.cut`: least summed difference of the texel pairs
                the cut makes neighbours) with overlaps of a sixth, a quarter, a third (the
                default) and three eighths of the block (at least 3 texels).

For each: the seam error inside charts over the natural neighbour difference (the scene
benchmark's "seams in charts / natural"), per seed and their median, and the quilt's wall time
(median over seeds; the machine is shared, so compare times within one run).

Usage (repository root)::

    .venv/bin/python benchmarks/bench_quilt_seams.py --size 64      # ~5 min on 2 cores

Writes benchmarks/out/quilt_seams_<timestamp>.json and prints a markdown table.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "pipeline"))
import usdbtf  # noqa: E402,F401  (pins the numeric platform before numpy's BLAS loads)
from common import OUT, format_machine, machine_info, timestamp, write_json  # noqa: E402


def efros_freeman_keep_old_mask(image, old, new, placed, widths):
    """The baseline cut, same signature as :func:`usdbtf.quilt.cut.keep_old_mask`: per side, the
    8-connected path of least ``|old - new|^2`` through the strip; old kept on the far side."""
    B = old.shape[0]
    left, top, right, bottom = widths
    strip = np.zeros((B, B), bool)                  # the overlap strips: only there is err needed
    strip[:, :left] = strip[:top] = True
    if right:
        strip[:, B - right:] = True
    if bottom:
        strip[B - bottom:] = True
    strip &= placed
    err = np.zeros((B, B), np.float32)
    d = image[new[strip]] - image[old[strip]]
    err[strip] = np.einsum("nd,nd->n", d, d)

    def path(e):
        n = e.shape[0]
        cost = e.astype(np.float64)
        for y in range(1, n):
            best = cost[y - 1].copy()
            np.minimum(best[1:], cost[y - 1][:-1], out=best[1:])
            np.minimum(best[:-1], cost[y - 1][1:], out=best[:-1])
            cost[y] += best
        rows = cost.tolist()
        cols = np.empty(n, np.intp)
        col = cols[-1] = rows[-1].index(min(rows[-1]))
        for y in range(n - 1, 0, -1):
            lo = max(col - 1, 0)
            above = rows[y - 1][lo:col + 2]
            col = cols[y - 1] = lo + above.index(min(above))
        return cols

    keep = np.zeros((B, B), bool)
    c = np.arange(B)
    if left:
        keep |= c[None, :] < path(err[:, :left])[:, None]
    if right:
        keep |= c[None, ::-1] < path(err[:, ::-1][:, :right])[:, None]
    if top:
        keep |= c[:, None] < path(err[:top, :].T)[None, :]
    if bottom:
        keep |= c[::-1, None] < path(err[::-1][:bottom, :].T)[None, :]
    return keep


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=64, help="synthetic sample side in texels (default 64)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    args = p.parse_args()
    from bench_scene_build import write_scene

    from usdbtf.compress import read_compressed
    from usdbtf.quilt import cut, engine
    from usdbtf.quilt.atlas import quilt_atlas
    from usdbtf.quilt.core import QuiltOptions
    from usdbtf.quilt.engine import default_block
    from usdbtf.quilt.features import image_features
    from usdbtf.quilt.seams import natural_neighbour_error, seam_error_all_samples
    from usdbtf.unwrap import read_unwrap
    from usdbtf.usd.scenes.build import build
    from usdbtf.usdstage import usd_warnings_silenced

    block = default_block(args.size, args.size)
    sixth = max(3, round(block / 6))
    variants = [("efros-freeman", sixth)] + [("pair", o) for o in
                                             dict.fromkeys([sixth, max(3, round(block / 4)), max(3, round(block / 3)),
                                                            max(3, round(3 * block / 8))])]
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_quilt_seams_") as tmp:
        with usd_warnings_silenced():
            scene = write_scene(Path(tmp), args.size)
        report = build(scene)
        compressed = {r.material: r.compressed for r in report["recipes"]}
        for chain in report["bindings"]:
            cbtf = read_compressed(compressed[chain.material])
            unwrapped = read_unwrap(chain.unwrap)
            feats = image_features(cbtf)
            natural = natural_neighbour_error(feats, cbtf.width, cbtf.height, cbtf.n_samples)
            for cut_name, overlap in variants:
                engine.keep_old_mask = efros_freeman_keep_old_mask if cut_name == "efros-freeman" else cut.keep_old_mask
                ratios, seconds = [], []
                for seed in args.seeds:
                    res = quilt_atlas(cbtf, unwrapped, QuiltOptions(overlap=overlap, seed=seed))
                    seam = seam_error_all_samples(res.positions, feats, cbtf.width, cbtf.n_samples,
                                                  labels=unwrapped.chart_map)
                    ratios.append(seam / natural)
                    seconds.append(res.record["_seconds"])
                rows.append({"binding": chain.prims[0], "cut": cut_name, "block": res.options.block,
                             "overlap": overlap, "ratios": ratios, "ratio_median": statistics.median(ratios),
                             "quilt_s_median": statistics.median(seconds), "quilt_s": seconds})
                print(rows[-1], file=sys.stderr, flush=True)
        engine.keep_old_mask = cut.keep_old_mask
    machine = machine_info()
    path = write_json(OUT / f"quilt_seams_{timestamp()}.json",
                      {"machine": machine, "size": args.size, "seeds": args.seeds, "rows": rows})
    print(format_machine(machine))
    print(f"\ninputs: the scene of benchmarks/bench_scene_build.py at {args.size}^2 (tiny sampling, k 6), each "
          f"binding's atlas quilted again with the default block; seeds {args.seeds}\n")
    print("| binding | cut | block | overlap | seams in charts / natural (per seed) | median | quilt s (median) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['binding']} | {r['cut']} | {r['block']} | {r['overlap']} | "
              f"{', '.join(f'{x:.2f}' for x in r['ratios'])} | {r['ratio_median']:.2f} | {r['quilt_s_median']:.1f} |")
    print(f"\n{path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
