"""``usdbtf bench``: benchmarks of run time against error (see :mod:`usdbtf.bench`)."""
from __future__ import annotations

import sys
from pathlib import Path

ORDER = 90
#: Arguments that name outputs (every other path argument is an input).
OUTPUT_ARGS = ("out",)


def _ints(text: str) -> tuple:
    return tuple(int(x) for x in text.split(",") if x.strip())


def _names(text: str) -> tuple:
    return tuple(x.strip() for x in text.split(",") if x.strip())


# Settings of usdbtf.bench.suite.Config a flag overrides: (flag, Config field, type, help).
OVERRIDES = [
    ("--presets", "presets", _names, "materials, e.g. pebbles,ridged_fabric,fuzzy_moss"),
    ("--sampling", "sampling", str, "compress section's sampling preset (paper, ubo81, small, tiny)"),
    ("--sizes", "sizes", _ints, "compress section's image sizes, e.g. 64,128"),
    ("--solvers", "solvers", _names, "e.g. rsvd,paper"),
    ("--codecs", "codecs", _names, "e.g. jxl,png,exr,jpeg"),
    ("--k", "ks", _ints, "k sweep, e.g. 25,50,150"),
    ("--repeats", "repeats", int, "timed runs per measurement (median quoted)"),
    ("--holdout", "holdout", float, "fraction of light directions held out (0: none)"),
    ("--eval-samples", "eval_samples", int, "samples evaluated per row (0: all)"),
    ("--jpeg-quality", "jpeg_qualities", _ints, "JPEG baseline qualities"),
    ("--pca-view-k", "pca_view_ks", _ints, "per-view PCA: k per view"),
    ("--video-crf", "video_crfs", _ints, "H.265 baseline CRFs"),
    ("--modes-size", "modes_size", int, "modes section: image size (time against error per compress mode)"),
    ("--scaling-sampling", "scaling_sampling", str, "scaling section's sampling preset"),
    ("--scaling-sizes", "scaling_sizes", _ints, "scaling section's image sizes"),
    ("--scaling-views", "scaling_views", _ints, "scaling section's view counts"),
    ("--scaling-k", "scaling_k", int, "scaling section's k"),
    ("--scaling-max-gb", "scaling_max_gb", float, "skip scaling points above this raw size (8-bit, GB)"),
    ("--quilt-size", "quilt_size", int, "quilt section: source size"),
    ("--quilt-out", "quilt_out", int, "quilt section: output size"),
    ("--quilt-m", "quilt_ms", _ints, "quilt section: matched coefficients m"),
    ("--quilt-blocks", "quilt_blocks", _ints, "quilt section: block sizes"),
    ("--render-size", "render_size", int, "render section: image size"),
    ("--render-k", "render_ks", _ints, "render section: k values"),
    ("--seed", "seed", int, "synthetic data and split seed"),
]


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="benchmarks: run time, memory, bytes and error (writes a report, CSV, plots)",
                       description="Run the benchmark suite on synthetic BTFs.  Default: the full configuration "
                                   "(paper sampling, 64^2..512^2; hours).  Flags override single settings.")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_const", const="quick", dest="config",
                      help="small sampling at 64^2: a couple of minutes")
    size.add_argument("--smoke", action="store_const", const="smoke", dest="config",
                      help="tiny sampling at 32^2: seconds (what the tests run)")
    p.add_argument("--sections", type=_names, help="comma-separated sections (default: all; see the report)")
    p.add_argument("-o", "--out", type=Path, help="output folder (default benchmarks/out/bench_<config>_<time>)")
    p.add_argument("--workdir", type=Path, help="dataset cache (default benchmarks/out/data)")
    for flag, dest, kind, text in OVERRIDES:
        p.add_argument(flag, dest=dest, type=kind, help=text)
    p.add_argument("--keep-outputs", action="store_true", default=None, help="keep every stored result")
    p.set_defaults(func=run, config="full")


def outputs(args):
    """The report folder when named (the default has a time stamp, so it is new).  A bench
    run writes it in place as it goes (hours of results are kept if it stops); with
    --force it may write into a previous bench folder."""
    from ..outputs import BENCH
    return [(args.out, BENCH)] if args.out is not None else []


def _command_line(args) -> str:
    """The equivalent ``usdbtf bench`` command (for the report)."""
    parts = ["usdbtf", "bench"] + ([f"--{args.config}"] if args.config != "full" else [])
    for flag, dest, _, _ in OVERRIDES + [("--keep-outputs", "keep_outputs", None, "")]:
        value = getattr(args, dest)
        if value is True:
            parts.append(flag)
        elif value is not None:
            parts += [flag, ",".join(map(str, value)) if isinstance(value, tuple) else str(value)]
    for key in ("sections", "out", "workdir"):
        value = getattr(args, key)
        if value is not None:
            parts += [f"--{key}", ",".join(value) if isinstance(value, tuple) else str(value)]
    return " ".join(parts)


def run(args) -> int:
    from dataclasses import replace

    from ..atomic import output_policy
    from ..bench.suite import config_from, failure_summary, run_suite
    from ..errors import UsageError
    from ..manifest import outside_paths_allowed

    overrides = {dest: getattr(args, dest) for _, dest, _, _ in OVERRIDES}
    cfg = config_from(args.config, keep_outputs=args.keep_outputs, **overrides)
    if args.eval_samples == 0:                   # 0 = every sample
        cfg = replace(cfg, eval_samples=None)
    try:
        # The benchmark's subset manifests name the images of the full datasets beside them,
        # and it rewrites its own intermediate outputs (inside its folders) as it goes.
        with outside_paths_allowed(), output_policy(force=True):
            doc = run_suite(cfg, sections=args.sections, out=args.out, workdir=args.workdir,
                            command=_command_line(args))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if doc["status"] != "ok":
        # A section that fails is a failed measurement (a bug or the machine), not bad input: status 1.
        print(f"usdbtf bench: error: {failure_summary(doc)}", file=sys.stderr)
        return 1
    return 0
