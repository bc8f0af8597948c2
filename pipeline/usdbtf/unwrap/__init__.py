"""Meshes and atlases: xatlas charts at the measured sample's texel density, tangent frames
that agree with the sample's axes, and the USD geometry layer packaging references."""
from .atlas import Atlas, chart_map, make_atlas, texel_density
from .core import CHARTS, LAYER, UnwrapOptions, read_chart_map, unwrap_to_folder
from .layer import UnwrappedMesh, read_layer
from .meshes import TriMesh, load_mesh

__all__ = ["Atlas", "chart_map", "make_atlas", "texel_density", "CHARTS", "LAYER", "UnwrapOptions",
           "read_chart_map", "unwrap_to_folder", "UnwrappedMesh", "read_layer", "TriMesh", "load_mesh"]
