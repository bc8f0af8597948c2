"""A scene's bound meshes at their material's measured scale (issue 31): what ``usdbtf build``
makes for every (BTF material, Mesh prim) binding, and the built scene that composes it.

For each binding, :func:`bindings` extracts the mesh prim into a layer of its own (points in
metres, in the prim's own frame when its world transform is a similarity, so moving or
rotating a mesh changes nothing; else in world space), and the build runs three steps on it:

* ``usdbtf unwrap --btf COMPRESSED --keep-uvs`` -- the mesh's atlas at the material's texel
  density (the mesh's own UVs when ``--keep-uvs`` accepts them, else xatlas charts);
* ``usdbtf quilt COMPRESSED --atlas mesh.usda`` -- the material quilted across those charts;
* ``usdbtf package QUILT --mesh mesh.usda`` -- the packaged material for that mesh.

Bindings of one material whose extracted meshes are byte-identical share these steps (one
atlas, one quilt).  The user's scene is never edited: the build writes the built stage
(:func:`built_scene_text`; ``SCENE.built.usda`` beside the scene unless ``usdbtf build -o``
names another path), whose root layer sublayers the user's scene and, being
stronger, overrides each bound mesh's topology, points, normals, ``st`` and tangent frames
with its atlas's and binds it to a Material referencing its packaged asset.

``btf:build:mapping = "tile"`` on a mesh prim (or its material) takes the cheap route instead:
one tileable quilt of :data:`TILE_SIZE` texels per material (``quilt --tileable --size``, then
``package``), and the built scene keeps the mesh's topology and scales its ``st`` so one tile
spans the quilt's physical size (the UVs' metres per unit measured from the mesh's world and UV
areas).

Instances are quilted once.  Meshes under instanceable prims are found as instance proxies,
and the proxies of one prototype at one scale extract to the same mesh, so they share one chain.
An instance proxy cannot be overridden, so the built scene authors their overrides in a
``class`` prim of its own (:data:`INSTANCE_CLASS` plus a digest of what it holds) and adds an
``inherits`` arc to that class on every instance (the instanceable prim itself, which may be
edited): instances given the same class still share one prototype.  A ``PointInstancer``'s
prototypes are ordinary prims of the scene (or instances), so each is quilted once however
many points draw it; the density is the prototype's own (the instancer's per-point scales are
not looked at).

Not covered: meshes of an instance nested inside another instance's prototype (the outer
instance's class cannot reach into the inner one), non-``Mesh`` gprims, and a binding
overruled by an ancestor's ``strongerThanDescendants`` binding.

Scene data never becomes code: paths and argument lists only (see :mod:`usdbtf.usd.scenes.build`).
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Binding", "bindings", "binding_steps", "binding_targets", "built_scene_text",
           "BINDINGS_SCOPE", "INSTANCE_CLASS"]

#: The prim of the built scene under which the per-mesh Materials live.
BINDINGS_SCOPE = "/UsdbtfBindings"
#: Name prefix of the built scene's root ``class`` prims that carry instanced meshes' overrides.
INSTANCE_CLASS = "UsdbtfInstance_"
#: ``btf:build:mapping`` values: a quilt across the mesh's own atlas, or a tileable quilt repeated
#: at physical scale through the mesh's UVs (their scale measured from the mesh's areas).
MAPPINGS = ("atlas", "tile")
#: Side of the tileable quilt of the "tile" mapping, texels.
TILE_SIZE = 256
_PURPOSES = {"": "material:binding", "preview": "material:binding:preview", "full": "material:binding:full"}


@dataclass
class Binding:
    """One unwrap -> quilt -> package chain of a material, shared by ``prims`` (their extracted
    meshes are identical).  ``mesh_text`` is the extracted mesh layer; ``placements``
    {prim path: (4, 4) matrix, row vectors} maps each prim's local points to the extracted
    space; ``relationships`` {prim path: [binding relationship names]} the purposes bound."""

    material: str
    key: str
    folder: Path
    mesh_text: str
    mapping: str = "atlas"
    prims: list[str] = field(default_factory=list)
    placements: dict = field(default_factory=dict)
    relationships: dict = field(default_factory=dict)

    @property
    def mesh_layer(self) -> Path:
        return self.folder / "source_mesh.usda"

    @property
    def unwrap(self) -> Path:
        return self.folder / "unwrap" / "mesh.usda"

    @property
    def quilt(self) -> Path:
        return self.folder / "quilt"

    @property
    def asset(self) -> Path:
        return self.folder / "asset" / f"{self.key}.usda"


def _placement(prim, metres_per_unit: float) -> np.ndarray:
    """(4, 4) row-vector matrix from the prim's local points to the extracted mesh's metres:
    a uniform scale when the world transform is a similarity (the density is the same and the
    extracted mesh does not change when the prim moves), else the world transform itself."""
    from pxr import UsdGeom

    xf = np.asarray(UsdGeom.XformCache().GetLocalToWorldTransform(prim), np.float64)
    linear = xf[:3, :3]
    det = np.linalg.det(linear)
    if det > 0:
        s = det ** (1.0 / 3.0)
        if np.allclose(linear @ linear.T / (s * s), np.eye(3), atol=1e-9):
            return np.diag([s * metres_per_unit] * 3 + [1.0])
    return xf @ np.diag([metres_per_unit] * 3 + [1.0])


def _extract(prim, placement: np.ndarray) -> str:
    """The usda text of ``prim``'s mesh (topology, points through ``placement``, ``st`` and
    normals as authored) as a one-mesh layer in metres."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    src = UsdGeom.Mesh(prim)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.GetStageUpAxis(prim.GetStage()))
    mesh = UsdGeom.Mesh.Define(stage, "/mesh")
    stage.SetDefaultPrim(mesh.GetPrim())
    pts = np.asarray(src.GetPointsAttr().Get() or [], np.float64).reshape(-1, 3)
    pts = (np.c_[pts, np.ones(len(pts))] @ placement)[:, :3]
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(pts, np.float32)))
    mesh.CreateFaceVertexCountsAttr(src.GetFaceVertexCountsAttr().Get())
    mesh.CreateFaceVertexIndicesAttr(src.GetFaceVertexIndicesAttr().Get())
    normals = src.GetNormalsAttr().Get()
    if normals:
        n = np.asarray(normals, np.float64).reshape(-1, 3) @ np.linalg.inv(placement[:3, :3]).T
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(n, np.float32)))
        mesh.SetNormalsInterpolation(src.GetNormalsInterpolation())
    st = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
    if st and st.HasValue():
        pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, st.GetInterpolation())
        pv.Set(st.ComputeFlattened())
    return layer.ExportToString()


def _mapping(prim, material_prim) -> str:
    """``btf:build:mapping`` of the mesh prim, else of its material, else "atlas"; BTFError
    naming the prim for anything but :data:`MAPPINGS`."""
    from ...errors import BTFError
    from ..material import NS

    for owner in (prim, material_prim):
        attr = owner.GetAttribute(NS + "build:mapping")
        if attr and attr.HasAuthoredValue():
            value = attr.Get()
            if not isinstance(value, str) or value not in MAPPINGS:
                raise BTFError(f"{owner.GetPath()}: {NS}build:mapping must be one of {', '.join(MAPPINGS)}, "
                               f"got {value!r}")
            return value
    return "atlas"


def bindings(stage, recipes, targets: dict, work: Path) -> list[Binding]:
    """The unwrap/quilt/package chains of every Mesh prim bound to a recipe's material.

    targets : {material path: {prim path: [binding relationship names]}}.  Chains are keyed by
    (material, extracted mesh text): identical meshes of one material share one chain."""
    from pxr import UsdGeom

    metres_per_unit = float(UsdGeom.GetStageMetersPerUnit(stage))
    out: list[Binding] = []
    for recipe in recipes:
        chains: dict[str, Binding] = {}
        for path in sorted(targets.get(recipe.material, {})):
            prim = stage.GetPrimAtPath(path)
            if not prim or not prim.IsA(UsdGeom.Mesh):
                continue
            mapping = _mapping(prim, stage.GetPrimAtPath(recipe.material))
            placement = _placement(prim, metres_per_unit)
            # Every tile-mapped mesh of a material shares its one tileable quilt.
            text = _extract(prim, placement) if mapping == "atlas" else ""
            chain = chains.get(text)
            if chain is None:
                # The folder is named after the first prim of the chain (prim names are identifiers).
                name = prim.GetName() if mapping == "atlas" else "tile"
                digest = hashlib.sha256(f"{recipe.material}\0{path if text else name}".encode()).hexdigest()[:10]
                key = f"{Path(recipe.material).name}_{name}"
                chain = chains[text] = Binding(recipe.material, key, work / "bindings" / f"{key}_{digest}", text,
                                               mapping)
            chain.prims.append(path)
            chain.placements[path] = placement
            chain.relationships[path] = targets[recipe.material][path]
        out += chains.values()
    return out


def binding_steps(chains: list[Binding], compressed: dict) -> list[dict]:
    """SCons commands (targets, sources, ``usdbtf`` argv, label) of every chain; ``compressed``
    {material: (its compressed folder's metadata file, [every file of it, or [] when a step
    makes it])}."""
    steps = []
    for c in chains:
        meta, files = compressed[c.material]
        folder = str(Path(meta).parent)
        label = f"{c.material} {c.prims[0]}"
        unwrap_out = c.unwrap.parent
        quilt_targets = [str(c.quilt / "btf-compressed.json"), str(c.quilt / "quilt_positions.exr")]
        if c.mapping == "tile":
            side = str(TILE_SIZE)
            steps += [
                {"label": "quilt " + label, "targets": quilt_targets, "sources": [meta, *files],
                 "argv": ["quilt", "--force", "-q", "--tileable", "--size", side, side, "-o", str(c.quilt), "--",
                          folder]},
                {"label": "package " + label, "targets": [str(c.asset)], "sources": quilt_targets,
                 "argv": ["package", "--force", "-q", "-o", str(c.asset), "--", str(c.quilt)]}]
            continue
        steps += [
            {"label": "unwrap " + label, "targets": [str(c.unwrap), str(unwrap_out / "charts.png")],
             "sources": [str(c.mesh_layer), meta, *files],
             "argv": ["unwrap", "--force", "-q", "--keep-uvs", "--btf", folder, "-o", str(unwrap_out), "--",
                      str(c.mesh_layer)]},
            {"label": "quilt " + label, "targets": quilt_targets,
             "sources": [str(c.unwrap), str(unwrap_out / "charts.png"), meta, *files],
             "argv": ["quilt", "--force", "-q", "--atlas", str(c.unwrap), "-o", str(c.quilt), "--", folder]},
            {"label": "package " + label, "targets": [str(c.asset)],
             "sources": [*quilt_targets, str(c.unwrap)],
             "argv": ["package", "--force", "-q", "--mesh", str(c.unwrap), "-o", str(c.asset), "--", str(c.quilt)]},
        ]
    return steps


def _copy_primvar(src_api, dst_api, name: str) -> None:
    pv = src_api.GetPrimvar(name)
    if not (pv and pv.HasValue()):
        return
    out = dst_api.CreatePrimvar(name, pv.GetTypeName(), pv.GetInterpolation())
    out.Set(pv.Get())
    if pv.IsIndexed():
        out.SetIndices(pv.GetIndices())
    else:
        out.BlockIndices()      # the scene's mesh may have indexed values of its own


def _override_mesh(stage, scene_stage, path: str, chain: Binding, material: str, at: str) -> None:
    """Over ``at`` (``path`` itself, or its place in an instance class) in the built scene with
    the chain's atlas mesh (back in the prim's local frame) and bind it to ``material`` for the
    purposes it was bound for."""
    from pxr import Sdf, Usd, UsdGeom, Vt

    atlas_stage = Usd.Stage.Open(str(chain.unwrap))
    atlas = UsdGeom.Mesh(next(p for p in atlas_stage.Traverse() if p.IsA(UsdGeom.Mesh)))
    over = stage.OverridePrim(at)
    mesh = UsdGeom.Mesh(over)
    inverse = np.linalg.inv(chain.placements[path])
    pts = np.asarray(atlas.GetPointsAttr().Get(), np.float64).reshape(-1, 3)
    pts = (np.c_[pts, np.ones(len(pts))] @ inverse)[:, :3]
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(pts, np.float32)))
    mesh.CreateFaceVertexCountsAttr(atlas.GetFaceVertexCountsAttr().Get())
    mesh.CreateFaceVertexIndicesAttr(atlas.GetFaceVertexIndicesAttr().Get())
    linear = chain.placements[path][:3, :3]

    def local(values, matrix):
        v = np.asarray(values, np.float64).reshape(-1, 3) @ matrix
        return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(
            v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300), np.float32))

    scene_prim = scene_stage.GetPrimAtPath(path)
    # Normals only where the scene has some (unwrap computes smooth ones for the tangent
    # frames; a box without normals must stay flat-shaded).
    if UsdGeom.Mesh(scene_prim).GetNormalsAttr().HasValue():
        if atlas.GetNormalsAttr().HasValue():
            mesh.CreateNormalsAttr(local(atlas.GetNormalsAttr().Get(), linear.T))
            mesh.SetNormalsInterpolation(atlas.GetNormalsInterpolation())
        else:
            mesh.GetPrim().CreateAttribute("normals", Sdf.ValueTypeNames.Normal3fArray).Block()
    src, dst = UsdGeom.PrimvarsAPI(atlas), UsdGeom.PrimvarsAPI(mesh)
    names = {pv.GetPrimvarName() for pv in src.GetPrimvarsWithValues()}
    for name in sorted(names):
        _copy_primvar(src, dst, name)
        if name in ("tangents", "bitangents"):      # surface directions: back through the inverse
            dst.GetPrimvar(name).Set(local(src.GetPrimvar(name).Get(), np.linalg.inv(linear)))
    # The scene's other per-point/per-face primvars no longer fit the new topology: blocked.
    for pv in UsdGeom.PrimvarsAPI(scene_prim).GetPrimvarsWithValues():
        if pv.GetPrimvarName() not in names and pv.GetInterpolation() != UsdGeom.Tokens.constant:
            attr = dst.CreatePrimvar(pv.GetPrimvarName(), pv.GetTypeName(), pv.GetInterpolation())
            attr.GetAttr().Block()
            attr.BlockIndices()
    _bind(over, chain.relationships[path], material)


def _bind(over, relationships: list[str], material: str) -> None:
    from pxr import Sdf, UsdShade

    UsdShade.MaterialBindingAPI.Apply(over)
    for rel in relationships:
        over.CreateRelationship(rel).SetTargets([Sdf.Path(material)])


def _override_tiled(stage, scene_stage, path: str, chain: Binding, material: str, at: str) -> None:
    """Over ``at`` (``path`` or its place in an instance class) with ``path``'s ``st`` scaled so
    that one tile of the tileable quilt spans the quilt's physical size on the mesh (the UVs'
    scale measured from the mesh's world and UV areas), and bind it to ``material``."""
    from pxr import Usd, UsdGeom, Vt

    from ...errors import BTFError
    from ...mesh import load_prim
    from ..density import uv_area
    from ..material import NS

    prim = scene_stage.GetPrimAtPath(path)
    mesh = load_prim(prim)
    area = uv_area(mesh)
    if not area > 0:
        raise BTFError(f"{path}: {NS}build:mapping = \"tile\" needs texture coordinates (primvars:st) that cover "
                       "some area")
    metres_per_uv = np.sqrt(mesh.area() / area)
    asset_stage = Usd.Stage.Open(str(chain.asset))
    tile = asset_stage.GetPrimAtPath(f"{asset_stage.GetDefaultPrim().GetPath()}/mtl/BtfMaterial")
    size = np.asarray(tile.GetAttribute(NS + "physicalSize").Get(), np.float64)
    st = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
    values = np.asarray(st.Get(), np.float64).reshape(-1, 2) * (metres_per_uv / size)
    over = stage.OverridePrim(at)
    out = UsdGeom.PrimvarsAPI(over).CreatePrimvar("st", st.GetTypeName(), st.GetInterpolation())
    out.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(values, np.float32)))
    _bind(over, chain.relationships[path], material)


def built_scene_text(scene: Path, scene_stage, chains: list[Binding], where: Path) -> str:
    """The usda text of the built stage (see the module docstring); its paths (the user's scene
    it sublayers, the packaged assets it references) are relative to ``where``, the folder it is
    written in.  Its layer metadata marks it (``customLayerData = {"usdbtf": {"output":
    "usdbtf-built-stage", "scene": <that sublayer path>}}``), so that a later build replaces it
    and nothing else."""
    import os

    from pxr import Sdf, Usd, UsdGeom, UsdShade

    from ...outputs import BUILT_STAGE, usd_marker

    layer = Sdf.Layer.CreateAnonymous(".usda")
    root = scene_stage.GetRootLayer().pseudoRoot
    for key in ("metersPerUnit", "upAxis", "defaultPrim"):
        if root.HasInfo(key):
            layer.pseudoRoot.SetInfo(key, root.GetInfo(key))
    layer.comment = "written by usdbtf build: the scene with every bound mesh at its material's measured scale"
    sublayer = os.path.relpath(scene, where)
    marker = usd_marker(BUILT_STAGE)
    marker["usdbtf"]["scene"] = sublayer
    layer.customLayerData = marker
    # Authored through a stage without the sublayer and references (relative to ``where``, which
    # an anonymous layer cannot resolve); those arcs are added to the layer afterwards.
    stage = Usd.Stage.Open(layer)
    UsdGeom.Scope.Define(stage, BINDINGS_SCOPE)
    references = []
    at, inherits = _instance_classes(scene_stage, chains)
    for cls in sorted(set(inherits.values())):
        stage.CreateClassPrim(cls)
    for chain in chains:
        material = f"{BINDINGS_SCOPE}/{chain.folder.name}"
        UsdShade.Material.Define(stage, material)
        references.append((material, chain.asset))
        for path in chain.prims:
            override = _override_tiled if chain.mapping == "tile" else _override_mesh
            override(stage, scene_stage, path, chain, material, at.get(path, path))
    for root in sorted(inherits):
        stage.OverridePrim(root).GetInherits().AddInherit(inherits[root])
    del stage
    layer.subLayerPaths.append(sublayer)
    for material, asset in references:
        target = Sdf.Path(f"/{Sdf.Layer.FindOrOpen(str(asset)).defaultPrim}/mtl/BtfMaterial")
        layer.GetPrimAtPath(material).referenceList.Prepend(Sdf.Reference(os.path.relpath(asset, where), target))
    return layer.ExportToString()


def _instance_classes(scene_stage, chains: list[Binding]) -> tuple[dict, dict]:
    """Where the overrides of instanced meshes go: ({instance proxy path: its path in a class},
    {instance prim path: that class's path}).  One class per distinct set of (mesh path inside
    the instance, chain), so instances that need the same overrides keep sharing a prototype."""
    groups: dict[str, list] = {}
    for chain in chains:
        for path in chain.prims:
            prim = scene_stage.GetPrimAtPath(path)
            if not prim.IsInstanceProxy():
                continue
            root = prim
            while root.IsInstanceProxy():         # up to the outermost instance (it may be edited)
                root = root.GetParent()
            inside = str(prim.GetPath().MakeRelativePath(root.GetPath()))
            groups.setdefault(str(root.GetPath()), []).append((inside, chain.folder.name, path))
    at, inherits = {}, {}
    for root, members in groups.items():
        signature = "\0".join(f"{inside}\0{name}" for inside, name, _ in sorted(members))
        cls = f"/{INSTANCE_CLASS}{hashlib.sha256(signature.encode()).hexdigest()[:10]}"
        inherits[root] = cls
        for inside, _, path in members:
            at[path] = f"{cls}/{inside}"
    return at, inherits


def binding_targets(stage, materials) -> dict:
    """{material path: {Mesh prim path: [binding relationship names]}} for ``materials``: the
    purposes (all, preview, full) under which each Mesh prim resolves to one of them."""
    from pxr import UsdShade

    from ..density import mesh_prims

    wanted = set(materials)
    out: dict[str, dict[str, list[str]]] = {}
    for prim in mesh_prims(stage):
        api = UsdShade.MaterialBindingAPI(prim)
        for purpose, rel in _PURPOSES.items():
            material, _ = api.ComputeBoundMaterial(purpose or UsdShade.Tokens.allPurpose)
            if material and str(material.GetPath()) in wanted:
                out.setdefault(str(material.GetPath()), {}).setdefault(str(prim.GetPath()), []).append(rel)
    return out
