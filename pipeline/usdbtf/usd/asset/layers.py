"""Pieces every layer a package writes shares: stage metadata (with the usdbtf output
marker), the material's name, USD write errors, usdz packaging."""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

from ... import __version__
from ...errors import BTFError
from ...outputs import usd_marker

__all__ = ["MATERIAL", "FIXED_MTIME", "stage_metadata", "usd_write", "make_usdz", "valid_name"]

#: The BTF material's prim name under ``/<root>/mtl``.
MATERIAL = "BtfMaterial"
#: The modification time given to files before they are zipped (2000-01-01T00:00:00Z): the usdz
#: writer stores each file's mtime, and the same inputs must give the same bytes.
FIXED_MTIME = 946684800


def valid_name(text: str) -> str:
    """``text`` as a valid prim name (``Tf.MakeValidIdentifier``: the root prim after the
    file's stem, the geometry after the mesh's name)."""
    from pxr import Tf

    return Tf.MakeValidIdentifier(text)


def stage_metadata(layer, root: str, *, asset_name: str, what: str, creator: str | None = None) -> None:
    """defaultPrim, metersPerUnit 1, upAxis Y, a doc string, and customLayerData on ``layer``:
    the usdbtf output marker (:func:`usdbtf.outputs.usd_marker`, so ``--force`` recognises the
    layer), the tool and, when given, the creator."""
    from pxr import UsdGeom

    layer.defaultPrim = root
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.metersPerUnit, 1.0)
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.upAxis, UsdGeom.Tokens.y)
    layer.documentation = f"{what} of BTF asset {asset_name}, written by usdbtf {__version__}"
    data = {**usd_marker(), "generator": f"usdbtf {__version__}"}
    if creator:
        data["creator"] = creator
    layer.customLayerData = data


@contextlib.contextmanager
def usd_write(path: Path):
    """USD's write failures (Tf errors) as usdbtf errors naming ``path``: an operating-system
    problem (disk full, permission) is an IOFailure, anything else bad data."""
    from pxr import Tf

    from ...errors import OS_ERROR_WORDS, IOFailure
    from ...usdstage import tf_message

    try:
        yield
    except Tf.ErrorException as exc:
        text = tf_message(exc)
        if any(w in text for w in OS_ERROR_WORDS):
            # In the words every other writer uses for these (usdbtf.atomic), USD's after them.
            reason = next((r for w, r in _OS_REASONS.items() if w in text), "cannot write the USD layer")
            raise IOFailure(f"{path}: {reason} ({text})") from None
        raise BTFError(f"{path}: cannot write the USD layer ({text})") from None


#: USD's words for a full disk or file-size limit -> usdbtf's (usdbtf.atomic's).
_OS_REASONS = {"File too large": "file size limit exceeded", "No space left": "no space left on the device",
               "Disk quota exceeded": "disk quota exceeded"}


def make_usdz(root_layer: Path, usdz: Path) -> Path:
    """Package ``root_layer`` and everything it references into ``usdz`` (variants and payloads
    kept; the root layer first, files stored uncompressed and 64-byte aligned)."""
    from pxr import Sdf, UsdUtils

    for path in Path(root_layer).parent.rglob("*"):
        if path.is_file():
            os.utime(path, (FIXED_MTIME, FIXED_MTIME))
    with usd_write(usdz):
        made = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(root_layer)), str(usdz))
    if not made:
        raise BTFError(f"{usdz}: usdz packaging failed")
    return usdz
