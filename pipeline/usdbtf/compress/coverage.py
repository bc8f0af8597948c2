"""A partial compress: only the (view, light) samples and the texture resolution a scene needs.

Two options shape the input before anything is fitted (:func:`shaped_input`):

``coverage`` (:class:`usdbtf.sampling.Coverage`)
    keep the samples whose view AND light are both listed, in the input's own order
    (view-major stays view-major: a V x L input gives a V' x L' partial one, which every
    renderer interpolates over).  Each listed direction must be one of the input's own
    directions, within :data:`usdbtf.sampling.DIRECTION_TOLERANCE` degrees.
``max_texels`` (N)
    box-filter the images by the smallest integer factor f that brings the larger side to
    at most N.  The filter averages f x f texels in scene-linear (radiance adds linearly: it
    is what a renderer's texture filter sees when one screen pixel covers f x f texels);
    where a side is not a multiple of f, the last row or column of boxes averages the texels
    that remain.  The averages are re-encoded to the input's colour space as floats, so the
    working-domain choice and ``--error-domain encoded`` keep the input's curve.  The
    physical size is unchanged: the texel density drops by f.

The result records what it covers under the metadata key ``coverage`` (:func:`coverage_record`):
the input's view, light and sample counts and size, the kept views and lights, the factor.
A folder without the key covers its whole input.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .. import color
from ..errors import BTFError
from ..model import BTF, FileBTF
from ..sampling import Coverage, match_directions

__all__ = ["shaped_input", "coverage_record", "read_coverage_record", "unique_directions", "SubsetBTF",
           "BoxFilteredBTF", "resolution_factor", "coverage_summary", "coverage_text", "box_mean", "subset_btf"]


def unique_directions(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distinct directions (n, 2) in order of first appearance, (S,) index of each row into them)."""
    _, first, inverse = np.unique(np.asarray(directions, np.float64), axis=0, return_index=True,
                                  return_inverse=True)
    order = np.argsort(first)                    # first-appearance order, not sorted order
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return np.asarray(directions, np.float64)[np.sort(first)], rank[inverse.ravel()]


def resolution_factor(width: int, height: int, max_texels: int | None) -> int:
    """The smallest integer f with ceil(max(width, height) / f) <= ``max_texels`` (1 without one)."""
    if max_texels is None:
        return 1
    return max(1, -(-max(width, height) // int(max_texels)))


def shaped_input(btf: BTF, coverage: Coverage | None, max_texels: int | None) -> tuple[BTF, dict | None]:
    """``btf`` restricted to ``coverage`` and filtered to ``max_texels``, and its record.

    Parameters
    ----------
    btf : the input (S samples of W x H texels).
    coverage : the views and lights to keep (None: all).
    max_texels : largest side of the filtered images, texels (None: the input's size).

    Returns
    -------
    (BTF, record) : the input itself and None when neither option is given; else a BTF of
    the kept samples (S' <= S, same order) at the filtered size and :func:`coverage_record`'s
    dict.  Raises BTFError when a listed direction is not one of the input's.
    """
    if coverage is None and max_texels is None:
        return btf, None
    views, view_of = unique_directions(btf.sampling.view)
    lights, light_of = unique_directions(btf.sampling.light)
    keep_views = _covered(views, coverage.views if coverage else views, "view", coverage)
    keep_lights = _covered(lights, coverage.lights if coverage else lights, "light", coverage)
    keep = np.flatnonzero(np.isin(view_of, keep_views) & np.isin(light_of, keep_lights))
    if len(keep) == 0:
        raise BTFError(f"{_where(coverage)}: no sample of the input has a listed view and a listed light")
    factor = resolution_factor(btf.width, btf.height, max_texels)
    record = coverage_record(btf, views[np.sort(keep_views)], lights[np.sort(keep_lights)], factor)
    shaped = btf if len(keep) == btf.n_samples else subset_btf(btf, keep)
    if factor > 1:
        shaped = BoxFilteredBTF.of(shaped, factor)
    return shaped, record


def _where(coverage: Coverage | None) -> str:
    return (coverage.path if coverage is not None and coverage.path else "coverage")


def _covered(available: np.ndarray, wanted: np.ndarray, what: str, coverage: Coverage | None) -> np.ndarray:
    """Indices into ``available`` of the ``wanted`` directions; BTFError for one that is not there."""
    idx = match_directions(wanted, available)
    for i in np.flatnonzero(idx < 0)[:1]:
        theta, phi = (float(x) for x in wanted[i])
        raise BTFError(f"{_where(coverage)}: {what} [{theta:g}, {phi:g}] is not one of the input's "
                       f"{len(available)} {what} directions")
    return np.unique(idx)


def coverage_record(btf: BTF, views: np.ndarray, lights: np.ndarray, factor: int) -> dict:
    """What a partial compress covers (metadata key ``coverage``).

    Keys: ``input_views``, ``input_lights``, ``input_samples`` (the full input's distinct view
    and light directions and its samples), ``input_view_directions``,
    ``input_light_directions`` (those directions, degrees [theta, phi]: what a full asset
    would interpolate over, so a reader can tell a direction the partial one renders exactly
    from one it does not, :mod:`usdbtf.usd.scenes.reach`), ``input_size`` [W, H] (texels), ``views``
    and ``lights`` (the kept directions, in the input's order), ``resolution_factor`` (f: the
    stored textures are ceil(W / f) x ceil(H / f))."""
    all_views, all_lights = unique_directions(btf.sampling.view)[0], unique_directions(btf.sampling.light)[0]
    return {"input_views": int(len(all_views)), "input_lights": int(len(all_lights)),
            "input_samples": int(btf.n_samples), "input_size": [int(btf.width), int(btf.height)],
            "input_view_directions": all_views.tolist(), "input_light_directions": all_lights.tolist(),
            "views": np.asarray(views, np.float64).tolist(), "lights": np.asarray(lights, np.float64).tolist(),
            "resolution_factor": int(factor)}


def read_coverage_record(info: dict, where: str) -> dict | None:
    """The ``coverage`` record of a compressed BTF's metadata (``info``), checked; None when
    it has none (it covers its whole input).  BTFError names ``where`` and the key."""
    record = info.get("coverage")
    if record is None:
        return None
    counts = ("input_views", "input_lights", "input_samples", "resolution_factor")
    ok = isinstance(record, dict) and all(isinstance(record.get(key), int) and not isinstance(record.get(key), bool)
                                          and record[key] >= 1 for key in counts)
    for key in ("views", "lights", "input_view_directions", "input_light_directions"):
        value = record.get(key) if isinstance(record, dict) else None
        if value is None and key.startswith("input_"):           # optional: the check then has less to go on
            continue
        ok = ok and isinstance(value, list) and 0 < len(value) and all(
            isinstance(p, list) and len(p) == 2 and all(isinstance(x, (int, float)) for x in p) for p in value)
    if not ok:
        raise BTFError(f"{where}: coverage: expected input_views, input_lights, input_samples, resolution_factor "
                       "(positive integers) and views, lights, input_view_directions, input_light_directions "
                       "(lists of [theta, phi])")
    return record


def subset_btf(btf: BTF, keep: np.ndarray) -> BTF:
    """The samples ``keep`` (sorted indices) of ``btf``: a file-backed BTF stays one (its decode
    stays parallel, :func:`.load.load_encoded`), with its per-sample lists cut; any other is
    wrapped (:class:`SubsetBTF`)."""
    if not isinstance(btf, FileBTF):
        return SubsetBTF.of(btf, keep)
    changes = {"sampling": btf.sampling.subset(keep), "interpolated": np.asarray(btf.interpolated)[keep]}
    for f in dataclasses.fields(btf):
        value = getattr(btf, f.name)
        if f.init and f.name not in changes and isinstance(value, list) and len(value) == btf.n_samples:
            changes[f.name] = [value[i] for i in keep]
    return dataclasses.replace(btf, **changes)


def _inherited(btf: BTF) -> dict:
    """The fields a wrapper copies from the BTF it wraps."""
    return {"color_space": btf.color_space, "bit_depth": btf.bit_depth, "working_space": btf.working_space,
            "ocio_config": btf.ocio_config, "metadata": btf.metadata, "path": btf.path}


@dataclass
class SubsetBTF(BTF):
    """Some samples of another BTF (``parent``), read through it: sample i is ``parent``'s
    sample ``indices[i]``."""

    parent: BTF | None = None
    indices: np.ndarray | None = None

    @classmethod
    def of(cls, parent: BTF, indices: np.ndarray) -> "SubsetBTF":
        idx = np.asarray(indices, np.int64)
        return cls(sampling=parent.sampling.subset(idx), width=parent.width, height=parent.height,
                   names=[parent.names[i] for i in idx], interpolated=np.asarray(parent.interpolated)[idx],
                   parent=parent, indices=idx, **_inherited(parent))

    def read_encoded(self, indices, rows=None):
        return self.parent.read_encoded(self.indices[np.arange(self.n_samples)[indices]], rows)


@dataclass
class BoxFilteredBTF(BTF):
    """Another BTF (``parent``) box-filtered by ``factor`` in scene-linear and stored as floats
    in the parent's colour space (module docstring)."""

    parent: BTF | None = None
    factor: int = 1

    @classmethod
    def of(cls, parent: BTF, factor: int) -> "BoxFilteredBTF":
        kw = dict(_inherited(parent), bit_depth="float")
        return cls(sampling=parent.sampling, width=-(-parent.width // factor), height=-(-parent.height // factor),
                   names=list(parent.names), interpolated=parent.interpolated, parent=parent, factor=factor, **kw)

    @property
    def files(self) -> BTF | None:
        """The image files underneath (the parent when it is a :class:`FileBTF`): decode
        workers then read this view by index (:func:`.load.decodes_in_workers`)."""
        return self.parent if isinstance(self.parent, FileBTF) else None

    def read_one(self, i: int, rows=None) -> np.ndarray:
        """Stored (filtered, re-encoded) values of sample i, (h, W, 3) float32."""
        return self.read_encoded([i], rows)[0]

    def read_encoded(self, indices, rows=None):
        f, parent = self.factor, self.parent
        y0, y1 = rows if rows is not None else (0, self.height)
        src = (y0 * f, min(y1 * f, parent.height))
        mean = box_mean(_linear(parent, parent.read_encoded(indices, rows=src), f"rows {src[0]}..{src[1]}"), f)
        to_file = color.processor(self.working_space, self.color_space, self.ocio_config)
        # A mean of in-gamut colours is in gamut: a value below zero is the round trip's rounding.
        return np.maximum(np.ascontiguousarray(to_file.apply(mean), dtype=np.float32), 0.0)


def _linear(btf: BTF, stored: np.ndarray, what: str) -> np.ndarray:
    """Working-space values of ``stored`` (n, h, w, 3), each element a function of its own
    texel only, so no value depends on how many samples or rows were read together: integer
    codes through the decode's per-channel table, then its primaries matrix as three products
    and two sums per channel (OpenCV's matrix transform, which the plain decode uses, rounds
    by array shape); other encodings through OCIO, which is per texel."""
    dec = btf.integer_decoder
    if dec is None or not dec.exact:
        return btf.decode(stored, what=what)
    x = dec.decode_curves(stored).astype(np.float64)
    if dec.matrix is None:
        return x
    m = np.asarray(dec.matrix, np.float64)
    return x[..., 0:1] * m[:, 0] + x[..., 1:2] * m[:, 1] + x[..., 2:3] * m[:, 2]


def box_mean(images: np.ndarray, f: int) -> np.ndarray:
    """(n, h, w, 3) -> (n, ceil(h / f), ceil(w / f), 3) float32: the mean of each f x f box
    (the last boxes of a side that is not a multiple of f average the texels that remain).
    Sums in float64 in a fixed order per box, so no box depends on the others."""
    n, h, w, c = images.shape
    hb, wb = -(-h // f), -(-w // f)
    padded = np.zeros((n, hb * f, wb * f, c), np.float64)
    padded[:, :h, :w] = images
    sums = np.zeros((n, hb, wb, c), np.float64)
    for dy in range(f):            # one elementwise add per box offset: the same order for every box
        for dx in range(f):
            sums += padded[:, dy::f, dx::f]
    counts = np.zeros((hb * f, wb * f))
    counts[:h, :w] = 1.0
    per_box = counts.reshape(hb, f, wb, f).sum(axis=(1, 3))
    return (sums / per_box[None, :, :, None]).astype(np.float32)


def coverage_summary(record: dict | None, n_samples: int, width: int, height: int) -> dict | None:
    """The ``coverage`` entry of ``info --json`` and ``inspect --json``: None for a BTF that
    covers its whole input, else {``views``, ``input_views``, ``lights``, ``input_lights``,
    ``samples``, ``input_samples``, ``resolution`` [W, H], ``input_resolution`` [W, H] or None,
    ``resolution_factor``}.

    Parameters
    ----------
    record : the coverage record (:func:`read_coverage_record`, or an asset's).
    n_samples, width, height : what the partial BTF itself holds.
    """
    if record is None:
        return None
    size = record.get("input_size")
    return {"views": len(record["views"]), "input_views": int(record["input_views"]),
            "lights": len(record["lights"]), "input_lights": int(record["input_lights"]),
            "samples": int(n_samples), "input_samples": int(record["input_samples"]),
            "resolution": [int(width), int(height)], "input_resolution": [int(x) for x in size] if size else None,
            "resolution_factor": int(record["resolution_factor"])}


def coverage_text(summary: dict | None) -> str:
    """One line for ``info`` and ``inspect``: what a partial BTF covers (:func:`coverage_summary`)."""
    if summary is None:
        return "the whole input"
    s = summary
    text = (f"{s['views']} of {s['input_views']} views x {s['lights']} of {s['input_lights']} lights "
            f"({s['samples']} of {s['input_samples']} samples)")
    # The texel density, not the size: a quilt of a partial folder is larger than its input.
    f = s["resolution_factor"]
    text += "; the input's texel density" if f == 1 else f"; 1/{f} of the input's texel density"
    if s["input_resolution"]:
        iw, ih = s["input_resolution"]
        text += f" (input {iw}x{ih} texels)"
    return text
