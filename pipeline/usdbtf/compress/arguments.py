"""The arguments of ``usdbtf compress``, defined once: the command uses them, and
``usdbtf build`` parses a scene's ``btf:build:options`` with them (restricted to
:data:`SCENE_OPTIONS`), so a scene can say nothing the command would not accept."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..argtypes import SEED, WORKERS, add_outside_paths_flag, float_in, int_in
from ..cluster import ADDRESS_HELP, parse_address
from .options import BUDGET_FOR, CODEC_NAMES, DEFAULT_CODEC, EFFORTS, ERROR_DOMAINS, SOLVERS

__all__ = ["SCENE_OPTIONS", "add_arguments"]

#: Options a scene's ``btf:build:options`` may give (``usdbtf build``): everything that
#: steers the result, nothing that names files or changes how the command runs.
SCENE_OPTIONS = ("solver", "k", "target_error", "max_bytes", "codec", "seed", "fit_texels", "power_iterations",
                 "region", "memory_budget", "domain", "error_domain", "effort")


def add_arguments(p) -> None:
    """The compress command's arguments (also used to parse a scene's build options)."""
    p.add_argument("input", type=Path, help="manifest folder, btf.json, UBO2003/UTIA/ATRIUM zip or folder, or "
                   "Bonn .btf file (UBO2014)")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.add_argument("--solver", default="rsvd", choices=SOLVERS,
                   help="rsvd (default) or paper: the 2003 method as the paper ran it (exact SVD of the central "
                        "quarter-width square, k = 150, 8-bit min-max JPEG coefficients and basis) on the input's "
                        "encoded values (with --domain auto: the input's encoding curve, sRGB for 8-bit sRGB files)")
    p.add_argument("--k", type=int_in(1, 300), help="number of basis vectors, 1..300 (maximum when a target is "
                   "given; default 150)")
    p.add_argument("--target-error", type=float_in(0, 100, lo_open=True), metavar="PCT",
                   help="percent error to reach (the paper's metric, 100 sum|x - x'| / sum x, on held-out texels; "
                        "see --error-domain)")
    p.add_argument("--error-domain", choices=ERROR_DOMAINS, default="encoded",
                   help="what --target-error is measured on: encoded (default: the values in the input's files, "
                        "e.g. the 8-bit sRGB codes -- what a user comparing images sees; for float files the same "
                        "as their linear values) or linear (scene-linear working space)")
    p.add_argument("--max-bytes", type=int_in(1), metavar="B",
                   help="byte budget: every file the packaged asset's full lod loads (see --budget-for)")
    p.add_argument("--budget-for", choices=BUDGET_FOR, default="asset",
                   help="what --max-bytes counts: asset (default: the files `usdbtf package` writes that the "
                        "full lod loads -- coefficient pages, tables, fallback maps, thumbnail, layers) or folder "
                        "(the compressed folder's basis + coefficient textures); --target-error's error is the "
                        "asset's either way, and `usdbtf package` prints the asset's bytes")
    p.add_argument("--codec", choices=sorted(CODEC_NAMES), help=f"texture storage (default {DEFAULT_CODEC['rsvd']}; "
                   f"paper solver: {DEFAULT_CODEC['paper']})")
    p.add_argument("--effort", choices=EFFORTS, default="auto",
                   help="JPEG XL effort: auto (default) quick for a plain --k (effort 2, basis 3: 8x faster, "
                        "~8 %% more bytes), full (effort 7) with --max-bytes or --target-error, where bytes buy "
                        "components; quick or full force one")
    p.add_argument("--domain", type=_domain, default="auto", metavar="auto|linear|srgb|gamma:G",
                   help="working-domain curve the basis is fitted and quantised in; every reader applies its "
                        "inverse after the dot product.  auto (default): chosen per material from linear, "
                        "x^(1/1.6), x^(1/2.2), the sRGB curve and x^(1/3) by the unquantised held-out error of "
                        "each one's basis, "
                        "encoded and scene-linear together (rsvd); the input's own encoding curve for --solver "
                        "paper (sRGB for 8-bit sRGB files: the paper fitted the camera's values); linear for a "
                        "factorised input.  gamma:G is x^(1/G), G in 1..4")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--fit-texels", type=int_in(1, 1 << 26), help="rsvd: texels sampled to fit the basis "
                   "(default 2048; 4096 with --max-bytes or --target-error)")
    p.add_argument("--fit-every-texel", action=argparse.BooleanOptionalAction, default=None,
                   help="rsvd with --max-bytes or --target-error: fit the basis on every texel, in passes "
                   "over the data (default where it applies: the budget modes without --fit-texels; the "
                   "4096-texel sample still chooses the domain and feeds the rate model); "
                   "--no-fit-every-texel fits the sample only (~15 %% less CPU, more error)")
    p.add_argument("--power-iterations", type=int_in(0, 20), default=1, help="rsvd: power iterations (0..20)")
    p.add_argument("--region", type=int_in(1), help="paper: side of the central fitting region in texels")
    p.add_argument("--workers", type=WORKERS, help="decode processes (default: CPU count; with 2 or more, one more "
                   "while a streamed input is spilled to disk, since each waits for its writes)")
    p.add_argument("--memory-budget", type=float_in(0, 1e4), default=1.0, metavar="GB",
                   help="hold the stored values in memory when they and the basis fit's working set fit this "
                        "size, else stream them: decoded once into an anonymous spill file when the temporary folder "
                        "has room, else twice (default 1.0)")
    p.add_argument("--dask", type=parse_address, metavar="ADDRESS", help=ADDRESS_HELP + "; the output is "
                   "byte-identical to a run without --dask")
    p.add_argument("--expand-factors", action="store_true",
                   help="a factorised input (UBO2014 .btf, DFMF/FMF): expand its images and compress those, "
                        "instead of transcoding from the factors (the default)")
    p.add_argument("--factor-rows", type=int_in(1, 1 << 31), metavar="M",
                   help="transcoding a nonlinear colour model (UBO2014's log Y, U/Y, V/Y): samples the "
                        "coefficients are solved on (default 16 k; the number of samples or more = exact)")
    p.add_argument("--coverage", type=Path, metavar="FILE.json",
                   help="keep only the samples whose view and light are both listed in this usdbtf-coverage/1 "
                        "file ({\"format\": \"usdbtf-coverage/1\", \"views\": [[theta, phi], ...], \"lights\": "
                        "[...]}, degrees, directions of the input's own sets): a partial asset that records what it "
                        "covers (what `usdbtf build` writes for a scene)")
    p.add_argument("--max-texels", type=int_in(1, 65536), metavar="N",
                   help="box-filter the images (in scene-linear) by the smallest integer factor that brings the "
                        "larger side to N texels or fewer; the physical size is unchanged")
    add_outside_paths_flag(p)




def _domain(text: str) -> str:
    """argparse type of ``--domain``: the canonical name (auto, linear, srgb, gamma:G)."""
    import argparse

    from ..errors import UsageError
    from .domain import parse_domain

    try:
        dom = parse_domain(text)
    except UsageError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--domain: ")) from None
    return "auto" if dom is None else dom.name
