"""Bonn's binary BTF files (``.btf``: the UBO2014 database and its siblings), read lazily.

UBO2014 (84 materials, 151 views x 151 lights, 400 x 400 texels) ships as DFMF files:
per channel of a decorrelated colour model, the factors U and S*V of a truncated SVD of
the (samples x texels) data matrix, in half floats.  This package reads every signature
the public reference readers handle -- cgbonn/btflib (MATLAB, by the format's authors)
and zeroeffects/btf (C++, embedded in the PyPI package btf-extractor):

===============  =======  ==========================================================
signature        format   notes
===============  =======  ==========================================================
``!DFMF08FCR``   DFMF     decorrelated full matrix factorisation (UBO2014's files);
``!DFMF08FC``             the same without the rotation block (zeroeffects only)
``!FMF12FCER``   FMF      one factorisation of all channels, extended header
``!FMF12FCE``             (dynamic-range reduction, height map); without "R": zeroeffects
``!FMF06FCR``    FMF      plain header
``!FMF06FC``
``!PVF06FCR``    PVF      per-view PCA (btflib only; also its legacy variant)
``!PVF06FC``
``!BDIF06R2!``   BDI      uncompressed ABRDF chunks, full or sparse (btflib only;
                          bzip2-compressed BDIs are refused, as btflib does)
===============  =======  ==========================================================

Where the references disagree this package follows btflib, the format's authors:

* **Rows.** File texel row 0 is the image's top row (btflib reshapes S*V to
  ``[width, height]`` and shows ``y = 1`` first).  zeroeffects/btf swaps rows y and H-1-y
  when loading (texture origin at the bottom), so btf-extractor's images are upside down
  relative to btflib's: ``usdbtf == extractor[::-1]``.
* **Colour model 11** (log Y, U/Y, V/Y -- UBO2014's): btflib inverts U = c1 (Y + eps);
  zeroeffects U = c1 Y + eps and clamps RGB to [0, 1] (see :mod:`.color_models`).
* **Angles** are radians in the file; btf-extractor reports degrees rounded to 0.1.
  Here they keep float32 precision, converted through the unit vector (btflib's way) and
  mapped to usdbtf's tangent frame (:func:`bonn_to_tangent_degrees`: the identity, see
  ``docs/ubo2014-frame.md``).

Also: the meta data's RGB scale factor is recorded, not applied (neither reference
applies it); rotations are recorded, not applied; ``ppmm`` gives ``physical_size_m``.

Laziness: blocks are memory-mapped, nothing is expanded at open.  ``UBO2014BTF.factors``
exposes the DFMF/FMF factors per channel -- ``samples`` (S x k, row v nL + l) and
``texels`` (T x k, row y W + x) with ``channel values = samples @ texels.T`` -- and the
colour model to invert after, so that a transcoder can work in memory proportional to the
factors (``usdbtf.compress.factored`` does); ``channels_to_rgb(planes, samples)`` applies to
channel values it multiplied out itself what ``read_encoded`` applies after the product (the
colour model's inverse, the cosine, the clamp).  ``read_encoded(samples, rows)`` multiplies out
any samples x row block.
"""
from .binary import SIGNATURES, BonnHeader
from .color_models import MODEL_NAMES, undecorrelate
from .formats import ChannelFactors, Factorisation
from .reader import DEFAULT_SPACE, UBO2014BTF, bonn_to_tangent_degrees, is_ubo2014, read_ubo2014

__all__ = ["read_ubo2014", "is_ubo2014", "UBO2014BTF", "Factorisation", "ChannelFactors", "BonnHeader",
           "SIGNATURES", "MODEL_NAMES", "undecorrelate", "bonn_to_tangent_degrees", "DEFAULT_SPACE"]
