"""What the benchmark compares: ``usdbtf compress`` (every solver x codec x k) and baselines.

A :class:`Method` knows three things:

* ``command(cli, fitted_dir, out)``: the subprocess that stores the fitted samples (timed);
* ``stored_bytes(out)``: what that storage costs (texture/image/video files only; metadata
  JSON and diagnostics are not counted);
* ``open(out, fitted_btf, needed)``: a :class:`Reconstruction` of what was stored, giving
  working-space images of fitted samples and predictions of held-out ones.
"""
from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .heldout import blend_rows

__all__ = ["Method", "Reconstruction", "CompressedReconstruction", "ManifestReconstruction", "compress_methods",
           "baseline_methods", "FAMILIES"]

# family -> (table label, the parameter it sweeps, is it a baseline)
FAMILIES = {
    "rsvd": ("usdbtf rsvd", "k", False),
    "paper": ("paper solver (Koudelka 2003)", "k", True),
    "jpeg": ("JPEG per image", "quality", True),
    "pca-view": ("per-view PCA", "k per view", True),
    "video": ("H.265 video (x265)", "crf", True),
}


class Reconstruction:
    """Images back from a stored representation.  Subclasses implement ``fitted``."""

    def fitted(self, positions) -> np.ndarray:
        """(n, H, W, 3) float32 working-space images of fitted samples at ``positions``."""
        raise NotImplementedError

    def blend(self, idx: np.ndarray, w: np.ndarray) -> np.ndarray:
        """(q, H, W, 3) predictions sum_j w[:, j] * image(idx[:, j]) (see :mod:`.heldout`)."""
        uniq, inv = np.unique(idx, return_inverse=True)
        images = self.fitted(uniq)
        return blend_rows(images, inv.reshape(idx.shape), w)


class CompressedReconstruction(Reconstruction):
    """A ``usdbtf compress`` folder: held-out samples interpolate basis rows."""

    def __init__(self, folder: Path):
        from ..compress import read_compressed
        from ..compress.format import working_coefficients

        self.cbtf = read_compressed(folder)
        self.coeff = working_coefficients(self.cbtf)           # de-quantised once, (k, H, W, 3)

    def fitted(self, positions) -> np.ndarray:
        from ..compress import reconstruct
        return reconstruct(self.cbtf, np.asarray(positions), coefficients=self.coeff)

    def blend(self, idx, w) -> np.ndarray:
        from .heldout import blend_compressed
        return blend_compressed(self.cbtf, self.coeff, idx, w)


class ManifestReconstruction(Reconstruction):
    """Images listed by a manifest: the JPEG baseline's files, or the input itself (the
    reference that shows how well held-out samples can be predicted at all)."""

    def __init__(self, folder: Path):
        from ..io import open_btf
        self.btf = open_btf(folder)

    def fitted(self, positions) -> np.ndarray:
        return self.btf.read_samples(np.asarray(positions))


class _PerViewReconstruction(Reconstruction):
    """One compressed folder per view; position p is light p % L of view p // L."""

    def __init__(self, folder: Path):
        from .baselines import VIEW_FOLDER, read_record
        meta = read_record(folder, "pca-view")
        self.lights = meta["lights"]
        self.views = [CompressedReconstruction(folder / VIEW_FOLDER.format(v)) for v in range(meta["views"])]

    def fitted(self, positions) -> np.ndarray:
        pos = np.asarray(positions)
        c = self.views[0].cbtf
        out = np.empty((len(pos), c.height, c.width, 3), np.float32)
        for v in np.unique(pos // self.lights):
            sel = np.flatnonzero(pos // self.lights == v)
            out[sel] = self.views[v].fitted(pos[sel] % self.lights)
        return out


class _VideoReconstruction(Reconstruction):
    """Decoded video frames (only ``needed`` ones are kept), decoded like the input files."""

    def __init__(self, folder: Path, fitted_btf, needed):
        from .baselines import decode_video
        self.frames = decode_video(folder, needed)
        self.btf = fitted_btf

    def fitted(self, positions) -> np.ndarray:
        return self.btf.decode(np.stack([self.frames[int(p)] for p in positions]))


def _files_bytes(folder: Path, pattern: str) -> int:
    return sum(f.stat().st_size for f in Path(folder).glob(pattern))


@dataclass(frozen=True)
class Method:
    """One point of a sweep: ``family`` (see FAMILIES), ``codec``, parameter value ``param``."""

    family: str
    codec: str
    param: int

    @property
    def label(self) -> str:
        return f"{self.family}/{self.codec}"

    @property
    def param_name(self) -> str:
        return FAMILIES[self.family][1]

    @property
    def baseline(self) -> bool:
        return FAMILIES[self.family][2]

    @property
    def slug(self) -> str:
        """A file-name-safe id, unique within a dataset."""
        return f"{self.family}-{self.codec}-{self.param}"

    def command(self, cli: list, fitted_dir: Path, out: Path) -> list:
        if self.family in ("rsvd", "paper"):
            return [*cli, "compress", fitted_dir, "-o", out, "--solver", self.family, "--codec", self.codec,
                    "--k", str(self.param)]
        base = [sys.executable, "-m", "usdbtf.bench.baselines", self.family, fitted_dir, out]
        return base + {"jpeg": ["--quality"], "pca-view": ["--codec", self.codec, "--k"],
                       "video": ["--crf"]}[self.family] + [str(self.param)]

    def stored_bytes(self, out: Path) -> int:
        if self.family in ("rsvd", "paper"):
            return int(json.loads((out / "btf-compressed.json").read_text())["bytes"]["payload"])
        if self.family == "pca-view":
            return sum(int(json.loads(p.read_text())["bytes"]["payload"]) for p in out.glob("view*/btf-compressed.json"))
        return _files_bytes(out, "*.jpg" if self.family == "jpeg" else "*.mp4")

    def details(self, out: Path) -> dict:
        """What the stored result says about itself (e.g. the k actually kept)."""
        if self.family in ("rsvd", "paper"):
            doc = json.loads((out / "btf-compressed.json").read_text())
            return {"k_stored": doc["k"]}
        return {}

    def open(self, out: Path, fitted_btf, needed) -> Reconstruction:
        if self.family in ("rsvd", "paper"):
            return CompressedReconstruction(out)
        if self.family == "jpeg":
            return ManifestReconstruction(out)
        if self.family == "pca-view":
            return _PerViewReconstruction(out)
        return _VideoReconstruction(out, fitted_btf, needed)


def compress_methods(solvers, codecs, ks) -> list:
    return [Method(s, c, int(k)) for s in solvers for c in codecs for k in ks]


def baseline_methods(jpeg_qualities=(), pca_view_ks=(), video_crfs=(), pca_codec: str = "jxl") -> list:
    return ([Method("jpeg", "jpeg", int(q)) for q in jpeg_qualities]
            + [Method("pca-view", pca_codec, int(k)) for k in pca_view_ks]
            + [Method("video", "x265", int(c)) for c in video_crfs])
