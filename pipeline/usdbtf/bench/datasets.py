"""Benchmark inputs: synthetic BTF manifests, cached on disk, and manifests of sample subsets.

A dataset is what ``usdbtf synth PRESET --sampling SAMPLING --size N --seed SEED`` writes
(8-bit sRGB PNG by default), optionally restricted to the first ``views`` views of the
sampling (all lights of each).  It is generated once into ``workdir`` and reused while its
``btf.json`` records the same parameters (``btf.json`` is written last, atomically, so a
folder with one is complete).

Subsets (the training half of a held-out split, the first n views for a scaling series)
are manifests whose ``image`` entries point into the full dataset's folder by relative
path: no pixel is copied.

Material presets are split in two (:data:`TUNING_PRESETS`, :data:`HELDOUT_PRESETS`): any
choice of a method's parameters may look at the tuning presets; the held-out ones stand in
for materials nobody has seen, so no tuning run may use them, and benchmarks report them
apart.  The split was fixed before any compression result on the new presets was seen.
"""
from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np

from .. import jsontext
from ..atomic import atomic_dir
from ..compress.format import cross_layout
from ..lifetime import dying_with_parent
from ..model import FileBTF
from ..sampling import Sampling, preset as sampling_preset

__all__ = ["dataset_dir", "cached_dataset_ok", "ensure_dataset", "synthesize", "first_views", "write_subset",
           "subset_btf", "compressed", "SRGB", "PHYSICAL_SIZE_M", "TUNING_PRESETS", "HELDOUT_PRESETS",
           "preset_split", "split_presets"]

SRGB = "sRGB Encoded Rec.709 (sRGB)"
PHYSICAL_SIZE_M = 0.05          # `usdbtf synth`'s default tile edge

#: Material presets (:data:`usdbtf.synth.PRESETS`) that tuning may look at.
TUNING_PRESETS = ("pebbles", "ridged_fabric", "fuzzy_moss", "metal_flakes", "satin_weave")
#: Presets kept out of every tuning run: deep crevices with cast shadows (energy in dark,
#: shadowed texels) and velvet (grazing sheen and retro-reflection).
HELDOUT_PRESETS = ("crevice_stones", "velvet")


def preset_split(preset: str) -> str:
    """"tuning" or "held-out" for a material preset (ValueError for an unknown one)."""
    if preset in TUNING_PRESETS:
        return "tuning"
    if preset in HELDOUT_PRESETS:
        return "held-out"
    raise ValueError(f"material preset {preset!r} is in neither the tuning nor the held-out set")


def split_presets(presets) -> tuple[list, list]:
    """(tuning, held-out) members of ``presets``, each in the given order."""
    presets = list(presets)
    return ([p for p in presets if preset_split(p) == "tuning"],
            [p for p in presets if preset_split(p) == "held-out"])


def first_views(sampling: Sampling, views: int | None) -> np.ndarray:
    """Indices of every sample of the first ``views`` views (all samples when None).

    The sampling must be every light for every view, view-major (:func:`cross_layout`)."""
    if views is None:
        return np.arange(len(sampling))
    cross = cross_layout(sampling)
    if cross is None:
        raise ValueError("a view subset needs a view x light sampling")
    V, L = cross
    return np.arange(min(views, V) * L)


def dataset_dir(workdir: Path, preset: str, sampling: str, size: int, seed: int, fmt: str = "png",
                views: int | None = None) -> Path:
    """``PRESET-SAMPLING[vVIEWS]-SIZE-seedSEED[-FMT]`` under ``workdir`` (png has no suffix)."""
    name = f"{preset}-{sampling}{'' if views is None else f'v{views}'}-{size}-seed{seed}"
    return Path(workdir) / (name if fmt == "png" else f"{name}-{fmt}")


def cached_dataset_ok(folder: Path, preset: str, sampling: str, size: int, seed: int, n_samples: int,
                      fmt: str = "png", views: int | None = None) -> bool:
    """A complete dataset from the same synth parameters (``btf.json`` is written last)."""
    path = Path(folder) / "btf.json"
    if not path.is_file():
        return False
    try:
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return False
    syn = doc.get("synthetic", {})
    want = {"preset": preset, "sampling": sampling, "size": size, "seed": seed, "views": views}
    if any(syn.get(k) != v for k, v in want.items()):
        return False
    samples = doc.get("samples", [])
    return (doc.get("width") == size and doc.get("height") == size and len(samples) == n_samples
            and doc.get("color_space", "").startswith("sRGB")
            and all(s["image"].endswith("." + fmt) and (Path(folder) / s["image"]).is_file() for s in samples))


def synthesize(folder: Path, preset: str, sampling: str, size: int, seed: int, fmt: str = "png",
               views: int | None = None) -> Path:
    """Write the dataset (8-bit sRGB) as ``usdbtf synth`` does, restricted to ``views`` views."""
    from dataclasses import replace

    from ..synth import SynthOptions, synth, write_synth

    result = synth(preset, SynthOptions(size=size, seed=seed, sampling=sampling, physical_size=PHYSICAL_SIZE_M,
                                        ext=fmt, bit_depth="uint8", color_space=SRGB))
    if views is not None:
        result = replace(result, sampling=result.sampling.subset(first_views(result.sampling, views)))
        result.metadata["synthetic"]["views"] = views
    write_synth(result, folder)
    return Path(folder)


def ensure_dataset(workdir: Path, preset: str, sampling: str, size: int, seed: int = 0, fmt: str = "png",
                   views: int | None = None, say=print) -> dict:
    """The dataset's folder, generated unless cached.  Returns {"folder", "cached", "synth_seconds",
    "n_samples"}."""
    n = len(first_views(sampling_preset(sampling), views))
    folder = dataset_dir(workdir, preset, sampling, size, seed, fmt, views)
    info = {"folder": str(folder), "n_samples": n, "format": fmt}
    if cached_dataset_ok(folder, preset, sampling, size, seed, n, fmt, views):
        say(f"  input: cached {folder}")
        return dict(info, cached=True, synth_seconds=None)
    say(f"  input: generating {folder} ({n} samples of {size}x{size}) ...")
    t = time.perf_counter()
    synthesize(folder, preset, sampling, size, seed, fmt, views)
    seconds = time.perf_counter() - t
    say(f"  input: generated in {seconds:.1f} s")
    return dict(info, cached=False, synth_seconds=seconds)


def write_subset(source: Path, indices, dest: Path, **extra) -> Path:
    """A manifest at ``dest`` listing samples ``indices`` of the manifest ``source`` (images by
    relative path into ``source``; top-level keys kept, ``extra`` added)."""
    source, dest = Path(source), Path(dest)
    doc = json.loads((source / "btf.json").read_text())
    samples = doc["samples"]
    rel = os.path.relpath(source.resolve(), dest.resolve())     # dest need not exist yet
    out = dict(doc)
    out.update(extra)
    out["samples"] = [dict(samples[int(i)], image=f"{rel}/{samples[int(i)]['image']}") for i in indices]
    with atomic_dir(dest) as tmp:
        (tmp / "btf.json").write_text(jsontext.dumps(out) + "\n")
    return dest


def subset_btf(btf: FileBTF, indices) -> FileBTF:
    """The samples ``indices`` of a file-backed BTF, as a BTF of their own (no I/O)."""
    idx = np.asarray(indices)
    return FileBTF(sampling=btf.sampling.subset(idx), width=btf.width, height=btf.height,
                   color_space=btf.color_space, bit_depth=btf.bit_depth, names=[btf.names[i] for i in idx],
                   interpolated=btf.interpolated[idx], working_space=btf.working_space, ocio_config=btf.ocio_config,
                   metadata=dict(btf.metadata), paths=[btf.paths[i] for i in idx])


def compressed(cli: list, source: Path, out: Path, k: int):
    """``usdbtf compress SOURCE -o OUT --k K`` (untimed: an input of another benchmark), reused
    when OUT already holds a result; returns it read back (:class:`CompressedBTF`)."""
    import subprocess

    from ..compress import read_compressed
    from ..errors import BTFError

    out = Path(out)
    if not (out / "btf-compressed.json").is_file():
        res = subprocess.run([*cli, "compress", str(source), "-o", str(out), "--k", str(k), "-q"],
                             capture_output=True, text=True, **dying_with_parent(signal.SIGTERM))
        if res.returncode != 0:
            raise BTFError(f"usdbtf compress {source} failed: {' '.join(res.stderr.split())[-500:]}")
    return read_compressed(out)
