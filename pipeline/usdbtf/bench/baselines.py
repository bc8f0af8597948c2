"""Baselines the benchmark measures next to ``usdbtf compress``, as commands of their own.

Each baseline stores the fitted samples of a BTF its own way; the benchmark times the
command as a subprocess (like ``usdbtf compress``) and then reads what it wrote back:

``jpeg``      every image as its own JPEG (quality 90, 4:2:0 chroma: what people do today).
              Writes the JPEGs and a btf-manifest/1 ``btf.json`` naming them.
``pca-view``  per-view PCA: each view's images (all its lights) compressed on their own by
              ``usdbtf compress`` (rsvd, k per view), one folder per view.  Same quantiser
              and codec as the global basis, so only the factorisation differs.
``video``     the image sequence (view-major: the lights of view 0, then of view 1, ...) as
              one H.265 video (ffmpeg + libx265, constant quality ``crf``, 4:4:4 chroma).

Run as ``python -m usdbtf.bench.baselines KIND INPUT OUTPUT [options]``; the output folder is
written atomically, and an existing one is replaced only when it is a previous output of the
same baseline (:mod:`usdbtf.atomic`): ``jpeg`` writes a ``btf-manifest/1`` folder, ``pca-view``
and ``video`` a ``usdbtf-bench-baseline/1`` folder whose record ``baseline.json`` names the
baseline and its settings (:mod:`usdbtf.outputs` recognises both).  INPUT is any BTF
:func:`usdbtf.io.open_btf` reads, with 8-bit files for ``jpeg`` and ``video``.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import shutil
import subprocess
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from .. import jsontext
from ..atomic import atomic_dir
from ..errors import BTFError
from ..lifetime import dying_with_parent
from ..outputs import BENCH_BASELINE, MANIFEST

__all__ = ["ffmpeg_x265", "encode_jpeg", "encode_pca_view", "encode_video", "decode_video", "read_record",
           "VIEW_FOLDER", "VIDEO_FILE", "RECORD", "main"]

VIEW_FOLDER = "view{:04d}"
VIDEO_FILE = "video.mp4"
#: The record a ``pca-view`` or ``video`` output carries: its kind's marker and its settings.
RECORD = "baseline.json"
_JPEG = {"Compression": "jpeg:{q}", "jpeg:subsampling": "4:2:0"}
_STATE: dict = {}


def ffmpeg_x265() -> tuple[str | None, str]:
    """(path of an ffmpeg that has the libx265 encoder, or None; why not)."""
    exe = shutil.which("ffmpeg")
    if exe is None:
        return None, "ffmpeg not found on PATH (Debian: apt-get install ffmpeg)"
    try:
        enc = subprocess.run([exe, "-hide_banner", "-encoders"], capture_output=True, text=True, timeout=30,
                             **dying_with_parent()).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"{exe} does not run ({exc})"
    if "libx265" not in enc:
        return None, f"{exe} has no libx265 encoder"
    return exe, ""


def _write_record(folder: Path, baseline: str, **settings) -> None:
    """``folder / RECORD``: the usdbtf-bench-baseline/1 marker, the baseline's name, its settings."""
    doc = {"format": BENCH_BASELINE, "baseline": baseline, **settings}
    (folder / RECORD).write_text(json.dumps(doc) + "\n")


def read_record(folder: Path, baseline: str) -> dict:
    """The settings a ``baseline`` output in ``folder`` recorded (BTFError when it holds another)."""
    path = Path(folder) / RECORD
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise BTFError(f"{path}: not a readable baseline record ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != BENCH_BASELINE or doc.get("baseline") != baseline:
        raise BTFError(f"{path}: not a {baseline} baseline's record")
    return doc


def _require_8bit(btf, kind: str) -> None:
    if btf.bit_depth != "uint8":
        raise BTFError(f"{btf.path or 'input'}: the {kind} baseline takes 8-bit images, "
                       f"got {btf.bit_depth}")


# -- jpeg -----------------------------------------------------------------------------------
def _jpeg_init(btf, folder, quality):
    import OpenImageIO as oiio

    oiio.attribute("threads", 1)  # OIIO's pool threads do not exist in a forked child
    _STATE.update(btf=btf, folder=folder, quality=quality)


def _jpeg_range(bounds) -> list:
    from ..imageio import write_image

    btf, folder, q = _STATE["btf"], _STATE["folder"], _STATE["quality"]
    attrs = {key: v.format(q=q) for key, v in _JPEG.items()}
    names = []
    for i in range(*bounds):
        name = f"{i:05d}.jpg"
        write_image(folder / name, btf.read_one(i), color_space=btf.color_space, attributes=attrs)
        names.append(name)
    return names


def encode_jpeg(btf, out: Path, quality: int = 90, workers: int | None = None) -> Path:
    """Every sample of ``btf`` (8-bit) as a JPEG file + a manifest naming them."""
    from ..compress.load import default_workers

    _require_8bit(btf, "jpeg")
    S = btf.n_samples
    workers = workers or default_workers()
    bounds = np.linspace(0, S, workers * 8 + 1).astype(int)
    ranges = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    with atomic_dir(out, kind=MANIFEST) as tmp:
        if workers > 1 and S >= 64:
            with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork"), initializer=_jpeg_init,
                                     initargs=(btf, tmp, quality)) as pool:
                names = [n for part in pool.map(_jpeg_range, ranges) for n in part]
        else:
            _STATE.update(btf=btf, folder=tmp, quality=quality)
            names = [n for r in ranges for n in _jpeg_range(r)]
        samples = [{"image": n, "view": [float(x) for x in v], "light": [float(x) for x in l]}
                   for n, v, l in zip(names, btf.sampling.view, btf.sampling.light)]
        doc = {"format": MANIFEST, "color_space": btf.color_space, "width": btf.width,
               "height": btf.height, "jpeg_quality": quality, "samples": samples}
        (tmp / "btf.json").write_text(jsontext.dumps(doc) + "\n")
    return out


# -- per-view PCA ---------------------------------------------------------------------------
def encode_pca_view(btf, out: Path, k: int, codec: str = "jxl", seed: int = 0) -> Path:
    """Each view's samples compressed on their own (rsvd, ``k`` vectors), one folder per view."""
    from ..compress import CompressOptions, compress, write_compress
    from ..compress.format import cross_layout
    from .datasets import subset_btf

    cross = cross_layout(btf.sampling)
    if cross is None:
        raise BTFError("per-view PCA needs a view x light sampling (every light for every view)")
    V, L = cross
    with atomic_dir(out, kind=BENCH_BASELINE) as tmp:
        for v in range(V):
            view = subset_btf(btf, np.arange(v * L, (v + 1) * L))
            write_compress(compress(view, CompressOptions(k=k, codec=codec, seed=seed)), tmp / VIEW_FOLDER.format(v))
        _write_record(tmp, "pca-view", views=V, lights=L, k=k, codec=codec)
    return out


# -- video ----------------------------------------------------------------------------------
def encode_video(btf, out: Path, crf: int = 28, preset: str = "medium") -> Path:
    """The samples in order as one H.265 video (rgb24 frames in, yuv444p coded)."""
    exe, why = ffmpeg_x265()
    if exe is None:
        raise BTFError(why)
    _require_8bit(btf, "video")
    cmd = [exe, "-hide_banner", "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
           "-s", f"{btf.width}x{btf.height}", "-framerate", "30", "-i", "-",
           "-c:v", "libx265", "-preset", preset, "-crf", str(crf), "-pix_fmt", "yuv444p",
           "-x265-params", "log-level=error", "-tag:v", "hvc1"]
    with atomic_dir(out, kind=BENCH_BASELINE) as tmp:
        proc = subprocess.Popen([*cmd, str(tmp / VIDEO_FILE)], stdin=subprocess.PIPE, stderr=subprocess.PIPE,
                                **dying_with_parent())
        try:
            for start in range(0, btf.n_samples, 64):
                block = btf.read_encoded(slice(start, min(start + 64, btf.n_samples)))
                proc.stdin.write(np.ascontiguousarray(block).tobytes())
            proc.stdin.close()
        except BrokenPipeError:
            pass
        err = proc.stderr.read().decode(errors="replace")
        if proc.wait() != 0:
            raise BTFError(f"ffmpeg failed (exit {proc.returncode}): {' '.join(err.split())[-500:]}")
        _write_record(tmp, "video", frames=btf.n_samples, width=btf.width, height=btf.height, crf=crf, preset=preset)
    return out


def decode_video(folder: Path, keep) -> dict:
    """Frames ``keep`` (indices) of the stored video as {index: (H, W, 3) uint8}, streamed
    (only the kept frames are held)."""
    exe, why = ffmpeg_x265()
    if exe is None:
        raise BTFError(why)
    meta = read_record(folder, "video")
    W, H, n = meta["width"], meta["height"], meta["frames"]
    keep = set(int(i) for i in keep)
    frame_bytes = W * H * 3
    cmd = [exe, "-hide_banner", "-v", "error", "-i", str(Path(folder) / VIDEO_FILE), "-f", "rawvideo",
           "-pix_fmt", "rgb24", "-fps_mode", "passthrough", "-"]
    out, count = {}, 0
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, **dying_with_parent()) as proc:
        while True:
            buf = proc.stdout.read(frame_bytes)
            if len(buf) < frame_bytes:
                break
            if count in keep:
                out[count] = np.frombuffer(buf, np.uint8).reshape(H, W, 3)
            count += 1
    if count != n:
        raise BTFError(f"{folder / VIDEO_FILE}: decoded {count} frames, expected {n}")
    return out


# -- command line ---------------------------------------------------------------------------
def main(argv=None) -> int:
    from ..io import open_btf
    from ..manifest import outside_paths_allowed

    p = argparse.ArgumentParser(prog="python -m usdbtf.bench.baselines", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="kind", required=True)
    j = sub.add_parser("jpeg", help="every image as JPEG")
    j.add_argument("--quality", type=int, default=90)
    j.add_argument("--workers", type=int)
    v = sub.add_parser("pca-view", help="per-view PCA (usdbtf compress per view)")
    v.add_argument("--k", type=int, required=True)
    v.add_argument("--codec", default="jxl")
    x = sub.add_parser("video", help="the image sequence as an H.265 video")
    x.add_argument("--crf", type=int, default=28)
    x.add_argument("--preset", default="medium")
    for s in (j, v, x):
        s.add_argument("input", type=Path)
        s.add_argument("output", type=Path)
    args = p.parse_args(argv)
    # The benchmark's inputs are subset manifests that name the images of the full dataset.
    try:
        with outside_paths_allowed():
            btf = open_btf(args.input)
            if args.kind == "jpeg":
                encode_jpeg(btf, args.output, args.quality, args.workers)
            elif args.kind == "pca-view":
                encode_pca_view(btf, args.output, args.k, args.codec)
            else:
                encode_video(btf, args.output, args.crf, args.preset)
    except BTFError as exc:
        print(f"baselines {args.kind}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
