"""Meshes: the one :class:`Mesh` type, the one loader (:func:`load_mesh`), tangent frames.

    >>> from usdbtf.mesh import load_mesh
    >>> mesh = load_mesh("knot.obj")                      # or .ply/.stl/.glb/.gltf/.off/.usd*
    >>> mesh.points.shape, mesh.triangles.shape, mesh.area()
"""
from .frames import mirrored_faces, tangent_frames, uv_gradients, uv_stretch
from .load import MESH_SUFFIXES, TRIMESH_SUFFIXES, USD_SUFFIXES, load_mesh, load_prim
from .model import ATTRIBUTES, CornerFrames, Mesh, chart_border_edges, degenerate_triangles, face_neighbours, smooth_normals, weld

__all__ = ["Mesh", "CornerFrames", "ATTRIBUTES", "load_mesh", "load_prim", "MESH_SUFFIXES", "TRIMESH_SUFFIXES", "USD_SUFFIXES",
           "weld", "face_neighbours", "chart_border_edges", "smooth_normals", "degenerate_triangles", "tangent_frames", "uv_gradients", "mirrored_faces",
           "uv_stretch"]
