"""Reading packaged BTF assets back: from the asset itself or from any stage that references it.

    >>> from usdbtf.usd.read import load_btf, sample_image
    >>> cbtf = load_btf("out/pebbles.usda")                   # the one BTF material
    >>> img = sample_image(cbtf, view=(30, 60), light=(45, 0))  # (H, W, 3) working space

``load_btf`` returns the same :class:`~usdbtf.compress.format.CompressedBTF` that
``read_compressed`` gives for the compressed folder, so every tool that takes one
(``reconstruct``, :mod:`usdbtf.decompress`, the renderer) takes an asset too.
"""
from __future__ import annotations

import numpy as np

from ..compress.format import CompressedBTF, reconstruct
from ..errors import BTFError
from ..usdstage import open_usd, usd_warnings_silenced
from .material import LOD_VARIANT_SET, btf_materials, read_btf


def open_stage(path, *, lod: str | None = None, where_offered: bool = False):
    """Open an asset (see :func:`open_usd`); ``lod`` selects that variant of every ``lod``
    variant set (in the session layer: nothing on disk changes; ``where_offered``: only of
    those that have it)."""
    with usd_warnings_silenced():   # reported below, where they matter
        stage = open_usd(path, composition_errors=False)
    if lod is not None:
        select_lod(stage, lod, where_offered=where_offered)
    return stage


def select_lod(stage, lod: str, *, where_offered: bool = False) -> None:
    """Select variant ``lod`` on every prim with a ``lod`` variant set (session layer only).

    where_offered : skip a variant set without ``lod`` (a scene whose materials have different
        k, hence different levels), instead of an error naming the prim."""
    from pxr import Usd

    found = False
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for prim in stage.Traverse():
            vset = prim.GetVariantSets().GetVariantSet(LOD_VARIANT_SET) if prim.HasVariantSets() else None
            if vset and vset.IsValid():
                names = vset.GetVariantNames()
                if lod not in names and where_offered:
                    continue
                if lod not in names:
                    raise BTFError(f"{prim.GetPath()}: no lod variant {lod!r} (has {', '.join(names)})")
                vset.SetVariantSelection(lod)
                found = True
    if not found:
        raise BTFError(f"{stage.GetRootLayer().identifier}: has no {LOD_VARIANT_SET!r} variant set")


def find_material(stage, material: str | None = None):
    """The BtfMaterialAPI prim at ``material``, or the only one on the stage."""
    if material is not None:
        prim = stage.GetPrimAtPath(material)
        if not prim:
            raise BTFError(f"{stage.GetRootLayer().identifier}: no prim {material}")
        return prim
    found = btf_materials(stage)
    if not found:
        errors = stage.GetCompositionErrors()
        why = f" (composition error: {' '.join(str(errors[0]).split())})" if errors else ""
        raise BTFError(f"{stage.GetRootLayer().identifier}: contains no BtfMaterialAPI material{why}")
    if len(found) > 1:
        raise BTFError(f"{stage.GetRootLayer().identifier}: has {len(found)} BTF materials "
                       f"({', '.join(str(p.GetPath()) for p in found)}); choose one")
    return found[0]


def load_btf(asset, *, material: str | None = None, lod: str | None = None, k: int | None = None,
             lazy: bool = False) -> CompressedBTF:
    """The compressed BTF of a packaged asset (a path or an open Usd.Stage); ``lazy``: its
    coefficients read when asked for (:func:`usdbtf.usd.material.read_btf`)."""
    stage = open_stage(asset, lod=lod) if not hasattr(asset, "GetRootLayer") else asset
    return read_btf(find_material(stage, material), k=k, lazy=lazy)


def sample_index(cbtf: CompressedBTF, view, light, *, tol_deg: float = 1e-3) -> int:
    """Index of the measured sample with view and light (theta, phi) degrees (phi mod 360;
    phi is irrelevant at theta = 0)."""
    def same(dirs, want):
        dtheta = np.abs(dirs[:, 0] - want[0])
        dphi = np.abs((dirs[:, 1] - want[1] + 180.0) % 360.0 - 180.0)
        return (dtheta <= tol_deg) & ((dphi <= tol_deg) | (np.abs(want[0]) <= tol_deg))

    view, light = np.asarray(view, float), np.asarray(light, float)
    hits = np.flatnonzero(same(cbtf.sampling.view, view) & same(cbtf.sampling.light, light))
    if not len(hits):
        raise BTFError(f"view {view.tolist()} light {light.tolist()} is not a measured direction pair "
                       f"(the renderer interpolates between them)")
    return int(hits[0])


def sample_image(cbtf: CompressedBTF, view, light, *, k: int | None = None) -> np.ndarray:
    """(H, W, 3) float32 working-space image of the measured sample at (view, light)."""
    return reconstruct(cbtf, [sample_index(cbtf, view, light)], k=k)[0]
