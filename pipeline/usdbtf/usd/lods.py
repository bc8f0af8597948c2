"""The default level-of-detail variants of a packaged asset (shared by packaging and the
Storm preview network, which both author the ``lod`` variant set)."""
from __future__ import annotations

__all__ = ["default_lods"]


def default_lods(k: int) -> list[int]:
    """Levels of detail for ``k`` vectors: k, then halvings down to no fewer than 4."""
    levels, n = [], k // 2
    while n >= 4 and len(levels) < 3:
        levels.append(n)
        n //= 2
    return levels
