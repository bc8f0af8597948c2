"""Readable JSON for the project's large documents (manifests, compressed-BTF metadata).

``json.dumps(doc, indent=1)`` puts every number on a line of its own and runs Python's
pure-Python encoder (indenting disables the C one): for a 10^4-sample document that is
~70,000 lines and ~0.15 s.  :func:`dumps` keeps objects indented but writes small things on
one line, each through the C encoder:

* a list of scalars: one line (``[0.5, 1.25]``);
* a list of such lists (directions, matrices): one row per line;
* a list of flat objects (manifest samples, per-texture entries): one object per line.

The text parses to exactly what ``json.dumps(doc, indent=1)`` parses to (same key order,
same float repr); only the whitespace differs.
"""
from __future__ import annotations

import json

__all__ = ["dumps", "load"]

# One encoder for every call: json.dumps with options builds a new one each time, which
# dominates for 10^4 one-line sample entries.
_compact = json.JSONEncoder(separators=(", ", ": "), allow_nan=False).encode


def _scalar(v) -> bool:
    return not isinstance(v, (dict, list, tuple))


def _flat_object(v) -> bool:
    """An object whose values are all scalars or lists of scalars."""
    return isinstance(v, dict) and all(
        _scalar(x) or (isinstance(x, (list, tuple)) and all(_scalar(y) for y in x)) for x in v.values())


def _list_text(obj, pad: str, inner: str, step: str) -> str:
    text = _compact(obj)
    if '"' not in text and "{" not in text:
        # No strings, so every bracket is structure: one "[" means scalars only (one line);
        # one per item plus the outer one, with every item a list, means rows of numbers.
        brackets = text.count("[")
        if brackets == 1:
            return text
        if brackets == len(obj) + 1 and all(isinstance(v, (list, tuple)) for v in obj):
            return "[\n" + inner + text[1:-1].replace("], [", "],\n" + inner + "[") + "\n" + pad + "]"
    if all(_scalar(v) for v in obj):
        return text
    lines = (inner + (_compact(v) if _flat_object(v) else _text(v, inner, step)) for v in obj)
    return "[\n" + ",\n".join(lines) + "\n" + pad + "]"


def _text(obj, pad: str, step: str) -> str:
    inner = pad + step
    if isinstance(obj, dict) and obj:
        items = (f"{inner}{_compact(str(key))}: {_text(value, inner, step)}" for key, value in obj.items())
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(obj, (list, tuple)) and obj:
        return _list_text(obj, pad, inner, step)
    return _compact(obj)


def dumps(obj, indent: int = 1) -> str:
    """``obj`` as indented JSON text with compact leaves (see the module docstring).
    NaN and infinities are refused (strict JSON), as with ``allow_nan=False``."""
    return _text(obj, "", " " * indent)


def load(path, what: str):
    """Parse the JSON file ``path`` (a ``what``, e.g. "JSON manifest") for a reader.

    A missing file or text that is not JSON is bad input (:class:`~usdbtf.errors.BTFError`,
    exit status 65); an operating-system error reading it (permission denied, a folder
    where the file should be) is :class:`~usdbtf.errors.IOFailure` (74).  Either names the
    file.
    """
    from pathlib import Path

    from .errors import BTFError, IOFailure, link_error, os_error_message

    path = Path(path)
    broken = link_error(path)          # a loop or a dangling link: say so, naming the chain
    if broken is not None:
        raise broken
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise BTFError(f"{path}: {what} not found") from None
    except UnicodeDecodeError as exc:
        raise BTFError(f"{path}: not a readable {what} ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise IOFailure(os_error_message(exc, path)) from None
    try:
        return json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise BTFError(f"{path}: not a readable {what} ({' '.join(str(exc).split())[:200]})") from None
