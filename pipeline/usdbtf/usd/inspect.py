"""A human-readable summary of the BTF materials on a stage (``usdbtf inspect``)."""
from __future__ import annotations

import numpy as np

from .material import LOD_VARIANT_SET, NS, btf_materials
from .read import find_material, open_stage


def asset_bytes(asset) -> int:
    """Bytes of the file an Sdf.AssetPath resolves to (members of a .usdz included); 0 if unresolved."""
    from pxr import Ar

    if not asset.resolvedPath:
        return 0
    info = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(asset.resolvedPath))
    return int(info.GetSize()) if info is not None else 0


def _error_at(prim, k: int) -> float | None:
    ks, pct = prim.GetAttribute(NS + "errorCurve:k").Get(), prim.GetAttribute(NS + "errorCurve:percent").Get()
    if not ks or not pct:
        return None
    table = dict(zip(ks, pct))
    return float(table[k]) if k in table else None


def _lod_levels(stage, prim) -> list[tuple[str, int]]:
    """(variant name, basis count) for each lod variant of the material's asset root."""
    from pxr import Usd

    root = prim
    while root and not (root.HasVariantSets() and root.GetVariantSets().HasVariantSet(LOD_VARIANT_SET)):
        root = root.GetParent()
    if not root or root.IsPseudoRoot():
        return []
    vset = root.GetVariantSets().GetVariantSet(LOD_VARIANT_SET)
    current = vset.GetVariantSelection()
    levels = []
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for name in vset.GetVariantNames():
            vset.SetVariantSelection(name)
            p = stage.GetPrimAtPath(prim.GetPath())
            count = p.GetAttribute(NS + "basisCount").Get() or len(p.GetAttribute(NS + "coefficients").Get() or [])
            levels.append((name, int(count)))
        vset.SetVariantSelection(current)
    return sorted(levels, key=lambda x: -x[1])


def describe(path) -> str:
    """Multi-line summary of every BTF material reachable from ``path``."""
    stage = open_stage(path)
    prims = btf_materials(stage)
    if not prims:
        find_material(stage)   # raises, naming the composition error that hid them if any
    lines = [f"{path}: {len(prims)} BTF material(s); metersPerUnit "
             f"{stage.GetMetadata('metersPerUnit')}, upAxis {stage.GetMetadata('upAxis')}"]
    errors = stage.GetCompositionErrors()
    if errors:
        lines.append(f"  composition errors: {len(errors)}, first: {' '.join(str(errors[0]).split())}")
    for prim in prims:
        get = lambda name: prim.GetAttribute(NS + name).Get()  # noqa: E731
        coeffs = list(get("coefficients") or [])
        if get("basis") is None or not coeffs:
            source = get("build:source")
            lines.append(f"  {prim.GetPath()}\n    no BTF data yet" +
                         (f" (recipe: build from {source.path} with `usdbtf build`)" if source else ""))
            continue
        k = int(get("basisCount") or len(coeffs))
        view = np.asarray(get("viewDirections") or [], float).reshape(-1, 2)
        light = np.asarray(get("lightDirections") or [], float).reshape(-1, 2)
        basis_bytes = asset_bytes(get("basis"))
        coeff_bytes = [asset_bytes(a) for a in coeffs[:k]]
        w, h = get("resolution") or (0, 0)
        size = get("physicalSize")
        lines.append(f"  {prim.GetPath()}")
        lines.append(f"    k            {k} of {len(coeffs)} coefficient textures, {w}x{h} texels"
                     + (f", tile {size[0] * 100:.2f} x {size[1] * 100:.2f} cm" if size and size[0] > 0 else ""))
        lines.append(f"    bytes        {basis_bytes + sum(coeff_bytes)} (basis {basis_bytes}, coefficients "
                     f"{sum(coeff_bytes)})")
        if len(view):
            lines.append(f"    directions   {len(view)} samples: {len({tuple(v) for v in view})} views "
                         f"(theta {view[:, 0].min():g}..{view[:, 0].max():g} deg), "
                         f"{len({tuple(v) for v in light})} lights (theta {light[:, 0].min():g}.."
                         f"{light[:, 0].max():g} deg), {len(get('interpolatedSamples') or [])} interpolated")
        err = _error_at(prim, k)
        lines.append(f"    error        " + (f"{err:.3f} % at k = {k} (scene-linear, paper's metric)"
                                             if err is not None else "not recorded"))
        lines.append(f"    colour       {get('colorSpace')} ({get('ocioConfig')}); measured in "
                     f"{get('source:colorSpace')} {get('source:bitDepth')}")
        lines.append(f"    provenance   {get('provenance:solver')} solver, {get('provenance:codec')} codec, "
                     f"usdbtf {get('provenance:version')}, from {get('provenance:source')}")
        levels = _lod_levels(stage, prim)
        if levels:
            lines.append("    lod          " + ", ".join(
                f"{name} (k = {n}" + (f", {_error_at(prim, n):.2f} %" if _error_at(prim, n) is not None else "")
                + ")" for name, n in levels))
    return "\n".join(lines)
