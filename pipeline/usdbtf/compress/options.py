"""What ``compress`` is asked to do: :class:`CompressOptions`, and the defaults that follow from it.

Every choice that depends only on the options is made here, once: the codec a solver
stores with, which quantiser that codec needs, how many basis vectors to fit.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import BTFError, UsageError

__all__ = ["CompressOptions", "SOLVERS", "EFFORTS", "ERROR_DOMAINS", "CODEC_NAMES", "DEFAULT_CODEC", "DEFAULT_K", "BUDGET_K"]

SOLVERS = ("rsvd", "paper")
#: The codecs :mod:`.codecs` defines, by name (here, light, for the command line).
CODEC_NAMES = ("jxlp", "jxl", "png", "exr", "jpeg")
#: Entropy-coder effort settings (``--effort``; see CompressOptions.quick_encode).
EFFORTS = ("auto", "quick", "full")
#: What ``--target-error`` is measured on: the input file's values, or scene-linear.
ERROR_DOMAINS = ("encoded", "linear")
#: What a byte budget (``--max-bytes``) and the bytes ``--target-error`` reports count (issue 39):
#: the packaged asset's full lod (default) or the compressed folder's textures.
BUDGET_FOR = ("asset", "folder")
#: The codec each solver stores with when none is asked for.
DEFAULT_CODEC = {"rsvd": "jxlp", "paper": "jpeg"}
#: Basis vectors kept for a plain run (the paper's 150).
DEFAULT_K = 150
#: With a byte or error target, rate-distortion may keep more components than the paper's
#: 150: low-energy coefficients cost few bits once entropy coded (measured: at the paper's
#: bytes, pebbles 9.1 % error at k <= 150, 8.0 % at k <= 300).  With a working-domain curve and
#: planar files (issue 16) k <= 300 binds on velvet and metallic flakes with bytes to spare at
#: the paper's budget, hence 500 (the research's k_max).
BUDGET_K = 500
#: Under a byte budget, a coefficient channel that needs a few more than 256 levels at the
#: step is stored at a coarser step of its own, up to this factor, so that it fits 8 bits
#: (:func:`.codecs.quantize_uniform`'s ``eight_bit_factor``).  One 16-bit layer makes its
#: whole level of detail's pages 16-bit, which the asset ships as float32 OpenEXR (Storm
#: reads PNG as 8 bits): paper-scale pebbles at the paper's bytes had layer 0 at 264 levels
#: and layer 2 at 261, and its first pages (layers 0..28) weighed 650,606 bytes as EXR
#: against 306,412 as PNG with those two channels' steps 1.031x and 1.020x coarser (0.12 of
#: the budget, for two of 711 planes' quantisation noise up by 6 % and 4 %; issue 43, bench
#: history "Issue 43, eleventh session").  At 2x a channel's noise grows 4x: one plane among
#: the hundreds a budget keeps, against a level's pages at about twice their bytes.
EIGHT_BIT_STEP_FACTOR = 2.0


@dataclass
class CompressOptions:
    """What ``compress`` does.  Units: ``target_error`` percent (paper's metric, on the input's
    encoded values or scene-linear per ``error_domain``),
    ``max_bytes`` bytes of stored textures (basis + coefficients)."""

    solver: str = "rsvd"
    k: int | None = None
    target_error: float | None = None
    max_bytes: int | None = None
    codec: str | None = None              # default: DEFAULT_CODEC[solver]
    seed: int = 0
    fit_texels: int | None = None         # rsvd: texels sampled for the basis fit (default: texels.py)
    fit_every_texel: bool | None = None   # rsvd under a budget: fit the basis on every texel (fit.every_texel);
                                          # None: yes where it applies, False: never, True: refused where it cannot
    power_iterations: int = 1
    oversample: int = 16
    region: int | None = None             # paper: side of the central square region (texels)
    memory_budget: float = 1.0e9          # hold stored values in memory when they and the fit's float32
                                          # columns fit in this many bytes, else stream (select_source)
    chunk_bytes: float = 64e6             # streaming: stored bytes per chunk (rounded to whole projection tiles)
    eval_texels: int = 1024               # held-out texels for error estimates
    workers: int | None = None
    spill: bool = True                    # streaming: decoded values to an anonymous spill file, read back once
    dask: str | None = None               # a Dask scheduler address or "local:N" (usdbtf.cluster.parse_address)
    progress: bool = False                # a progress bar on stderr for long passes (the Dask ones)
    expand_factors: bool = False          # a factorised input (UBO2014 DFMF/FMF): expand its images instead of
                                          # transcoding from the factors (see factored.py)
    factor_rows: int | None = None        # transcoding a nonlinear colour model: samples the coefficients are
                                          # solved on (default: factored.default_rows; >= S: all, exact)
    domain: str = "auto"                  # working-domain curve: auto, linear, srgb, gamma:G (see domain.py)
    error_domain: str = "encoded"         # target_error is on the input file's values ("encoded") or "linear"
    coverage: object = None               # a usdbtf.sampling.Coverage: keep only these views x lights (coverage.py)
    max_texels: int | None = None         # box-filter so the larger side is at most this (coverage.py)
    effort: str = "auto"                  # entropy-coder effort: auto (quick for a plain k, full when bytes are
                                          # asked for), quick or full (see quick_encode)
    budget_for: str = "folder"            # what --max-bytes / --target-error's bytes count: "asset" (every file
                                          # the packaged asset's full lod loads) or "folder" (the compressed
                                          # folder's basis + coefficient textures; before issue 39)
    asset_overhead: object = None         # budget_for "asset": callable(CompressedBTF) -> dict, what packaging
                                          # adds beside the coefficient pages and basis codes (the CLI passes
                                          # usd.asset.package.asset_overhead; without it ratecontrol estimates)
    extra: dict = field(default_factory=dict)

    def validate(self):
        if self.solver not in SOLVERS:
            raise BTFError(f"unknown solver {self.solver!r}; choose from {', '.join(SOLVERS)}")
        if self.k is not None and self.k < 1:
            raise BTFError(f"--k must be at least 1, got {self.k}")
        if self.target_error is not None and not (self.target_error > 0):
            raise BTFError(f"--target-error must be a positive percentage, got {self.target_error}")
        if self.max_bytes is not None and self.max_bytes <= 0:
            raise BTFError(f"--max-bytes must be positive, got {self.max_bytes}")
        if self.dask is not None:
            import argparse

            from ..cluster import parse_address

            try:
                parse_address(self.dask)
            except argparse.ArgumentTypeError as exc:
                raise UsageError(f"--dask: {exc}") from None
        if self.factor_rows is not None and self.factor_rows < 1:
            raise BTFError(f"--factor-rows must be at least 1, got {self.factor_rows}")
        if self.codec_name not in CODEC_NAMES:
            raise BTFError(f"unknown codec {self.codec_name!r}; choose from {', '.join(CODEC_NAMES)}")
        from .domain import parse_domain      # numpy: not at import (--help stays light)
        parse_domain(self.domain)
        if self.fit_every_texel is True and not (self.solver == "rsvd" and self.budgeted and not self.fit_texels):
            raise UsageError("--fit-every-texel needs the rsvd solver with --max-bytes or --target-error, "
                             "and no --fit-texels")
        if self.max_texels is not None and self.max_texels < 1:
            raise BTFError(f"--max-texels must be at least 1, got {self.max_texels}")
        if self.max_texels is not None and self.dask is not None:
            raise UsageError("--max-texels with --dask: the box filter runs in this process; filter without --dask")
        if self.effort not in EFFORTS:
            raise BTFError(f"--effort must be one of {', '.join(EFFORTS)}, got {self.effort!r}")
        if self.budget_for not in BUDGET_FOR:
            raise BTFError(f"--budget-for must be one of {', '.join(BUDGET_FOR)}, got {self.budget_for!r}")
        if self.error_domain not in ERROR_DOMAINS:
            raise BTFError(f"--error-domain must be one of {', '.join(ERROR_DOMAINS)}, got {self.error_domain!r}")

    @property
    def codec_name(self) -> str:
        """The codec the textures are stored with: ``codec``, else the solver's default."""
        return self.codec or DEFAULT_CODEC[self.solver]

    @property
    def quantiser(self) -> str:
        """How coefficients and basis become stored integers (see :mod:`.quantise`):
        "half" for exr, "minmax" (the paper's 8-bit scaling) for the paper solver or jpeg,
        else "uniform" (one step chosen by rate-distortion)."""
        if self.codec_name == "exr":
            return "half"
        if self.solver == "paper" or self.codec_name == "jpeg":
            return "minmax"
        return "uniform"

    @property
    def quick_encode(self) -> bool:
        """Encode at the codec's quick effort (:meth:`.codecs.Codec.quick`): asked for, or
        ``auto`` with a plain k -- no size was asked for, so the 8x faster encode is worth its
        7.5 % more bytes; under ``--max-bytes`` or ``--target-error`` the bytes buy components."""
        return self.effort == "quick" or (self.effort == "auto" and not self.budgeted)

    @property
    def budgeted(self) -> bool:
        """A byte budget or an error target is set (rate control chooses k and the step)."""
        return self.max_bytes is not None or self.target_error is not None

    @property
    def dead_zone(self) -> bool:
        """Round sparse coefficient planes towards zero (:func:`.codecs.uniform_codes`, issue
        39): under ``--max-bytes``, where the bytes it saves buy components (paper-scale probes:
        1-2 % less RMS error at the same shipped bytes; metal_flakes at the paper's bytes 0.772 ->
        0.721 of the paper's encoded error).  ``--target-error`` keeps round-to-nearest: with the
        dead zone the error moved in coarser jumps between the search's choices (32^2 pebbles,
        6 % target: 5.81 % at k 11, 6.03 % at k 10, nothing between), so the search no longer
        landed within its tolerance under the target, spending bytes the target did not need.
        A plain k keeps round-to-nearest too: it asked for no size, and its step was chosen for
        rint's error (:func:`.ratedist.choose_for_k`)."""
        return self.max_bytes is not None and self.quantiser == "uniform"

    @property
    def eight_bit_factor(self) -> float:
        """How much coarser than the step a coefficient channel may be stored so that it fits 8
        bits (:data:`EIGHT_BIT_STEP_FACTOR`, issue 43): under ``--max-bytes``, where one
        16-bit layer turns a level's pages into float32 OpenEXR; 1 (never) otherwise: a plain k
        and ``--target-error`` store every channel at the step they chose it for."""
        return EIGHT_BIT_STEP_FACTOR if self.dead_zone else 1.0

    @property
    def target_k(self) -> int:
        """Components to keep when no budget decides: ``k``, else :data:`DEFAULT_K`."""
        return self.k or DEFAULT_K

    def fit_k(self, n_samples: int, n_pixels: int) -> int:
        """Basis vectors to fit for S samples of P texels: ``k`` (default 150, or 500 for the
        default solver with a budget, see :data:`BUDGET_K`), at most min(S, 3 P)."""
        default = BUDGET_K if self.budgeted and self.solver == "rsvd" else DEFAULT_K
        return min(self.k or default, n_samples, 3 * n_pixels)

    def recorded(self) -> dict:
        """The options as the output's provenance records them: those that steer the result,
        not how or where it was computed (memory budget, chunk size, workers, spill file,
        cluster), which give the same bytes; the factor-input and shaping options only when
        set, so other inputs' records stay as they were (the coverage itself is recorded
        under the metadata's ``coverage`` key, :mod:`.coverage`)."""
        out = {k: v for k, v in self.__dict__.items() if k not in _NOT_RECORDED}
        for key, default in _RECORDED_WHEN_SET.items():
            if out[key] == default:
                del out[key]
        if not self.budgeted:
            del out["budget_for"]             # only a budget or an error target counts bytes
        return out


#: Options that do not change a bit of the output (see :mod:`.projection`).
_NOT_RECORDED = ("extra", "workers", "memory_budget", "chunk_bytes", "spill", "dask", "progress", "coverage",
                 "asset_overhead")
#: Options recorded only when set, with their defaults: those that steer factorised inputs,
#: and the texture side a scene-shaped build asks for.
_RECORDED_WHEN_SET = {"expand_factors": False, "factor_rows": None, "max_texels": None}
