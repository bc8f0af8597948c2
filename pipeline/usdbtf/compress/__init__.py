"""Apparent-BRDF compression: basis + coefficient textures.

:func:`compress` (pure, in memory) and :func:`write_compress` (the folder) are the stage;
the steps :func:`compress` calls, in order, are public for benchmarks and distributed runs:
:func:`sample_texels`, :func:`load_source`, :func:`fit_basis`, :func:`held_out_set`,
:func:`sampled_coefficients`, :func:`color_decorrelation`, :func:`step_for_k`,
:func:`project`, :func:`rate_control` (:func:`quantise`, :func:`encode`),
:func:`held_out_error`, :func:`error_curve`.

The names below are loaded on first use (PEP 562): ``usdbtf compress --help`` reads
:mod:`.arguments` and :mod:`.options` only, without numpy, OpenCV or OpenImageIO.
"""
from __future__ import annotations

import importlib
import sys
import types

#: Public name -> the module of this package that defines it.
_WHERE = {
    "compress": "core", "write_compress": "core",
    "color_decorrelation": "decorrelate", "rotate_color": "decorrelate",
    "encode": "encode", "truncate_encoded": "encode",
    "HeldOut": "evaluate", "error_curve": "evaluate", "held_out_error": "evaluate", "held_out_set": "evaluate",
    "BasisFit": "fit", "fit_basis": "fit", "sampled_coefficients": "fit",
    "CompressedBTF": "format", "read_compressed": "format", "reconstruct": "format",
    "ErrorSums": "metrics",
    "SOLVERS": "options", "CompressOptions": "options",
    "project": "projection",
    "Factorisation": "quantise", "quantise": "quantise",
    "rate_control": "ratecontrol", "step_for_k": "ratecontrol",
    "load_source": "select_source",
    "Texels": "texels", "sample_texels": "texels",
}

__all__ = ["SOLVERS", "CompressOptions", "compress", "write_compress", "CompressedBTF", "read_compressed",
           "reconstruct", "ErrorSums", "Texels", "sample_texels", "load_source", "BasisFit", "fit_basis",
           "HeldOut", "held_out_set", "sampled_coefficients", "color_decorrelation", "rotate_color", "step_for_k",
           "project", "Factorisation", "rate_control", "quantise", "encode", "truncate_encoded", "held_out_error",
           "error_curve"]


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """Where a public function has its module's name (``quantise``, ``encode``), the import
    system binds the submodule on this package when it loads it; bind the function
    instead, as the eager ``from .quantise import quantise`` did."""

    def __setattr__(self, name, value):
        if isinstance(value, types.ModuleType) and _WHERE.get(name) == name:
            value = getattr(value, name)
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
