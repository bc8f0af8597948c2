#!/usr/bin/env python
"""Issue 39: what the asset's thumbnail (every lod loads it) costs at sizes below its 256²,
for a decision on its size; the shipped size (256², ``thumbnail.THUMBNAIL_SIZE``) is the
baseline, measured in the same run.  Each argument a compressed folder; the thumbnail is
rendered as ``package`` renders it (a 5 cm swatch) at each size and encoded as the RGBA PNG
written before the JPEG thumbnail (PNG level 9), with the smaller PNG filter, and as it is
written now (``thumbnail.thumbnail_jpeg``).

Usage (repository root)::

    .venv/bin/python benchmarks/probes/thumbnail_bytes.py FOLDER [FOLDER ...]
"""
from __future__ import annotations

import sys
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy)

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks" / "research"))
from rlib import header, say  # noqa: E402

SIZES = (256, 192, 128)


def main() -> None:
    from usdbtf.imageio import encode_image, encode_png_smallest
    from usdbtf.mesh import Mesh
    from usdbtf.render.output import display_processor
    from usdbtf.usd.asset.package import read_input
    from usdbtf.usd.asset.thumbnail import THUMBNAIL_SIZE, render_thumbnail, thumbnail_jpeg

    folders = [Path(a) for a in sys.argv[1:]]
    header("issue 39: the thumbnail's bytes by size (baseline: the shipped THUMBNAIL_SIZE)",
           [f"compressed folders: {', '.join(map(str, folders))}; a 5 cm swatch, rendered as package renders it",
            f"shipped size {THUMBNAIL_SIZE}²; 'smallest' = level 9 with the smaller of two PNG filters"])
    say("| folder | size | RGBA PNG (before) | smallest filter | vs shipped size | JPEG as written now |")
    say("|---|---:|---:|---:|---:|---:|")
    for folder in folders:
        cbtf = read_input(folder)
        mesh = Mesh.swatch(0.05, 0.05)
        _, display, _ = display_processor(cbtf.working_space, None, None, cbtf.ocio_config)
        base = None
        for size in SIZES:
            pixels = render_thumbnail(cbtf, mesh, size)
            written = len(encode_image(pixels, "png", color_space=display, attributes={"png:compressionLevel": 9}))
            smallest = len(encode_png_smallest(pixels, color_space=display, level=9))
            jpeg = len(thumbnail_jpeg(cbtf, mesh, size))
            base = written if size == THUMBNAIL_SIZE else base
            say(f"| {folder.name} | {size}² | {written:,} | {smallest:,} | {written / base:.3f} | {jpeg:,} |")


if __name__ == "__main__":
    main()
