"""Apparent-BRDF compression: basis + coefficient textures (see :mod:`.core`)."""
from .core import SOLVERS, Options, compress, compress_to_folder
from .format import CompressedBTF, read_compressed, reconstruct, write_compressed
from .metrics import ErrorSums

__all__ = ["SOLVERS", "Options", "compress", "compress_to_folder", "CompressedBTF", "read_compressed",
           "reconstruct", "write_compressed", "ErrorSums"]
