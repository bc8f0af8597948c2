"""Apparent-BRDF compression: basis + coefficient textures.

:func:`compress` (pure, in memory) and :func:`write_compress` (the folder) are the stage;
the steps :func:`compress` calls, in order, are public for benchmarks and distributed runs:
:func:`sample_texels`, :func:`load_source`, :func:`fit_basis`, :func:`held_out_set`,
:func:`sampled_coefficients`, :func:`colour_decorrelation`, :func:`step_for_k`,
:func:`project`, :func:`rate_control` (:func:`quantise`, :func:`encode`),
:func:`held_out_error`, :func:`error_curve`.
"""
from .core import compress, write_compress
from .decorrelate import colour_decorrelation, rotate_colour
from .encode import encode, truncate_encoded
from .evaluate import HeldOut, error_curve, held_out_error, held_out_set
from .fit import BasisFit, fit_basis, sampled_coefficients
from .format import CompressedBTF, read_compressed, reconstruct
from .metrics import ErrorSums
from .options import SOLVERS, CompressOptions
from .projection import project
from .quantise import Factorisation, quantise
from .ratecontrol import rate_control, step_for_k
from .source import load_source
from .texels import Texels, sample_texels

__all__ = ["SOLVERS", "CompressOptions", "compress", "write_compress", "CompressedBTF", "read_compressed",
           "reconstruct", "ErrorSums", "Texels", "sample_texels", "load_source", "BasisFit", "fit_basis",
           "HeldOut", "held_out_set", "sampled_coefficients", "colour_decorrelation", "rotate_colour", "step_for_k",
           "project", "Factorisation", "rate_control", "quantise", "encode", "truncate_encoded", "held_out_error",
           "error_curve"]
