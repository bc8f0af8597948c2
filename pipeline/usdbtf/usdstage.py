"""Opening USD files with errors that name the file.

Every reader of USD input (meshes, packaged assets, scenes) opens it here, so a missing
file, a syntax error or a broken reference is one :class:`~usdbtf.errors.BTFError` naming
the file and the parser's ``file:line:col: message``, not a traceback or USD's own warnings
on stderr.  Paths are found through the asset resolver (:func:`resolve_usd`), so a name the
studio's resolver understands (a search-path-relative name, a URI) works wherever a file
path does.
"""
from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
from .errors import BTFError

__all__ = ["USD_SUFFIXES", "open_usd", "resolve_usd", "usd_exists", "tf_message", "usd_warnings_silenced"]

#: File name suffixes of USD layers and packages.
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


def tf_message(exc) -> str:
    """The useful part of a Tf error: the parser's 'file:line:col: message' when there is one."""
    text = re.sub(r"pxrInternal_\w+?__pxrReserved__::", "", " ".join(str(exc).split()))
    found = re.search(r"'([^']*:\d+:\d+: [^']*)'", text)
    return found.group(1) if found else re.sub(r"Error in '[^']*' at line \d+ in file \S+ : ", "", text)[:300]


def resolve_usd(path) -> str:
    """The asset resolver's answer for ``path`` (a file path, a search-path-relative name,
    whatever the studio's resolver understands); BTFError when it finds nothing."""
    from pxr import Ar

    resolved = str(Ar.GetResolver().Resolve(str(path)))
    if not resolved:
        raise BTFError(f"{path}: no such USD file (the asset resolver finds nothing there)")
    return resolved


def usd_exists(path) -> bool:
    """Whether ``path`` names a USD layer (by its suffix) that the asset resolver finds."""
    from pxr import Ar

    return str(path).lower().endswith(USD_SUFFIXES) and bool(str(Ar.GetResolver().Resolve(str(path))))


def composition_error_text(error) -> str:
    """One line for a Pcp composition error (``stage.GetCompositionErrors()``), as USD words it
    (a cycle names every layer and prim on it), without the stage's anonymous session layer,
    whose name holds a memory address (it would differ from run to run)."""
    return re.sub(r",?@anon:[^@]*@", "", " ".join(str(error).split()))


def composition_cycle(stage):
    """The first arc or sublayer cycle among ``stage``'s composition errors, or None."""
    from pxr import Pcp

    cycles = (Pcp.ErrorType_ArcCycle, Pcp.ErrorType_SublayerCycle)
    return next((e for e in stage.GetCompositionErrors() if e.errorType in cycles), None)


def open_usd(path, *, composition_errors: bool = True):
    """``Usd.Stage.Open(path)`` with payloads loaded, the path found through the asset
    resolver (:func:`resolve_usd`); raises BTFError naming the file for a missing or
    unparsable layer and (optionally) for composition errors, e.g. a corrupt payload or an
    unreadable referenced layer."""
    from pxr import Tf, Usd

    resolve_usd(path)
    path = str(path)
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise BTFError(f"{path}: cannot open USD layer: {tf_message(exc)}") from None
    if stage is None:
        raise BTFError(f"{path}: cannot open USD layer")
    errors = stage.GetCompositionErrors() if composition_errors else []
    if errors:
        raise BTFError(f"{path}: composition error: {composition_error_text(errors[0])}")
    return stage


@contextlib.contextmanager
def usd_warnings_silenced():
    """Hold back USD's own stderr warnings (composition errors we expect and report
    ourselves, e.g. references to assets a build has not written yet).

    USD prints from C++ straight to file descriptor 2, so the descriptor is pointed at
    a scratch file for the duration and restored after."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
