"""The one photometric convention every usdbtf path follows: what a BTF value means, and what
radiance a renderer returns for it under a light.

What a value is
---------------
A BTF value ``I`` (a measured or reconstructed sample: scene-linear, in the BTF's working space)
is a **reflectance factor relative to the white level** ``W``: ``I / W`` is the material's
radiance relative to that of a white Lambertian surface (albedo 1, BRDF ``1 / pi``) lit head-on
by the same light.  ``W`` is what such a surface reads (``white_level`` in a source's metadata,
``btf:whiteLevel`` on a packaged Material; 1 unless recorded).  With ``f`` the material's
apparent BRDF (shadows, masking and inter-reflections of the surface included) and ``l`` the
light direction::

    I(x, v, l) = W * pi * f(x, v, l) * (n . l)

so the values include the light's foreshortening, and the capture's light has irradiance
:func:`capture_irradiance` ``= pi * W`` on a plane facing it (in the value's own units).

What a renderer returns
-----------------------
Under a light of irradiance ``E`` on a plane facing it (a UsdLux light's intensity x
``2^exposure`` x colour, times the solid angle for a ``DistantLight``: see docs/previews.md, "Which
lights the preview honours"), every BTF path returns the radiance::

    L = I * E / (pi * W)          (= f * E * (n . l), the physically based answer)

:func:`radiance_per_irradiance` is the factor ``1 / (pi * W)``.  A white Lambertian
``UsdPreviewSurface`` (``diffuseColor`` 1) beside the swatch returns ``E (n . l) / pi``, and the
BTF of a white Lambertian (``I = W (n . l)``) returns the same: the BTF, its fallback and any
ordinary physically based material agree on what white is.  The light that reproduces the
measured images (``L = I``) has irradiance ``pi * W``.

Who follows it: the shared GLSL (``gpu/glsl/btf_core.glsl``'s ``btfRadiancePerIrradiance``:
the Storm shader, the MaterialX genglsl/genosl node, the OSL shader and the Blender add-on),
the CPU renderer (``usdbtf render``, ``usdbtf preview``'s CPU frames, the thumbnail, which is
lit by the capture light), and the fallback fit (``usdbtf.svbrdf``: ``I / (pi W)`` is what it
fits ``f (n . l)`` to).

Assets
------
A packaged Material says which convention its values follow with ``btf:photometry``
(:data:`CONVENTION`, authored by ``usdbtf package``).  An asset written before this convention
has no opinion, and reads :data:`LEGACY`: its values are the same kind of number (nothing in the
data changed), so renderers render it under this convention with ``W = 1``; only its BTF preview
is ``1 / pi`` as bright as before under the same light (it now matches its own fallback, which
was always physically based).  Any other token is refused (:func:`check_photometry`).
"""
from __future__ import annotations

import math

from .errors import BTFError

__all__ = ["CONVENTION", "LEGACY", "KNOWN", "DEFAULT_WHITE_LEVEL", "capture_irradiance", "radiance_per_irradiance",
           "check_white_level", "white_level_of", "check_photometry"]

#: ``btf:photometry`` of an asset that follows this module's convention.
CONVENTION = "reflectance"
#: ``btf:photometry`` of an asset written before it (the schema's fallback: no opinion).
LEGACY = "legacy"
#: Tokens a reader knows; both render under :data:`CONVENTION` (module docstring).
KNOWN = (CONVENTION, LEGACY)
#: The white level of a source that records none.
DEFAULT_WHITE_LEVEL = 1.0


def check_white_level(white_level, where: str = "white_level") -> float:
    """``white_level`` as a float; BTFError (naming ``where``) unless finite and positive."""
    try:
        w = float(white_level)
    except (TypeError, ValueError):
        raise BTFError(f"{where}: white level {white_level!r} is not a number") from None
    if not (math.isfinite(w) and w > 0):
        raise BTFError(f"{where}: white level {white_level!r} must be a positive number")
    return w


def white_level_of(info: dict | None, where: str = "white_level") -> float:
    """The white level a compressed BTF's ``info`` records (``source_metadata.white_level``,
    what ``usdbtf.usd.read`` also fills from ``btf:whiteLevel``), else 1; checked."""
    meta = (info or {}).get("source_metadata") or {}
    return check_white_level(meta.get("white_level", DEFAULT_WHITE_LEVEL), where)


def capture_irradiance(white_level: float = DEFAULT_WHITE_LEVEL) -> float:
    """Irradiance (on a plane facing the light) of the capture's light: ``pi * W``.  A light of
    this irradiance reproduces the measured values."""
    return math.pi * float(white_level)


def radiance_per_irradiance(white_level: float = DEFAULT_WHITE_LEVEL) -> float:
    """``1 / (pi * W)``: radiance = BTF value x irradiance x this."""
    return 1.0 / (math.pi * float(white_level))


def check_photometry(token, where: str) -> str:
    """The ``btf:photometry`` token of an asset (None: unauthored, :data:`LEGACY`); BTFError
    naming ``where`` for a token this version does not know (a newer convention)."""
    token = LEGACY if token in (None, "") else str(token)
    if token not in KNOWN:
        raise BTFError(f"{where}: btf:photometry {token!r} is not a convention this usdbtf knows "
                       f"({', '.join(KNOWN)}); a newer usdbtf wrote it")
    return token
