"""One exception type for bad input, so every CLI can print one clear line and exit non-zero."""
from __future__ import annotations

__all__ = ["BTFError"]


class BTFError(Exception):
    """Bad input or an impossible request.  The message names the file or sample at fault."""
