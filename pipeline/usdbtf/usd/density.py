"""Physical scale as a checked property (issue 31): the texel density a BTF material has on
each mesh bound to it, against the material's own.

A material's density is its texture resolution over its physical size (``btf:resolution`` /
``btf:physicalSize``, texels per metre; the geometric mean of the two axes).  On a mesh, the
same textures cover the mesh's UV area, so the density there is
``sqrt(W * H * uv_area / world_area)`` with the areas summed over the mesh's triangles (world
space, metres).  A swatch stretched over a whole [0, 1] atlas shows up as a density far from
the material's; an atlas made by ``usdbtf unwrap`` at the material's density matches it.
"""
from __future__ import annotations

import numpy as np

from ..mesh.frames import uv_stretch as stretch
from .material import NS

__all__ = ["uv_area", "stretch", "mesh_prims", "mesh_density", "binding_densities", "density_problems", "MAX_DENSITY_MISMATCH"]

#: Largest relative difference between the density on a mesh and the material's that passes.
MAX_DENSITY_MISMATCH = 0.02


def uv_area(mesh) -> float:
    """Total area of ``mesh``'s triangles in UV space (0 without UVs); overlaps count twice."""
    if mesh.uv is None:
        return 0.0
    uv = mesh.corner(mesh.uv)                                   # (F, 3, 2)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())


def mesh_prims(stage):
    """Every Mesh prim of the composed ``stage`` (default predicate), instance proxies included:
    the meshes of instanceable prims are bound, rendered and measured like any other."""
    from pxr import Usd, UsdGeom

    return [p for p in stage.Traverse(Usd.TraverseInstanceProxies()) if p.IsA(UsdGeom.Mesh)]


def mesh_density(mesh, width: int, height: int) -> float | None:
    """Texels per metre of a (width, height) texture over ``mesh``'s UVs; None without UVs
    or area."""
    area, world_area = uv_area(mesh), mesh.area()
    if not (area > 0 and world_area > 0):
        return None
    return float(np.sqrt(width * height * area / world_area))


def binding_densities(stage) -> list[dict]:
    """[{"prim", "material", "mesh_texels_per_metre", "material_texels_per_metre", "ratio",
    "stretch" (:func:`stretch`, reported, not checked), "problem"}] for every Mesh prim bound (all purposes) to a BTF material with a resolution
    and a physical size; ``mesh_texels_per_metre`` and ``ratio`` (mesh / material) are None
    when the mesh has no UVs, or cannot be read (``problem`` says why)."""
    from pxr import UsdShade

    from ..errors import BTFError
    from ..mesh import load_prim

    out = []
    for prim in mesh_prims(stage):
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not material:
            continue
        resolution = material.GetPrim().GetAttribute(NS + "resolution").Get()
        size = material.GetPrim().GetAttribute(NS + "physicalSize").Get()
        if not resolution or not size or min(resolution) <= 0 or min(size) <= 0:
            continue
        w, h = int(resolution[0]), int(resolution[1])
        material_density = float(np.sqrt(w * h / (float(size[0]) * float(size[1]))))
        try:
            mesh = load_prim(prim)
            on_mesh, anisotropy, problem = mesh_density(mesh, w, h), stretch(mesh, w, h), None
        except BTFError as exc:        # a broken mesh (NaN points, bad primvars): reported, not raised
            on_mesh, anisotropy, problem = None, None, str(exc)
        out.append({"prim": str(prim.GetPath()), "material": str(material.GetPath()),
                    "mesh_texels_per_metre": on_mesh, "material_texels_per_metre": material_density,
                    "ratio": on_mesh / material_density if on_mesh is not None else None, "stretch": anisotropy,
                    "problem": problem})
    return out


def density_problems(entries: list[dict]) -> list[str]:
    """A validation line for every binding whose density on the mesh is missing or off by
    more than :data:`MAX_DENSITY_MISMATCH`."""
    lines = []
    for e in entries:
        where = f"{e['prim']} (bound to {e['material']})"
        if e.get("problem"):
            lines.append(f"[usdbtf:TexelDensity] {where}: cannot measure: {e['problem']}")
        elif e["ratio"] is None:
            lines.append(f"[usdbtf:TexelDensity] {where}: the mesh has no texture coordinates (or no area), so "
                         "the material has no physical scale on it")
        elif abs(e["ratio"] - 1) > MAX_DENSITY_MISMATCH:
            lines.append(f"[usdbtf:TexelDensity] {where}: {e['mesh_texels_per_metre']:.1f} texels/m on the mesh, "
                         f"the material's is {e['material_texels_per_metre']:.1f} ({(e['ratio'] - 1) * 100:+.1f} %, "
                         f"more than {MAX_DENSITY_MISMATCH * 100:g} %); `usdbtf build` unwraps and quilts it")
    return lines
