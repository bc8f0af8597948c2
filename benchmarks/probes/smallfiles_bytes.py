#!/usr/bin/env python
"""Issue 39 (the small files): what the thumbnail and the fallback maps of packaged assets would
take as JPEG, per map kind, beside the PNGs the assets hold (the baseline, read in the same run).

Each argument an asset's root layer (``m.usda``); its ``<stem>_textures`` folder's
``thumbnail.png`` and ``fallback/*.png`` are read (``usdbtf.imageio.read_image``) and their
pixels re-encoded through OIIO:

* thumbnail (256² RGBA, transparent where nothing was hit): composited over the background
  ``thumbnail.BACKGROUND`` and written as JPEG at quality 90 and 95, 4:2:0 and 4:4:4; and the
  PNG re-encoded at 128² (a box downsample of the render: an estimate of a 128² render);
* each fallback map as JPEG 4:4:4 at quality 95, 97, 98 and 100 (grey maps as 1-channel
  JPEG), with the decoded pixels' mean and largest absolute code difference from the PNG's
  (the 16-bit OpenPBR data maps are skipped: baseline JPEG is 8-bit).

The bytes are exact for these pixels; what the differences cost in the fits' error is
measured by ``benchmarks/bench_fallback.py --map-encoding``.  Usage (repository root)::

    .venv/bin/python benchmarks/probes/smallfiles_bytes.py ASSET.usda [ASSET.usda ...]
"""
from __future__ import annotations

import sys
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy)
import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks" / "research"))
from rlib import header, say  # noqa: E402

QUALITIES = (95, 97, 98, 100)


def jpeg(pixels: np.ndarray, quality: int, subsampling: str = "4:4:4") -> bytes:
    from usdbtf.imageio import encode_image

    return encode_image(pixels, "jpg", color_space="sRGB",
                        attributes={"Compression": f"jpeg:{quality}", "jpeg:subsampling": subsampling})


def main() -> None:
    from usdbtf.imageio import decode_image, encode_png_smallest, read_image, read_rgba
    from usdbtf.usd.asset.thumbnail import composite_background

    roots = [Path(a) for a in sys.argv[1:]]
    header("issue 39: thumbnail and fallback maps as JPEG (baseline: the assets' PNGs, read in this run)",
           [f"assets: {', '.join(str(r) for r in roots)}",
            "JPEG through OIIO (libjpeg-turbo), Compression jpeg:Q, jpeg:subsampling as named",
            "code error: |decoded JPEG - PNG pixels| in 8-bit codes, mean and max over every value"])
    totals: dict = {}
    for root in roots:
        tex = root.with_name(root.stem + "_textures")
        say(f"\n## {root.parent.name}\n")
        thumb = read_rgba(tex / "thumbnail.png")
        flat = composite_background(thumb)
        half = np.rint(thumb.reshape(128, 2, 128, 2, 4).astype(np.float64).mean(axis=(1, 3))).astype(np.uint8)
        rows = [("thumbnail PNG 256² (as shipped)", (tex / "thumbnail.png").stat().st_size),
                ("thumbnail PNG 128² (box of the 256² render)", len(encode_png_smallest(half, color_space="sRGB", level=9)))]
        for q in (90, 95):
            for sub in ("4:2:0", "4:4:4"):
                rows.append((f"thumbnail JPEG 256² q{q} {sub}", len(jpeg(flat, q, sub))))
        say("| thumbnail | bytes | x shipped |\n|---|---:|---:|")
        for name, size in rows:
            say(f"| {name} | {size:,} | {size / rows[0][1]:.3f} |")
            totals.setdefault(name, 0)
            totals[name] += size
        say("\n| map | PNG bytes | " + " | ".join(f"JPEG q{q} bytes (mean / max code diff)" for q in QUALITIES) + " |")
        say("|---|---:|" + "---:|" * len(QUALITIES))
        for path in sorted((tex / "fallback").glob("*.png")):
            pixels, info = read_image(path)
            pixels = pixels[..., :info.channels]
            png = path.stat().st_size
            totals.setdefault(("map", path.stem, "png"), 0)
            totals[("map", path.stem, "png")] += png
            if pixels.dtype != np.uint8:
                say(f"| {path.stem} (16-bit) | {png:,} |" + " - |" * len(QUALITIES))
                continue
            cells = []
            for q in QUALITIES:
                blob = jpeg(pixels, q)
                back = decode_image(blob)[..., :pixels.shape[-1]].astype(np.int16)
                diff = np.abs(back - pixels.astype(np.int16))
                cells.append(f"{len(blob):,} ({diff.mean():.2f} / {diff.max()})")
                totals.setdefault(("map", path.stem, q), 0)
                totals[("map", path.stem, q)] += len(blob)
            say(f"| {path.stem} | {png:,} | " + " | ".join(cells) + " |")
    say("\n## totals over the assets\n")
    say("| file | PNG | " + " | ".join(f"JPEG q{q}" for q in QUALITIES) + " |")
    say("|---|---:|" + "---:|" * len(QUALITIES))
    stems = sorted({k[1] for k in totals if isinstance(k, tuple)})
    for stem in stems:
        png = totals[("map", stem, "png")]
        say(f"| {stem} | {png:,} | " + " | ".join(
            f"{totals[('map', stem, q)]:,} ({totals[('map', stem, q)] / png:.2f})" if ("map", stem, q) in totals
            else "-" for q in QUALITIES) + " |")
    for name in [k for k in totals if isinstance(k, str)]:
        say(f"| {name} | {totals[name]:,} | | | | |")


if __name__ == "__main__":
    main()
