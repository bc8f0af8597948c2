"""UBO2014-sized synthetic BTFs for the scale benchmark, made in minutes rather than hours.

UBO2014 has 151 x 151 = 22,801 samples of 400^2 texels.  Rendering that with ``usdbtf synth``
at full tracing quality (parallax, cast shadows, GGX + sheen) costs ~70 ms per 400^2 image
on this machine, ~27 minutes of CPU plus the PNG encodes.  Instead:

* the material (a tileable heightfield, ``synth.make_material``) is rendered at half the
  side, ``size / 2``, with the same full-quality renderer (``synth.render_sample``: every
  view traced, every light's shadow map, the full shading) -- a quarter of the work;
* each image is tiled 2 x 2 to ``size`` (the material is periodic, so the tiled image is
  seamless and still a real BTF with mesostructure, masking and shadows: a sample twice as
  large, seen at the same texel density);
* the views are spread over the CPUs (forked processes), each writing its PNGs straight
  into the staging folder (8-bit sRGB, as ``usdbtf synth`` writes them).

Honest caveat for compression: the data matrix's columns repeat with a period of
``size / 2`` texels in x and y, so its rank is that of the ``size / 2`` data; the compressor
does not know or use that, and decoding, fitting and projecting cost what they cost at
``size``.  The folder is a ``btf-manifest/1`` written through :func:`usdbtf.atomic.atomic_dir`
(``btf.json`` last, so a folder with one is complete) and is reused while its recorded
parameters match.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from usdbtf import __version__, color, jsontext, synth
from usdbtf.atomic import atomic_dir
from usdbtf.compress.format import cross_layout
from usdbtf.imageio import write_image
from usdbtf.manifest import FORMAT, FORMAT_ATTRIBUTES, MANIFEST, _sample_file, encode_for_file
from usdbtf.outputs import MANIFEST as MANIFEST_KIND
from usdbtf.sampling import preset as sampling_preset

SRGB = "sRGB Encoded Rec.709 (sRGB)"
LINEAR_709 = "Linear Rec.709 (sRGB)"
_STATE: dict = {}


def tiled_dir(workdir: Path, preset: str, sampling: str, size: int, seed: int, fmt: str = "png") -> Path:
    return Path(workdir) / f"{preset}-{sampling}-{size}-tiled{size // 2}-seed{seed}{'' if fmt == 'png' else '-' + fmt}"


def _cached(folder: Path, want: dict, n: int) -> bool:
    try:
        doc = json.loads((folder / MANIFEST).read_text())
    except (OSError, ValueError):
        return False
    return doc.get("synthetic") == want and len(doc.get("samples", [])) == n


def _init(material, sampling, folder, fmt):
    _STATE.update(material=material, sampling=sampling, folder=folder, fmt=fmt,
                  cache=synth.RenderCache(material, max_views=2),
                  proc=color.processor(LINEAR_709, SRGB))


def _render_range(bounds):
    """Render, tile 2 x 2, encode and write samples a..b (whole views)."""
    a, b = bounds
    s, folder, fmt = _STATE["sampling"], _STATE["folder"], _STATE["fmt"]
    attrs = FORMAT_ATTRIBUTES.get(fmt, {})
    for i in range(a, b):
        img = synth.render_sample(_STATE["material"], s.view[i], s.light[i], cache=_STATE["cache"])
        enc = encode_for_file(np.tile(img, (2, 2, 1)), _STATE["proc"], "uint8")
        write_image(folder / _sample_file(i, s.view[i], s.light[i], fmt), enc, color_space=SRGB, attributes=attrs)
    return b - a


def ensure_tiled(workdir: Path, preset: str = "pebbles", sampling: str = "ubo151", size: int = 400, seed: int = 0,
                 fmt: str = "png", workers: int | None = None, say=print) -> dict:
    """The dataset folder (generated unless cached): {"folder", "cached", "seconds", "n_samples", "how"}."""
    s = sampling_preset(sampling)
    folder = tiled_dir(workdir, preset, sampling, size, seed, fmt)
    want = {"preset": preset, "sampling": sampling, "size": size, "rendered_size": size // 2, "tiled": [2, 2],
            "seed": seed, "usdbtf_version": __version__}
    how = (f"synth.render_sample of {preset} (seed {seed}) at {size // 2}^2, full quality, tiled 2x2 to {size}^2, "
           f"{sampling} sampling, 8-bit sRGB {fmt.upper()}")
    info = {"folder": str(folder), "n_samples": len(s), "how": how}
    if _cached(folder, want, len(s)):
        say(f"  input: cached {folder}")
        return dict(info, cached=True, seconds=None)
    say(f"  input: generating {folder} ({len(s)} samples: {how}) ...")
    t = time.perf_counter()
    material = synth.make_material(preset, size // 2, seed)
    V, L = cross_layout(s)
    workers = workers or len(os.sched_getaffinity(0))
    views = np.array_split(np.arange(V), max(1, min(V, workers * 8)))
    bounds = [(int(v[0]) * L, (int(v[-1]) + 1) * L) for v in views if len(v)]
    with atomic_dir(folder, kind=MANIFEST_KIND) as tmp:
        with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork"), initializer=_init,
                                 initargs=(material, s, tmp, fmt)) as pool:
            done = 0
            for n in pool.map(_render_range, bounds):
                done += n
                say(f"    {done}/{len(s)} samples, {time.perf_counter() - t:.0f} s")
        doc = {"format": FORMAT, "color_space": color.resolve_space(SRGB, None), "width": size, "height": size,
               "physical_size_m": [0.1, 0.1], "synthetic": want,
               "samples": [{"image": _sample_file(i, s.view[i], s.light[i], fmt),
                            "view": [float(x) for x in s.view[i]], "light": [float(x) for x in s.light[i]]}
                           for i in range(len(s))]}
        (tmp / MANIFEST).write_text(jsontext.dumps(doc) + "\n")
    seconds = time.perf_counter() - t
    say(f"  input: generated in {seconds:.0f} s")
    return dict(info, cached=False, seconds=seconds)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="generate (or find) a UBO2014-sized tiled synthetic BTF")
    ap.add_argument("--size", type=int, default=400)
    ap.add_argument("--preset", default="pebbles")
    ap.add_argument("--workdir", type=Path, default=Path(__file__).resolve().parent / "out" / "data")
    args = ap.parse_args()
    print(ensure_tiled(args.workdir, args.preset, "ubo151", args.size))
