"""usdbtf: measured BTF materials (Koudelka et al. 2003) turned into production USD assets.

Stages, one module each, all speaking the :class:`usdbtf.model.BTF` data model:
``synth`` (procedural BTFs), ``manifest``/``ubo`` (readers and writers),
``compress`` (apparent-BRDF basis + coefficient textures), ...
"""
__version__ = "0.1.0"
