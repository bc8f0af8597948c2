#!/usr/bin/env python
"""Issue 39: what a packaged asset spends on its fallback maps and thumbnail, before and after
the fallback PNGs choose their filter (``imageio.encode_png_smallest``), in one run.

Per preset: ``usdbtf synth PRESET --sampling paper --size N`` and ``usdbtf compress --k K``
(cached under ``benchmarks/out/probes/fallback_bytes``), then packaged in this process
(``package`` + ``write_package``, a 5 cm swatch, no validation: the same files) and counted:

* every file under ``<stem>_textures/fallback`` and the thumbnail as written (after), and
  each fallback file's pixels re-encoded as the base commit (02cc7d4) wrote them (before:
  ``encode_image(..., "png", png:compressionLevel 9)``, libpng's default filter, data PNGs
  tagged by ``png_as_data``); the decoded pixels of both must be equal (asserted), so the
  fallbacks' fitted errors cannot differ;
* the full lod's bytes (every file it loads, ``write_package``'s summary) after, and before =
  after - the fallback files after + before (nothing else changed);
* the fallbacks' fitted errors (``usd.asset.openpbr.fit_errors``: held-out samples, working
  space, against the compressed BTF) as shipped, and for two storage choices not taken, with
  their bytes: the colour maps as JPEG (4:4:4, quality 95 and 90), and the OpenPBR 16-bit data
  maps (params, lobes) at 8 bits;
* what the second encode costs: median CPU seconds to encode the 11 maps (tiled ``--tile`` times a
  side, a larger texture of the same statistics) the base commit's way and the smaller-filter way.

Usage (repository root)::

    .venv/bin/python benchmarks/probes/fallback_bytes.py [--presets metal_flakes,pebbles,velvet] [--size 64] [--k 150] [--tile 8]
"""
from __future__ import annotations

import argparse
import contextlib
import subprocess
import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks" / "research"))
from rlib import header, say  # noqa: E402

WORK = REPO / "benchmarks" / "out" / "probes" / "fallback_bytes"
JPEG = {"jpeg:subsampling": "4:4:4"}


def compressed(preset: str, size: int, k: int) -> Path:
    """The compressed folder of ``preset`` (synth + compress through the CLI, cached)."""
    cli = str(REPO / ".venv/bin/usdbtf")
    src, out = WORK / f"{preset}-paper-{size}", WORK / f"{preset}-paper-{size}-k{k}"
    if not (src / "btf.json").is_file():
        subprocess.run([cli, "synth", preset, "--sampling", "paper", "--size", str(size), "-o", str(src), "--force",
                        "-q"], check=True)
    if not (out / "btf-compressed.json").is_file():
        subprocess.run([cli, "compress", str(src), "--k", str(k), "-o", str(out), "--force", "-q"], check=True)
    return out


def base_encoding(path: Path, colour: bool) -> bytes:
    """The file the base commit wrote for the pixels of ``path``."""
    from usdbtf.imageio import encode_image, read_image
    from usdbtf.usd.asset.fallback import COLOUR_ENCODING
    from usdbtf.usd.asset.textures import DATA, png_as_data

    pixels, info = read_image(path)
    pixels = pixels[..., :info.channels]            # a grey file reads back as RGB
    blob = encode_image(pixels, "png", color_space=COLOUR_ENCODING if colour else DATA,
                        attributes={"png:compressionLevel": 9})
    return blob if colour else png_as_data(blob)


@contextlib.contextmanager
def stored_as(change):
    """Both fallbacks' ``encode_maps`` with ``change({map: pixels})`` applied to what they
    return (a storage not taken: what a renderer would read from it), inside the block."""
    from usdbtf.usd.asset import fallback, openpbr

    saved = fallback.encode_maps, openpbr.encode_maps

    def wrap(encode):
        return lambda maps, ocio_config=None: change(encode(maps, ocio_config))

    fallback.encode_maps, openpbr.encode_maps = wrap(saved[0]), wrap(saved[1])
    try:
        yield
    finally:
        fallback.encode_maps, openpbr.encode_maps = saved


def what_ifs(cbtf, result) -> list[tuple[str, int, dict]]:
    """[(storage, bytes of the maps it changes, fit errors)] of the storages not taken."""
    from usdbtf.imageio import decode_image, encode_image, encode_png_smallest
    from usdbtf.usd.asset import fallback, openpbr

    preview, op = result.svbrdf_fit, result.openpbr_maps
    pixels = {**{("ups", n): p for n, p in fallback.encode_maps(preview, cbtf.ocio_config).items()},
              **{("op", n): p for n, p in openpbr.encode_maps(op, cbtf.ocio_config).items()}}
    colour = {key for key in pixels if (fallback.MAP_FILES if key[0] == "ups" else openpbr.MAP_FILES)[key[1]][1] == "srgb"}
    colour_names = {name for _, name in colour}
    rows = []
    png_colour = sum(len(encode_png_smallest(pixels[key], color_space=fallback.COLOUR_ENCODING, level=9))
                     for key in colour)
    rows.append(("colour maps PNG (as shipped)", png_colour, openpbr.fit_errors(cbtf, preview, op)))
    for quality in (95, 90):
        attrs = {**JPEG, "Compression": f"jpeg:{quality}"}
        size = sum(len(encode_image(pixels[key], "jpg", color_space=fallback.COLOUR_ENCODING, attributes=attrs))
                   for key in colour)

        def jpeg(maps, attrs=attrs):
            return {n: decode_image(encode_image(p, "jpg", color_space=fallback.COLOUR_ENCODING, attributes=attrs))
                    if n in colour_names else p for n, p in maps.items()}

        with stored_as(jpeg):
            rows.append((f"colour maps JPEG q{quality} 4:4:4", size, openpbr.fit_errors(cbtf, preview, op)))
    data16 = [("op", "params"), ("op", "lobes")]
    rows.append(("OpenPBR params+lobes 16-bit PNG (as shipped)",
                 sum(len(encode_png_smallest(pixels[key], color_space="data", level=9)) for key in data16), rows[0][2]))
    eight = {key: np.rint(pixels[key] / 257.0).astype(np.uint8) for key in data16}

    def to8(maps):
        return {n: (eight[("op", n)].astype(np.uint16) * 257 if ("op", n) in eight else p) for n, p in maps.items()}

    with stored_as(to8):
        rows.append(("OpenPBR params+lobes 8-bit PNG", sum(len(encode_png_smallest(p, color_space="data", level=9))
                                                          for p in eight.values()), openpbr.fit_errors(cbtf, preview, op)))
    return rows


def encode_seconds(cbtf, result, tile: int, repeats: int = 5) -> tuple[float, float]:
    """Median CPU seconds (this process: OIIO encodes on the calling thread) to encode both
    fallbacks' maps, tiled ``tile`` x ``tile`` (a larger texture of the same statistics), the
    base commit's way (one PNG encode each) and the smaller-filter way (two each)."""
    import time

    from usdbtf.imageio import encode_image, encode_png_smallest
    from usdbtf.usd.asset import fallback, openpbr

    pixels = [np.tile(p, (tile, tile, 1)) for p in (*fallback.encode_maps(result.svbrdf_fit, cbtf.ocio_config).values(),
                                                    *openpbr.encode_maps(result.openpbr_maps, cbtf.ocio_config).values())]
    ways = {"before": lambda px: encode_image(px, "png", color_space="data", attributes={"png:compressionLevel": 9}),
            "after": lambda px: encode_png_smallest(px, color_space="data", level=9)}
    out = []
    for way in ways.values():
        runs = []
        for _ in range(repeats):
            t = time.process_time()
            for px in pixels:
                way(px)
            runs.append(time.process_time() - t)
        out.append(float(np.median(runs)))
    return out[0], out[1]


def measure(preset: str, size: int, k: int, tile: int) -> dict:
    from usdbtf.imageio import decode_image
    from usdbtf.usd.asset import fallback, openpbr
    from usdbtf.usd.asset.package import PackageOptions, package, read_input, write_package
    from usdbtf.usd.asset.thumbnail import THUMBNAIL_FILE

    folder = compressed(preset, size, k)
    cbtf = read_input(folder)
    result = package(cbtf, PackageOptions(physical_size=(0.05, 0.05), validate=False))
    colour = {f for f, kind in [*fallback.MAP_FILES.values(), *openpbr.MAP_FILES.values()] if kind == "srgb"}
    with tempfile.TemporaryDirectory(prefix="fallback-bytes-") as tmp:
        summary = write_package(result, Path(tmp) / "m.usda")
        textures = Path(summary["textures"])
        files = {}
        for path in sorted((textures / fallback.FALLBACK_DIR).iterdir()):
            before = base_encoding(path, path.name in colour)
            after = path.read_bytes()
            assert np.array_equal(decode_image(before), decode_image(after)), path.name
            files[path.name] = (len(before), len(after))
        thumb = (textures / THUMBNAIL_FILE).stat().st_size
    full = int(summary["bytes"]["full"])
    after_fb = sum(a for _, a in files.values())
    before_fb = sum(b for b, _ in files.values())
    return {"k": cbtf.k, "files": files, "thumbnail": thumb, "full_after": full,
            "full_before": full - after_fb + before_fb, "fit_errors": result.fit_errors,
            "what_ifs": what_ifs(cbtf, result), "tile": tile, "encode_s": encode_seconds(cbtf, result, tile)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--presets", default="metal_flakes,pebbles,velvet")
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--k", type=int, default=150)
    p.add_argument("--tile", type=int, default=8, help="the encode timing's maps tiled this many times a side")
    args = p.parse_args()
    presets = args.presets.split(",")
    header("issue 39: the fallback maps' bytes in the packaged asset (before = the base commit's PNG encoding)",
           [f"presets {', '.join(presets)}; usdbtf synth --sampling paper --size {args.size} (seed 0); "
            f"usdbtf compress --k {args.k} (defaults otherwise); packaged as a 5 cm swatch, png textures",
            "before: each fallback file's pixels re-encoded as 02cc7d4 wrote them (PNG level 9, libpng's default "
            "filter); after: as written now (level 9, the smaller of default/none filter); same pixels (asserted)",
            "asset = every file the full lod loads (layers, thumbnail, GPU tables and pages, both fallbacks' maps)",
            "fit errors: usd.asset.openpbr.fit_errors (256 held-out samples, working space, vs the compressed BTF)"])
    for preset in presets:
        r = measure(preset, args.size, args.k, args.tile)
        say(f"\n## {preset} ({args.size}^2, k {r['k']})\n")
        say("| file | before | after | after / before |")
        say("|---|---:|---:|---:|")
        for name, (b, a) in r["files"].items():
            say(f"| fallback/{name} | {b:,} | {a:,} | {a / b:.3f} |")
        fb_b = sum(b for b, _ in r["files"].values())
        fb_a = sum(a for _, a in r["files"].values())
        say(f"| **fallback maps** | {fb_b:,} | {fb_a:,} | {fb_a / fb_b:.3f} |")
        say(f"| thumbnail.png (every lod loads it; unchanged) | {r['thumbnail']:,} | {r['thumbnail']:,} | 1.000 |")
        say(f"| **asset (full lod)** | {r['full_before']:,} | {r['full_after']:,} | "
            f"{r['full_after'] / r['full_before']:.4f} |")
        say(f"\nfallback maps / asset: before {fb_b / r['full_before']:.2%}, after {fb_a / r['full_after']:.2%}; "
            f"with the thumbnail: before {(fb_b + r['thumbnail']) / r['full_before']:.2%}, "
            f"after {(fb_a + r['thumbnail']) / r['full_after']:.2%}")
        e = r["fit_errors"]
        say(f"fitted error as shipped (identical before/after: same pixels): UsdPreviewSurface "
            f"{e['preview_surface']:.3f} %, OpenPBR {e['open_pbr']:.3f} %\n")
        before_s, after_s = r["encode_s"]
        side = args.size * r["tile"]
        say(f"encoding both fallbacks' 11 maps tiled to {side}^2, median CPU s of 5: before {before_s:.3f}, "
            f"after {after_s:.3f} ({after_s / before_s:.2f}x)\n")
        say("| storage of the maps it changes | their bytes | UsdPreviewSurface % | OpenPBR % |")
        say("|---|---:|---:|---:|")
        for name, size, err in r["what_ifs"]:
            say(f"| {name} | {size:,} | {err['preview_surface']:.3f} | {err['open_pbr']:.3f} |")


if __name__ == "__main__":
    main()
