"""File formats ``usdbtf package`` may write, as plain names (no USD or image library is
imported here: the command line lists them in ``--help``, which must stay fast)."""
from __future__ import annotations

__all__ = ["PAYLOAD_FORMATS", "TEXTURE_FORMATS"]

#: Layer formats of the heavy payload layer (the root may be .usda or .usdc).
PAYLOAD_FORMATS = ("usdc", "usda")
#: Texture file formats: PNG (every USD consumer and usdz), tiled mip-mapped TIFF through
#: maketx, tiled mip-mapped OpenEXR.
TEXTURE_FORMATS = ("png", "tx", "exr")
