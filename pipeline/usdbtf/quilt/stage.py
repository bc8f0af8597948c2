"""``quilt``: synthesise a larger coefficient-texture set from a compressed BTF.

    >>> from usdbtf.quilt import QuiltOptions, quilt, write_quilt
    >>> result = quilt("pebbles_c", QuiltOptions(size=(1024, 1024), seed=1, tileable=True))
    >>> result.positions.shape       # (1024, 1024) flat source texel per output texel
    >>> write_quilt(result, "pebbles_q1024")

``quilt(source, options, atlas=None) -> QuiltResult`` is the stage: a plane of
``options.size`` texels (:func:`~.core.quilt_plane`), or the charts of an ``usdbtf unwrap``
atlas (:func:`~.atlas.quilt_atlas`), in memory; :func:`~.folder.write_quilt` writes it.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ..compress.format import CompressedBTF, read_compressed
from ..errors import UsageError
from .atlas import quilt_atlas
from .core import QuiltOptions, QuiltResult, quilt_plane
from ..numeric import single_blas_thread

__all__ = ["quilt"]


@single_blas_thread
def quilt(source, options: QuiltOptions, *, atlas=None) -> QuiltResult:
    """Quilt ``source`` (a :class:`CompressedBTF`, or the folder of one) into a plane of
    ``options.size`` texels, or into the charts of ``atlas`` (an :class:`~usdbtf.unwrap.UnwrapResult`,
    or the path of an ``usdbtf unwrap`` layer) -- in memory; :func:`~.folder.write_quilt`
    writes the result.  UsageError for options that do not fit the sample."""
    folder = None
    if not isinstance(source, CompressedBTF):
        folder = Path(source)
        source = read_compressed(folder)
    if atlas is not None:
        q = quilt_atlas(source, atlas, options)
    else:
        if options.size is None:
            raise UsageError("give the output --size W H (or quilt into an --atlas)")
        q = quilt_plane(source, *options.size, options)
    return replace(q, source_folder=folder)
