"""The one rule the example scripts that draw pictures share: where a picture may be written.

A picture goes to a ``.png`` path that is absent or already holds a PNG (a previous picture);
anything else there (notes, a scene, a folder, a link) is never replaced: the script stops
before any work with one line ``NAME: error: PATH: ...`` and exit status 73 (output refused).
"""
from __future__ import annotations

import sys
from pathlib import Path

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
REFUSED = 73


def picture_refusal(path) -> str | None:
    """Why ``path`` may not be written (None: it may)."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        return f"{path}: the picture must be a .png path"
    if path.is_symlink() or (path.exists() and not path.is_file()):
        return f"{path}: exists and is not a plain file; refusing to replace it"
    if path.exists():
        with open(path, "rb") as f:
            if f.read(len(PNG_SIGNATURE)) != PNG_SIGNATURE:
                return f"{path}: exists and is not a PNG picture; refusing to replace it"
    return None


def refused(path, name: str) -> int | None:
    """73 after printing why, when ``path`` may not be written; None when it may."""
    why = picture_refusal(path)
    if why is None:
        return None
    print(f"{name}: error: {why}", file=sys.stderr)
    return REFUSED
