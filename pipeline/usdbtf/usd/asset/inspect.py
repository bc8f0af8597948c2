"""What the BTF materials on a stage hold (``usdbtf inspect``): a summary dict and its text.

:func:`summary` is the machine-readable form (``inspect --json``; keys in
docs/unattended-runs-errors-outputs.md, "Scripting"), :func:`describe` the human-readable one written from it.
"""
from __future__ import annotations

import numpy as np

from ...errors import BTFError
from ...compress.coverage import coverage_summary, coverage_text
from ..material import GPU_PAGES, LOD_VARIANT_SET, NS, btf_materials, read_coverage, read_directions
from ...usdstage import resolve_usd
from ..density import binding_densities
from ..read import find_material, open_stage


def asset_bytes(asset) -> int:
    """Bytes of the file an Sdf.AssetPath resolves to (members of a .usdz included); 0 if unresolved."""
    from pxr import Ar

    if not asset.resolvedPath:
        return 0
    info = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(asset.resolvedPath))
    return int(info.GetSize()) if info is not None else 0


def _resolved_size(resolved: str) -> int:
    from pxr import Ar

    info = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved))
    return int(info.GetSize()) if info is not None else 0


def _network_assets(prim) -> list:
    """Sdf.AssetPaths a renderer loads for the material ``prim``: its ``btf:`` textures and
    the asset inputs of every shader reachable from its outputs through connections (a
    connection a ``lod`` variant blocks is not followed: that page is not loaded)."""
    from pxr import Sdf, UsdShade

    found = [a for name in ("basis", "coefficients") for a in _as_list(prim.GetAttribute(NS + name).Get())]
    seen, todo = set(), [o for o in UsdShade.Material(prim).GetOutputs()]
    while todo:
        port = todo.pop()
        for source in (port.GetConnectedSources()[0] if port.HasConnectedSource() else []):
            node = source.source.GetPrim()
            if node.GetPath() in seen:
                continue
            seen.add(node.GetPath())
            for attr in node.GetAttributes():
                if attr.GetTypeName() in (Sdf.ValueTypeNames.Asset, Sdf.ValueTypeNames.AssetArray):
                    found += _as_list(attr.Get())
            todo += UsdShade.ConnectableAPI(node).GetInputs()
    return found


def _as_list(value) -> list:
    if value is None:
        return []
    return [value] if hasattr(value, "resolvedPath") else list(value)


def loaded_files(stage, prim) -> list[tuple[str, int]]:
    """[(resolved path, bytes)] of every file rendering material ``prim`` loads on ``stage``
    as composed now: the stage's layers (file-backed), the asset's thumbnail (the default
    prim's), the material's BTF textures and those its shader networks read; sorted, each
    file once."""
    from pxr import UsdMedia

    files = {layer.realPath for layer in stage.GetUsedLayers() if not layer.anonymous and layer.realPath}
    assets = _network_assets(prim)
    root = stage.GetDefaultPrim()
    if root and root.HasAPI(UsdMedia.AssetPreviewsAPI):
        thumbs = UsdMedia.AssetPreviewsAPI(root).GetDefaultThumbnails()
        if thumbs and thumbs.defaultImage.resolvedPath:
            assets.append(thumbs.defaultImage)
    files |= {a.resolvedPath for a in assets if a.resolvedPath}
    return sorted((f, _resolved_size(f)) for f in files)


def lod_files(stage, prim, budget: int | None = None, *, shares: bool = True) -> list[dict]:
    """Per ``lod`` variant of material ``prim`` (largest first; the composed selection alone
    when it has none): {"name", "k", "files": [{"path", "bytes"}], "total", "share"}, the files
    :func:`loaded_files` finds with that variant selected (session layer only).  Paths are
    relative to the stage's root layer's folder where they are inside it.  "share": a lower
    level's share of ``budget`` (default the full level's total; :func:`usdbtf.usd.asset.lod.lod_share`)
    for an asset on GPU pages, the full level's is the budget; None otherwise, and without
    ``shares`` (which re-encodes the full tables' basis block once per level)."""
    import os

    base = os.path.dirname(stage.GetRootLayer().realPath or "")

    def rel(path: str) -> str:
        inside = base and (path.startswith(base + os.sep) or "[" in path and path.split("[")[0].startswith(base))
        return os.path.relpath(path, base) if inside and "[" not in path else path

    def entry(name, p):
        files = loaded_files(stage, p)
        document = _materialx_document(p)
        if document is not None:
            files = sorted(set(files) | {(document, _resolved_size(document))})
        k = int(p.GetAttribute(NS + "basisCount").Get() or 0)
        paged = str(p.GetAttribute(NS + "coefficientLayout").Get() or "files") == GPU_PAGES
        return {"name": name, "k": k, "files": [{"path": rel(f), "bytes": n} for f, n in files],
                "total": int(sum(n for _, n in files)), "share": None,
                "_pages": [a.resolvedPath for a in _as_list(p.GetAttribute(NS + "coefficients").Get())] if paged
                else None, "_basis": p.GetAttribute(NS + "basis").Get(), "_sizes": dict(files)}

    out = _per_lod(stage, prim, entry)
    out = [entry(None, prim)] if out is None else sorted(out, key=lambda x: -x["k"])
    if shares:
        _shares(out, budget)
    for lv in out:
        for key in ("_pages", "_basis", "_sizes"):
            lv.pop(key)
    return out


def _materialx_document(prim) -> str | None:
    """The MaterialX document ``package`` wrote beside the level's tables (``gpu/usdbtf.mtlx``
    for the full level, ``usdbtf_k<n>.mtlx`` for a lower one), if there is one: a MaterialX
    consumer of that level loads it with the pages, so it counts among the level's files
    although no USD layer names it."""
    import os
    from .storm import MTLX_FILE, lod_mtlx_name, lod_tables_name

    tables = prim.GetAttribute(NS + "basis").Get()
    path = getattr(tables, "resolvedPath", "") or ""
    if not path or "[" in path:
        return None                 # unresolved, or a .usdz member (no document beside it)
    k = int(prim.GetAttribute(NS + "basisCount").Get() or 0)
    stem = os.path.splitext(os.path.basename(path))[0]
    name = lod_mtlx_name(k) if stem == lod_tables_name(k) else MTLX_FILE
    document = os.path.join(os.path.dirname(path), name)
    return document if os.path.isfile(document) else None


def _shares(levels: list[dict], budget: int | None) -> None:
    """Set each level's "share" (:func:`lod_files`) from the full (first) level's pages and
    tables: what it spends on the vectors a level drops."""
    from ...gpu.tables import basis_bytes, basis_in_page
    from ...imageio import read_rgba
    from .lod import lod_share

    full = levels[0]
    if full["_pages"] is None or not full["_basis"] or not full["_basis"].resolvedPath or \
            "[" in full["_basis"].resolvedPath:
        return                      # files layout, or a .usdz member (no share reported)
    budget = full["total"] if budget is None else int(budget)
    full["share"] = budget
    if len(levels) == 1:
        return
    tables = read_rgba(full["_basis"].resolvedPath)
    if basis_in_page(tables):
        # Schema 4: each level's basis page is listed last, its bytes are the file's.
        def split(lv):
            return set(lv["_pages"][:-1]), lv["_sizes"].get(lv["_pages"][-1], 0)
    else:
        def split(lv):
            return set(lv["_pages"]), basis_bytes(tables, lv["k"])
    full_pages, basis_full = split(full)
    for lv in levels[1:]:
        pages, basis_own = split(lv)
        dropped = sum(full["_sizes"].get(page, 0) for page in full_pages - pages)
        lv["share"] = lod_share(budget, dropped, basis_full, basis_own)


def _error_at(prim, k: int) -> float | None:
    ks, pct = prim.GetAttribute(NS + "errorCurve:k").Get(), prim.GetAttribute(NS + "errorCurve:percent").Get()
    if not ks or not pct:
        return None
    table = dict(zip(ks, pct))
    return float(table[k]) if k in table else None


def _lod_levels(stage, prim) -> list[tuple[str, int]]:
    """(variant name, basis count) for each ``lod`` variant of the material (its own set,
    else the nearest ancestor's), largest first."""
    def level(name, p):
        count = p.GetAttribute(NS + "basisCount").Get() or len(p.GetAttribute(NS + "coefficients").Get() or [])
        return name, int(count)

    return sorted(_per_lod(stage, prim, level) or [], key=lambda x: -x[1])


def _per_lod(stage, prim, fn) -> list | None:
    """``[fn(variant name, material prim composed with it)]`` for each ``lod`` variant of
    material ``prim``'s own set, else its nearest ancestor's (the root prim's set switches the
    whole asset); None when there is none.  Each selection is made in the session layer and
    the previous one is put back after."""
    from pxr import Usd

    owner = prim
    while owner and not (owner.HasVariantSets() and owner.GetVariantSets().HasVariantSet(LOD_VARIANT_SET)):
        owner = owner.GetParent()
    if not owner or owner.IsPseudoRoot():
        return None
    vset = owner.GetVariantSets().GetVariantSet(LOD_VARIANT_SET)
    current = vset.GetVariantSelection()
    out = []
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for name in vset.GetVariantNames():
            vset.SetVariantSelection(name)
            out.append(fn(name, stage.GetPrimAtPath(prim.GetPath())))
        if current:
            vset.SetVariantSelection(current)
        else:
            vset.ClearVariantSelection()
    return out


def _theta_range(directions: np.ndarray) -> list[float] | None:
    return [float(directions[:, 0].min()), float(directions[:, 0].max())] if len(directions) else None


_FALLBACK_NAMES = {"UsdPreviewSurface": "UsdPreviewSurface", "ND_open_pbr_surface_surfaceshader": "OpenPBR (MaterialX)"}


def fallback_summary(prim) -> list[dict]:
    """The material's fallback surfaces: [{"output", "shader", "fit_error_percent"}] for each
    surface output whose source is a UsdPreviewSurface or an OpenPBR Surface (the error
    recorded when packaging, :data:`usdbtf.usd.asset.openpbr.FIT_ERROR_KEY`, or None)."""
    from pxr import UsdShade

    from .openpbr import FIT_ERROR_KEY

    out = []
    material = UsdShade.Material(prim)
    for output in material.GetSurfaceOutputs():
        for source in output.GetConnectedSources()[0]:
            shader = UsdShade.Shader(source.source.GetPrim())
            shader_id = shader.GetIdAttr().Get() if shader else None
            if shader_id in _FALLBACK_NAMES:
                error = source.source.GetPrim().GetCustomDataByKey(FIT_ERROR_KEY)
                out.append({"output": output.GetFullName(),
                            "shader": _FALLBACK_NAMES[shader_id],
                            "fit_error_percent": None if error is None else float(error)})
    return out


def _basis_page_listed(tables) -> bool:
    """Whether the GPU tables ``tables`` (an asset path) keep the basis codes in the basis page
    listed last in btf:coefficients (schema 4); False where they cannot be read as a file."""
    from ...gpu.tables import basis_in_page
    from ...imageio import read_rgba

    resolved = tables.resolvedPath if tables else ""
    if not resolved or "[" in resolved:
        return False
    try:
        return basis_in_page(read_rgba(resolved))
    except BTFError:
        return False


def material_summary(stage, prim) -> dict:
    """One BTF material's entry of :func:`summary`."""
    get = lambda name: prim.GetAttribute(NS + name).Get()  # noqa: E731
    coeffs = list(get("coefficients") or [])
    entry = {"path": str(prim.GetPath())}
    if get("basis") is None or not coeffs:
        source = get("build:source")
        entry.update(built=False, recipe={"source": source.path if source else None,
                                          "options": get("build:options") or "",
                                          "asset": get("build:asset").path if get("build:asset") else None})
        return entry
    paged = str(get("coefficientLayout") or "files") == "gpuPages"
    vectors = len(get("coefficientScale") or []) if paged else len(coeffs)
    k = int(get("basisCount") or vectors)
    view, light = read_directions(prim) if get("viewDirections") else (np.zeros((0, 2)), np.zeros((0, 2)))
    basis_bytes = asset_bytes(get("basis"))
    coeff_bytes = sum(asset_bytes(a) for a in coeffs[:k])
    if paged and _basis_page_listed(get("basis")):
        # Schema 4: the basis page, listed after the pages, is the basis's, beside its tables.
        page = asset_bytes(coeffs[-1])
        basis_bytes, coeff_bytes = basis_bytes + page, coeff_bytes - page
    size = get("physicalSize")
    resolution = [int(x) for x in (get("resolution") or (0, 0))]
    entry.update(
        built=True, k=k, coefficients=vectors, coefficient_files=len(coeffs), resolution=resolution,
        physical_size_m=[float(x) for x in size] if size and size[0] > 0 else None,
        bytes={"total": basis_bytes + coeff_bytes, "basis": basis_bytes, "coefficients": coeff_bytes},
        samples=len(view), views=len({tuple(v) for v in view}), lights=len({tuple(v) for v in light}),
        view_theta_deg=_theta_range(view), light_theta_deg=_theta_range(light),
        interpolated=len(get("interpolatedSamples") or []), error_percent=_error_at(prim, k),
        color_space=get("colorSpace"), ocio_config=get("ocioConfig"),
        # Issue 40: what the BTF shaders return; None (an asset before it): the working space.
        rendering_space=get("renderingColorSpace") or None,
        photometry=str(get("photometry")), white_level=float(get("whiteLevel")),
        source={"color_space": get("source:colorSpace"), "bit_depth": get("source:bitDepth")},
        provenance={"solver": get("provenance:solver"), "codec": get("provenance:codec"),
                    "version": get("provenance:version"), "source": get("provenance:source")},
        lod=[{"name": name, "k": n, "error_percent": _error_at(prim, n)} for name, n in _lod_levels(stage, prim)],
        lod_files=lod_files(stage, prim),
        coverage=coverage_summary(read_coverage(prim), len(view), *resolution),
        fallbacks=fallback_summary(prim))
    return entry


def summary(path) -> dict:
    """{"asset", "resolved", "meters_per_unit", "up_axis", "composition_errors", "materials": [...]}
    for every BTF material reachable from ``path`` (opened through the asset resolver)."""
    stage = open_stage(path)
    prims = btf_materials(stage)
    if not prims:
        find_material(stage)   # raises, naming the composition error that hid them if any
    return {"asset": str(path), "resolved": resolve_usd(path),
            "meters_per_unit": stage.GetMetadata("metersPerUnit"), "up_axis": stage.GetMetadata("upAxis"),
            "composition_errors": [" ".join(str(e).split()) for e in stage.GetCompositionErrors()],
            "materials": [material_summary(stage, prim) for prim in prims],
            "bindings": binding_densities(stage)}


def describe(path, info: dict | None = None) -> str:
    """Multi-line summary of every BTF material reachable from ``path`` (or of ``info``,
    a :func:`summary` already made)."""
    info = info or summary(path)
    lines = [f"{info['asset']}: {len(info['materials'])} BTF material(s); metersPerUnit "
             f"{info['meters_per_unit']}, upAxis {info['up_axis']}"]
    errors = info["composition_errors"]
    if errors:
        lines.append(f"  composition errors: {len(errors)}, first: {errors[0]}")
    for m in info["materials"]:
        if not m["built"]:
            source = m["recipe"]["source"]
            lines.append(f"  {m['path']}\n    no BTF data yet" +
                         (f" (recipe: build from {source} with `usdbtf build`)" if source else ""))
            continue
        w, h = m["resolution"]
        size = m["physical_size_m"]
        lines.append(f"  {m['path']}")
        lines.append(f"    k            {m['k']} of {m['coefficients']} coefficient textures, {w}x{h} texels"
                     + (f", tile {size[0] * 100:.2f} x {size[1] * 100:.2f} cm" if size else ""))
        b = m["bytes"]
        lines.append(f"    bytes        {b['total']} (basis {b['basis']}, coefficients {b['coefficients']}"
                     f"{' in GPU tables and pages' if m['coefficient_files'] != m['coefficients'] else ''})")
        if m["samples"]:
            (v0, v1), (l0, l1) = m["view_theta_deg"], m["light_theta_deg"]
            lines.append(f"    directions   {m['samples']} samples: {m['views']} views (theta {v0:g}..{v1:g} deg), "
                         f"{m['lights']} lights (theta {l0:g}..{l1:g} deg), {m['interpolated']} interpolated")
        if m.get("coverage"):
            lines.append(f"    coverage     {coverage_text(m['coverage'])}")
        err = m["error_percent"]
        lines.append("    error        " + (f"{err:.3f} % at k = {m['k']} (scene-linear, paper's metric)"
                                             if err is not None else "not recorded"))
        lines.append(f"    colour       {m['color_space']} ({m['ocio_config']}); measured in "
                     f"{m['source']['color_space']} {m['source']['bit_depth']}; shaders return "
                     + (m.get("rendering_space") or f"{m['color_space']} (packaged before the rendering space: "
                                                    "beside Rec.709 surfaces its hues differ)"))
        lines.append(f"    photometry   {m['photometry']}: radiance = value x irradiance / (pi x {m['white_level']:g})"
                     + (" (written before the convention: renders 1/pi as bright as it did)"
                        if m["photometry"] == "legacy" else ""))
        p = m["provenance"]
        lines.append(f"    provenance   {p['solver']} solver, {p['codec']} codec, usdbtf {p['version']}, "
                     f"from {p['source']}")
        if m.get("fallbacks"):
            lines.append("    fallbacks    " + ", ".join(
                f"{f['shader']} on {f['output']}"
                + (f" ({f['fit_error_percent']:.2f} %)" if f["fit_error_percent"] is not None else "")
                for f in m["fallbacks"]) + " (fitted error against the BTF, held-out samples)")
        if m["lod"]:
            lines.append("    lod          " + ", ".join(
                f"{lv['name']} (k = {lv['k']}"
                + (f", {lv['error_percent']:.2f} %" if lv["error_percent"] is not None else "") + ")"
                for lv in m["lod"]))
        for lv in m.get("lod_files", []):
            share = lv.get("share")
            lines.append(f"    loads        {lv['name'] or 'as composed'} (k = {lv['k']}): {len(lv['files'])} files, "
                         f"{lv['total']} bytes"
                         + ("" if share is None or lv is m["lod_files"][0] else
                            f"; {'within' if lv['total'] <= share else 'OVER'} its share {share} "
                            f"({lv['total'] / share:.3f} of it: the full lod's bytes less what it spends on "
                            f"the vectors this lod drops)"))
            lines += [f"                   {f['bytes']:>12}  {f['path']}" for f in lv["files"]]
    for b in info.get("bindings", []):
        on_mesh = b["mesh_texels_per_metre"]
        lines.append(f"  {b['prim']} -> {b['material']}: " + (
            f"{on_mesh:.1f} texels/m on the mesh, material {b['material_texels_per_metre']:.1f} "
            f"({(b['ratio'] - 1) * 100:+.2f} %), stretch {b['stretch']:.3f}" if on_mesh is not None
            else b.get("problem") or "no texture coordinates"))
    return "\n".join(lines)
