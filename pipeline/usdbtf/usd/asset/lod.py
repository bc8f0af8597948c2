"""Levels of detail of a packaged asset: the ``lod`` variant sets.

Coefficients are energy-ordered, so a level of detail is the first n textures of the same
files.  Two variant sets named ``lod``, both authored in the root layer (outside the
payload, so they can be chosen before it loads):

* on the **Material** (``/<root>/mtl/BtfMaterial``): variant ``k<n>`` sets
  ``btf:basisCount`` and ``btf:coefficients`` to the files of the first n (the pages they
  are on: the asset's one copy, ``gpuPages``; or the first n files), and on the Storm shader sets
  ``inputs:basisCount`` and blocks the connections of the coefficient pages it no longer
  needs (pages end where levels end, so Storm then loads only its own textures); with the
  GPU pages it also names the level's own tables (``gpu/tables_k<n>.exr``: the basis
  vectors and packs of its n vectors only) as ``btf:basis`` and as the Storm tables node's
  file, and (schema 4) its own basis page (``gpu/basis_k<n>.png``: its n vectors' codes) last
  in ``btf:coefficients`` and as the Storm basis page node's file, so every consumer of the
  composed stage reads that level's own tables and basis; variant
  ``full`` changes nothing.  A scene that
  references only the material (``@asset.usda@</pebbles/mtl/BtfMaterial>``, the scene pattern
  of docs/scenes-and-build.md) switches it with its own ``variants = {lod = "k16"}``.
* on the **root prim**: variant ``<name>`` selects the Material's variant ``<name>``, so
  the asset's own selection drives it.

**A lower level's share of a budget** (issue 39).  A level loads the files every level loads
(layers, fallback maps, thumbnail: the fixed part), its own coefficient pages and its own
tables.  Its share of a budget ``B`` (``compress --max-bytes``; without one, what the full
level loads) is ``B`` less what the full level spends on the vectors it drops
(:func:`lod_share`)::

    share(n) = B - (bytes of the full level's pages holding only vectors past n)
                 - (basis_bytes(k) - basis_bytes(n))

with ``basis_bytes(m)`` the first m basis vectors' codes encoded alone as the tables encode
them (:func:`usdbtf.gpu.tables.basis_bytes`; schema 4: the bytes of the basis page file of
the level of m vectors).  Not ``B n / k``: coefficients are energy-ordered,
so the first vectors carry most of the bytes (pebbles 32^2, k 152: the first 19 vectors, 1/8,
hold 37 % of the page bytes and 29 % of the basis bytes), and no prefix of the same codes could
meet a proportional share.  A level that loaded the full tables (assets before its own tables)
overspends its share by the basis it does not draw.

Why the root layer: an opinion in a variant is weaker than a local opinion on the same
prim in the same layer stack, but stronger than anything the root prim's payload brings
in (LIVRPS), so the payload can hold the full values as plain local opinions.
"""
from __future__ import annotations

__all__ = ["LOD_VARIANT_SET", "FULL_LOD", "default_lods", "lod_name", "author_lod_variants", "lod_share"]

from ...compress.packs import default_lods  # noqa: F401  (where rate control counts the asset's pages too)
from ..material import LOD_VARIANT_SET

FULL_LOD = "full"


def lod_name(n: int) -> str:
    return f"k{n}"


def lod_share(budget: int, dropped_pages: int, basis_full: int, basis_own: int) -> int:
    """A lower level of detail's share of ``budget`` bytes (module docstring): ``budget`` less
    ``dropped_pages`` (bytes of the full level's coefficient pages this level does not load)
    less ``basis_full - basis_own`` (basis codes of all k vectors and of this level's n, each
    encoded alone, :func:`usdbtf.gpu.tables.basis_bytes`)."""
    return int(budget) - int(dropped_pages) - (int(basis_full) - int(basis_own))


def author_lod_variants(stage, root_path: str, material_path: str, levels: list[int], coefficients: list[str],
                        storm: tuple[str, list, int] | None = None, *, paged: bool = False,
                        tables: dict | None = None, basis_pages: dict | None = None) -> list[str]:
    """Author both ``lod`` variant sets on ``stage`` (the root layer); returns the variant names.

    levels : basis counts below k (descending); coefficients : the k coefficient asset
    paths (relative to this layer), or with ``paged`` the coefficient pages (one per entry
    of storm's first packs: a level lists the pages its vectors are on, a prefix).
    storm : (Storm shader's name under the material, the first pack of each of its pages,
    the basis count its tables hold), or None without a Storm preview.
    tables : {n: asset path of the GPU tables of the first n vectors} (paged assets since issue
    39): variant ``k<n>`` names them as ``btf:basis`` and as the Storm tables node's file, so a
    level loads only its own basis vectors; a level without an entry keeps the full tables.
    basis_pages : {n: asset path of the basis page of the first n vectors} (schema 4): variant
    ``k<n>`` lists it after its pages in ``btf:coefficients`` (``coefficients`` then ends with
    the full level's basis page) and names it as the Storm basis page node's file.
    """
    from pxr import Sdf

    from ...gpu.shaders import page_name
    from ...gpu.tables import pack_count
    from ..material import NS
    from .storm import TABLES_NODE, basis_node

    names = [FULL_LOD] + [lod_name(n) for n in levels]
    material = stage.OverridePrim(material_path)
    mset = material.GetVariantSets().AddVariantSet(LOD_VARIANT_SET)
    for name in names:
        mset.AddVariant(name)
    for n in levels:
        mset.SetVariantSelection(lod_name(n))
        with mset.GetVariantEditContext():
            count = material.CreateAttribute(NS + "basisCount", Sdf.ValueTypeNames.Int, custom=False,
                                             variability=Sdf.VariabilityUniform)
            count.Set(n)
            coeffs = material.CreateAttribute(NS + "coefficients", Sdf.ValueTypeNames.AssetArray, custom=False,
                                              variability=Sdf.VariabilityUniform)
            if paged:
                _, first_packs, gpu_k = storm
                files = [c for c, first in zip(coefficients, first_packs) if first < pack_count(min(n, gpu_k))]
                if basis_pages and n in basis_pages:
                    files.append(basis_pages[n])
            else:
                files = coefficients[:n]
            coeffs.Set(Sdf.AssetPathArray([Sdf.AssetPath(p) for p in files]))
            own = [count, coeffs]
            if tables and n in tables:
                basis = material.CreateAttribute(NS + "basis", Sdf.ValueTypeNames.Asset, custom=False,
                                                 variability=Sdf.VariabilityUniform)
                basis.Set(Sdf.AssetPath(tables[n]))
                own.append(basis)
            for attr in own:
                attr.SetColorSpace("raw")
            if storm is not None:
                shader_name, first_packs, gpu_k = storm
                over = stage.OverridePrim(f"{material_path}/{shader_name}")
                over.CreateAttribute("inputs:basisCount", Sdf.ValueTypeNames.Int).Set(min(n, gpu_k))
                if tables and n in tables:
                    node = stage.OverridePrim(f"{material_path}/{TABLES_NODE}")
                    node.CreateAttribute("inputs:file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(tables[n]))
                if basis_pages and n in basis_pages:
                    node = stage.OverridePrim(f"{material_path}/{basis_node()}")
                    node.CreateAttribute("inputs:file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(basis_pages[n]))
                for page, first in enumerate(first_packs):
                    if first >= pack_count(min(n, gpu_k)):       # a page of vectors beyond n only
                        over.CreateAttribute(f"inputs:{page_name(page)}", Sdf.ValueTypeNames.Float).SetConnections([])
    mset.ClearVariantSelection()      # no selection of its own: the root's (or a referencing scene's) decides

    root = stage.GetPrimAtPath(root_path)
    rset = root.GetVariantSets().AddVariantSet(LOD_VARIANT_SET)
    for name in names:
        rset.AddVariant(name)
        rset.SetVariantSelection(name)
        with rset.GetVariantEditContext():
            stage.OverridePrim(material_path).GetVariantSets().SetSelection(LOD_VARIANT_SET, name)
    rset.SetVariantSelection(FULL_LOD)
    return names
