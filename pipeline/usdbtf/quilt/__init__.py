"""Image quilting in coefficient space (Koudelka et al. 2003, sec. IV; Efros & Freeman 2001)."""
from .core import DEFAULT_M, Quilt, QuiltOptions, prepare_source, quilt
from .folder import POSITION_MAP, quilted_btf, read_position_map, write_quilted

__all__ = ["DEFAULT_M", "Quilt", "QuiltOptions", "prepare_source", "quilt", "POSITION_MAP", "quilted_btf",
           "read_position_map", "write_quilted"]
