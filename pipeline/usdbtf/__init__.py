"""usdbtf: measured BTF materials (Koudelka et al. 2003) turned into production USD assets.

Stages, one module each, all speaking the :class:`usdbtf.model.BTF` data model:
``synth`` (procedural BTFs), ``manifest``/``ubo`` (readers and writers),
``compress`` (apparent-BRDF basis + coefficient textures), ``usd`` (the BtfMaterialAPI
schema, packaging, reading assets back), ...

Importing the package sets up the usdBtf USD plugin for this process (the environment
``usdbtf env`` prints), so it must come before the process first imports pxr (see
:mod:`usdbtf.usd.plugin`).  It does so without importing USD: ``usdbtf --version`` and
``--help`` load no pxr, numpy or OIIO.

It also pins the numeric platform (:mod:`usdbtf.numeric`: the BLAS kernel and numpy's SIMD
level) before numpy loads, so that any x86-64-v3 machine writes the same bytes.
"""
__version__ = "0.1.0"

from . import lifetime as _lifetime  # noqa: F401 - its fork hooks: what usdbtf forks dies with its parent
from .numeric import pin as _pin_numeric_platform
from .usd.plugin import register_lazily as _register_usd_plugin

_pin_numeric_platform()
_register_usd_plugin()
