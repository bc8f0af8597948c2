"""Atlases: xatlas charts at the measured sample's texel density, tangent frames that agree
with the sample's axes, and the USD geometry layer packaging references.

``unwrap(mesh, UnwrapOptions) -> UnwrapResult``, ``write_unwrap(result, folder)``,
``read_unwrap(folder / "mesh.usda")``; meshes come from :func:`usdbtf.mesh.load_mesh`."""
from .atlas import MAX_ATLAS_SIDE, MIN_TEXEL_SCALE, Atlas, chart_map, make_atlas, texel_density
from .core import CHARTS, LAYER, UnwrapOptions, UnwrapResult, read_unwrap, unwrap, write_unwrap

__all__ = ["Atlas", "chart_map", "make_atlas", "texel_density", "MAX_ATLAS_SIDE", "MIN_TEXEL_SCALE", "CHARTS",
           "LAYER", "UnwrapOptions", "UnwrapResult", "unwrap", "write_unwrap", "read_unwrap"]
