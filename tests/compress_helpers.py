"""Compressing into a folder from tests: :func:`usdbtf.compress.compress`, then
:func:`usdbtf.compress.write_compress`."""
from __future__ import annotations

from usdbtf.compress import compress, write_compress


def compress_into(btf, folder, options=None):
    """``compress(btf, options)`` written to ``folder`` (replacing an earlier output there,
    as tests reuse folders); returns the in-memory result."""
    result = compress(btf, options)
    write_compress(result, folder, force=True)
    return result
