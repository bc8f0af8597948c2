"""The one hand-written GLSL core and the names its consumers share.

``glsl/btf_core.glsl`` is the shading (equation 2 with the CPU renderer's hemisphere
interpolation); :func:`core_source` puts the page macros in front of it.  The GLSL consumers
(:mod:`usdbtf.gpu.shaders`) include it unchanged; the OSL ones (:mod:`usdbtf.gpu.osl`) translate it
(:mod:`usdbtf.gpu.glsl_to_osl`).
"""
from __future__ import annotations

from pathlib import Path

from .tables import MAX_PAGES

__all__ = ["MTLX_BSDF", "MTLX_SURFACE", "GLSL_DIR", "page_name", "page_sampler", "core_source"]

MTLX_BSDF = "usdbtf_bsdf"
MTLX_SURFACE = "usdbtf_surface"
GLSL_DIR = Path(__file__).resolve().parent / "glsl"


def page_name(page: int) -> str:
    """Shader input of coefficient page ``page`` (an atlas of packs, usdbtf.gpu.tables)."""
    return f"page{page:02d}"


def page_sampler(page: int) -> str:
    """The GLSL name of page ``page``'s sampler in the core's functions (and the harness)."""
    return f"btfPage{page:02d}"


def core_source() -> str:
    """The shared GLSL (functions only, no #version) after the page macros it uses: the
    samplers ``btfPage00`` .. as parameters and arguments, and the fetch of texel (x, y)
    (image row y from the top) of page ``page``."""
    names = [page_sampler(p) for p in range(MAX_PAGES)]
    fetch = " ".join(f"if (page == {p}) {{ return texelFetch({n}, ivec2(x, textureSize({n}, 0).y - 1 - y), 0); }}"
                     for p, n in enumerate(names))
    return (f"#define BTF_MAX_PAGES {MAX_PAGES}\n"
            f"#define BTF_PAGE_PARAMS {', '.join(f'sampler2D {n}' for n in names)}\n"
            f"#define BTF_PAGE_ARGS {', '.join(names)}\n"
            f"#define BTF_PAGE_FETCH {fetch}\n"
            + (GLSL_DIR / "btf_core.glsl").read_text())
