"""A last check before a USD layer is published: no NaN or infinite number in it.

Nothing non-finite is ever written: readers validate their inputs, and this catches what
slips through (a NaN vertex of a mesh, a scale computed from bad data) in the layers a
writer staged, naming the attribute, before they replace anything.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["non_finite_values", "non_finite_in_stage"]


def _bad(value) -> bool:
    """True when ``value`` is numeric and holds NaN or Inf (strings, tokens, asset paths and
    other non-numeric values are never bad)."""
    if isinstance(value, bool) or value is None or isinstance(value, (str, bytes)):
        return False
    if isinstance(value, (int, float)):
        return not np.isfinite(value)
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):
        return False
    return arr.dtype.kind in "fc" and arr.size > 0 and not np.isfinite(arr).all()


def non_finite_values(layer_path) -> list[str]:
    """Attribute paths of the layer file ``layer_path`` whose default or time-sample values
    hold NaN or Inf."""
    from pxr import Sdf

    return _in_layer(Sdf.Layer.OpenAsAnonymous(str(Path(layer_path))))


def non_finite_in_stage(path) -> list[str]:
    """"<layer>: <attribute path>" for every non-finite value in any layer the stage at
    ``path`` uses (payloads loaded, usdz packages included)."""
    from ...usdstage import open_usd, usd_warnings_silenced

    with usd_warnings_silenced():
        stage = open_usd(path, composition_errors=False)
    found = []
    for layer in stage.GetUsedLayers():
        if layer.anonymous:
            continue
        name = Path(layer.realPath or layer.identifier).name
        found += [f"{name}: {attr}" for attr in _in_layer(layer)]
    return found


def _in_layer(layer) -> list[str]:
    from pxr import Sdf

    found = []

    def visit(path):
        if not path.IsPropertyPath():
            return
        spec = layer.GetAttributeAtPath(path)
        if spec is None:
            return
        if spec.HasDefaultValue() and _bad(spec.default):
            found.append(str(path))
            return
        for t in layer.ListTimeSamplesForPath(path):
            if _bad(layer.QueryTimeSample(path, t)):
                found.append(f"{path} at time {t:g}")
                return

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return found
