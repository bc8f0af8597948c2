"""Image quilting in coefficient space (Koudelka et al. 2003, sec. IV; Efros & Freeman 2001):
``quilt(source, QuiltOptions, atlas=None) -> QuiltResult`` and ``write_quilt(result, folder)``."""
from .core import DEFAULT_M, QuiltOptions, QuiltResult, prepare_source
from .folder import POSITION_MAP, quilted_btf, read_position_map, write_quilt
from .stage import quilt
from .texels import QuiltTexels, quilt_texels

__all__ = ["DEFAULT_M", "QuiltResult", "QuiltOptions", "prepare_source", "quilt", "POSITION_MAP", "quilted_btf",
           "read_position_map", "write_quilt", "QuiltTexels", "quilt_texels"]
