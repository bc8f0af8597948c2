"""Side-by-side sheet: measured (synthetic) samples vs their reconstruction from a compressed BTF.

    python examples/figure.py RAW_MANIFEST COMPRESSED -o sheet.png [--samples 0,40,...]
    python examples/figure.py --readme [WORKDIR]     # regenerates docs/result.png

Rows: original, reconstruction, |difference| x 4.  Columns: (view, light) samples.
Colours go working space -> sRGB through OCIO, the file is written through OIIO.
"""
from __future__ import annotations

import argparse

import cv2
import numpy as np

from usdbtf import color
from usdbtf.compress import read_compressed, reconstruct
from usdbtf.imageio import write_image
from usdbtf.io import open_btf

from pictures import refused


def sheet(raw, cbtf, indices, *, scale: int = 2) -> np.ndarray:
    """(rows * (H*scale + label), cols * (W*scale + gap), 3) uint8 sRGB image."""
    to_srgb = color.processor(raw.working_space, "sRGB Encoded Rec.709 (sRGB)", raw.ocio_config)
    orig = raw.read_samples(indices)
    rec = reconstruct(cbtf, indices)
    diff = np.abs(orig - rec) * 4
    rows = []
    for name, block in (("original", orig), (f"k = {cbtf.k}", rec), ("|diff| x4", diff)):
        tiles = []
        for i, img in zip(indices, block):
            enc = np.clip(to_srgb.apply(img), 0, 1)
            tile = cv2.resize((enc * 255 + 0.5).astype(np.uint8), None, fx=scale, fy=scale,
                              interpolation=cv2.INTER_NEAREST)
            tile = cv2.copyMakeBorder(tile, 18, 4, 4, 4, cv2.BORDER_CONSTANT, value=(255, 255, 255))
            v, l = raw.sampling.view[i], raw.sampling.light[i]
            label = f"{name}  v({v[0]:.0f},{v[1]:.0f}) l({l[0]:.0f},{l[1]:.0f})"
            cv2.putText(tile, label, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
            tiles.append(tile)
        rows.append(np.hstack(tiles))
    return np.vstack(rows)


def readme_figure(workdir, out, presets=("pebbles", "ridged_fabric", "fuzzy_moss"), samples=(20, 75, 130, 160)):
    """The README picture: for each preset, originals over reconstructions (default solver, k = 48)."""
    from pathlib import Path

    from usdbtf.cli import main as usdbtf

    workdir = Path(workdir)
    rows = []
    for preset in presets:
        raw, comp = workdir / f"{preset}_raw", workdir / f"{preset}_c"
        usdbtf(["synth", preset, "-o", str(raw), "--sampling", "small", "--size", "96", "--seed", "3", "-q", "--force"])
        usdbtf(["compress", str(raw), "-o", str(comp), "--k", "48", "-q", "--force"])
        rows.append(sheet(open_btf(raw), read_compressed(comp), np.array(samples))[:2 * (96 * 2 + 22)])
    write_image(out, np.vstack(rows), color_space="sRGB Encoded Rec.709 (sRGB)")
    print(f"wrote {out}")


def main(argv=None):
    import sys

    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--readme":
        readme_figure(argv[1] if len(argv) > 1 else "examples/out/figure", "docs/result.png")
        return
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("raw")
    p.add_argument("compressed")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--samples", help="comma-separated sample indices (default: 4 spread out)")
    a = p.parse_args(argv)
    if (code := refused(a.output, 'figure')) is not None:
        return code
    raw = open_btf(a.raw)
    cbtf = read_compressed(a.compressed)
    if a.samples:
        idx = np.array([int(s) for s in a.samples.split(",")])
    else:
        idx = np.linspace(0, raw.n_samples - 1, 6).round().astype(int)[1:-1]
    write_image(a.output, sheet(raw, cbtf, idx), color_space="sRGB Encoded Rec.709 (sRGB)")
    print(f"wrote {a.output}")


if __name__ == "__main__":
    raise SystemExit(main())
