"""The benchmark suite behind ``usdbtf bench``: configurations, and one run over the sections.

A run prints the machine and its inputs, runs each section of :mod:`usdbtf.bench.sections`
(in order; pending ones are listed with the module they wait for) and writes into its
output folder:

``report.md``        machine, configuration, every section's tables, notes and plots;
``<section>.csv``    one row per measurement, full precision;
``<section>/*.png``  plots;
``results.json``     everything above plus the configuration, machine and timings, and
                     ``failures``: per failed section, its error or its first failing row.

Configurations: ``full`` (paper sampling, 64^2..512^2: hours on two cores), ``quick``
(small sampling, 64^2: a couple of minutes) and ``smoke`` (tiny sampling, 32^2: seconds; the
test suite runs it).  Any field can be overridden (``dataclasses.replace``).
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from .machine import format_machine, machine_info
from .measure import cli_command, default_out, timestamp, write_json
from .report import write_csv
from .sections import PLANNED, Context, discover, missing_modules

__all__ = ["Config", "CONFIGS", "run_suite", "describe_row", "failure_summary"]


@dataclass(frozen=True)
class Config:
    """What one benchmark run measures (see :mod:`.sections.compress` and :mod:`.sections.scaling`).

    solver_codecs : explicit (solver, codec) pairs; None = every solver x every codec.
    holdout : fraction of light directions held out of every fit (0 = none).
    scaling_max_gb : skip scaling points whose raw 8-bit size S x P x 3 exceeds this (GB); None = none.
    eval_samples : fitted (and held-out) samples evaluated per row, evenly spread; None = all.
    """

    name: str
    presets: tuple = ("pebbles",)
    sampling: str = "paper"
    sizes: tuple = (64, 128, 256, 512)
    solvers: tuple = ("rsvd", "paper")
    codecs: tuple = ("jxl", "png", "exr", "jpeg")
    solver_codecs: tuple | None = None
    ks: tuple = (25, 50, 100, 150, 300)
    repeats: int = 3
    holdout: float = 0.1
    neighbours: int = 4
    eval_samples: int | None = 1000
    jpeg_qualities: tuple = (90,)
    pca_view_ks: tuple = (2, 4, 8)
    video_crfs: tuple = (20, 28, 36)
    modes_size: int = 128                 # modes section: image size (the paper's 128^2)
    scaling_sampling: str = "paper"
    scaling_sizes: tuple = (64, 128, 256, 512)
    scaling_views: tuple = (10, 30, 90)
    scaling_k: int = 150
    scaling_max_gb: float | None = None
    quilt_size: int = 128
    quilt_out: int = 512
    quilt_k: int = 150
    quilt_ms: tuple = (1, 2, 4, 8, 16, 64)
    quilt_blocks: tuple = (16, 24, 32, 48)
    render_size: int = 128
    render_ks: tuple = (8, 25, 50, 100, 150)
    render_directions: int = 64
    seed: int = 0
    pss_interval: float = 0.2
    keep_outputs: bool = False


CONFIGS = {
    "full": Config("full"),
    "quick": Config("quick", sampling="small", sizes=(64,), ks=(4, 8, 16, 32), repeats=3, holdout=0.15,
                    eval_samples=None, pca_view_ks=(1, 2, 4), video_crfs=(20, 30), modes_size=64, scaling_sampling="small",
                    scaling_sizes=(32, 64, 128), scaling_views=(4, 13), scaling_k=16, quilt_size=64, quilt_out=128,
                    quilt_k=32, quilt_ms=(1, 2, 4, 16), quilt_blocks=(12, 16), render_size=64,
                    render_ks=(4, 8, 16, 32), render_directions=24),
    "smoke": Config("smoke", sampling="tiny", sizes=(32,), solver_codecs=(("rsvd", "jxl"), ("paper", "jpeg")),
                    ks=(2, 4, 8), repeats=1, holdout=0.2, neighbours=3, eval_samples=None, pca_view_ks=(1, 2),
                    video_crfs=(24,), modes_size=32, scaling_sampling="tiny", scaling_sizes=(16, 32), scaling_views=(4,),
                    scaling_k=4, pss_interval=0.1, quilt_size=32, quilt_out=48, quilt_k=8, quilt_ms=(1, 4),
                    quilt_blocks=(8,), render_size=32, render_ks=(2, 8), render_directions=4),
}


def validate(cfg: Config) -> None:
    """Raise ValueError naming the first setting no run could use."""
    from ..compress import SOLVERS
    from ..compress.codecs import CODECS
    from ..sampling import PRESETS as SAMPLINGS
    from ..synth import PRESETS as MATERIALS

    pairs = cfg.solver_codecs or [(s, c) for s in cfg.solvers for c in cfg.codecs]
    checks = [("material", cfg.presets, MATERIALS), ("sampling", (cfg.sampling, cfg.scaling_sampling), SAMPLINGS),
              ("solver", [s for s, _ in pairs], SOLVERS), ("codec", [c for _, c in pairs], CODECS)]
    for what, values, known in checks:
        bad = [v for v in values if v not in known]
        if bad:
            raise ValueError(f"unknown {what} {bad[0]!r}; choose from {', '.join(known)}")
    if not cfg.presets:
        raise ValueError("no material preset given")
    numbers = [("--sizes", cfg.sizes), ("--quilt-blocks", cfg.quilt_blocks), ("--quilt-m", cfg.quilt_ms),
               ("--render-k", cfg.render_ks), ("--scaling-sizes", cfg.scaling_sizes), ("--k", cfg.ks),
               ("--scaling-k", (cfg.scaling_k,)), ("--pca-view-k", cfg.pca_view_ks),
               ("--scaling-views", cfg.scaling_views), ("--repeats", (cfg.repeats,)),
               ("--modes-size", (cfg.modes_size,))]
    for flag, values in numbers:
        if any(v < 1 for v in values):
            raise ValueError(f"{flag} values must be at least 1, got {min(values)}")
    if not 0 <= cfg.holdout < 1:
        raise ValueError(f"--holdout must be in [0, 1), got {cfg.holdout}")


def _describe(cfg: Config) -> list:
    from ..sampling import preset
    from .datasets import split_presets

    tuning, held = split_presets(cfg.presets)
    pairs = (", ".join(f"{s}/{c}" for s, c in cfg.solver_codecs) if cfg.solver_codecs
             else f"{' + '.join(cfg.solvers)} x {' + '.join(cfg.codecs)}")
    return [
        f"- configuration `{cfg.name}`; materials {', '.join(tuning) or '-'} (tuning set), {', '.join(held) or '-'} "
        f"(held-out set: never tuned on) (synthetic, seed {cfg.seed}, 8-bit sRGB PNG)",
        f"- compress: sampling `{cfg.sampling}` ({len(preset(cfg.sampling))} samples), sizes "
        f"{', '.join(f'{s}²' for s in cfg.sizes)}; {pairs}; k {', '.join(map(str, cfg.ks))}; "
        f"{cfg.repeats} timed run(s) each",
        f"- held out: {cfg.holdout:.0%} of the light directions (every view), predicted from the "
        f"{cfg.neighbours} nearest fitted directions; evaluated samples per row: {cfg.eval_samples or 'all'}",
        f"- baselines: JPEG per image q {', '.join(map(str, cfg.jpeg_qualities)) or '-'}; per-view PCA k/view "
        f"{', '.join(map(str, cfg.pca_view_ks)) or '-'}; H.265 video crf {', '.join(map(str, cfg.video_crfs)) or '-'}",
        f"- scaling: sampling `{cfg.scaling_sampling}` first {', '.join(map(str, cfg.scaling_views))} views x sizes "
        f"{', '.join(f'{s}²' for s in cfg.scaling_sizes)}, `usdbtf compress --k {cfg.scaling_k}`"
        + (f"; points above {cfg.scaling_max_gb:g} GB raw skipped" if cfg.scaling_max_gb else ""),
        f"- quilt: {cfg.quilt_size}² source (k {cfg.quilt_k}) to {cfg.quilt_out}², blocks "
        f"{', '.join(map(str, cfg.quilt_blocks))}, m {', '.join(map(str, cfg.quilt_ms))}",
        f"- render: {cfg.render_size}² swatches, k {', '.join(map(str, cfg.render_ks))}, up to "
        f"{cfg.render_directions} fitted + held-out directions",
    ]


def _rel(path: Path, base: Path) -> str:
    try:
        return str(Path(path).relative_to(base))
    except ValueError:
        return str(path)


# Row fields that say which measurement a row is, in the order a reader names them (each
# section's rows carry some of them; ``param_name``/``param`` follow as "<name> <value>").
_ROW_IDENTITY = ("preset", "sampling", "size", "samples", "mode", "method", "directions", "block", "m", "k")


def describe_row(row: dict) -> str:
    """Which measurement ``row`` is, e.g. "preset pebbles, sampling small, size 64, method
    pca-view/jxl, k per view 1"."""
    parts = [f"{key} {row[key]}" for key in _ROW_IDENTITY if row.get(key) not in (None, "")]
    if row.get("param_name"):
        parts.append(f"{row['param_name']} {row.get('param')}")
    return ", ".join(parts) or "?"


def _failed(row: dict) -> bool:
    return str(row.get("status", "ok")).startswith("failed")


def failure_summary(doc: dict) -> str:
    """One line for a failed run's results document: the report, the failed sections, and
    the first failure (its section, and its error or its first failing row)."""
    failures = doc.get("failures") or {}
    names = ", ".join(failures) or "?"
    first = next(iter(failures.items()), None)
    detail = f"; first: {first[0]}: {first[1]}" if first else ""
    return " ".join(f"{doc.get('out')}/report.md: section(s) {names} failed{detail}".split())


def run_suite(cfg: Config, *, sections=None, out: Path | None = None, workdir: Path | None = None,
              command: str = "", say=print) -> dict:
    """Run the sections named in ``sections`` (default: all available) and write the report.

    Returns the results document (also written as ``results.json``); its "status" is "ok",
    or "failed" when a measurement failed or a section raised; "failures" then maps each
    failed section to its error or to its first failing row and that row's status.
    """
    validate(cfg)
    t_start = time.perf_counter()
    stamp = timestamp()
    out = Path(out or default_out() / f"bench_{cfg.name}_{stamp}").resolve()
    workdir = Path(workdir or default_out() / "data").resolve()
    out.mkdir(parents=True, exist_ok=True)
    available = discover()
    wanted = list(sections or list(available) + [n for n in PLANNED if n not in available])
    unknown = [n for n in wanted if n not in available and n not in PLANNED]
    if unknown:
        raise ValueError(f"unknown benchmark section(s) {unknown}; known: {', '.join([*available, *PLANNED])}")

    machine = machine_info()
    say(f"# usdbtf bench `{cfg.name}` ({stamp})")
    say(f"command: {command or ' '.join(sys.argv)}")
    say("\n## machine\n" + format_machine(machine))
    say("\n## inputs\n" + "\n".join(_describe(cfg)))
    doc = {"benchmark": "usdbtf bench", "timestamp": stamp, "command": command, "config": asdict(cfg),
           "machine": machine, "out": str(out), "sections": {}, "pending": {}}
    ctx = Context(config=cfg, out=out, workdir=workdir, cli=cli_command(), say=say)
    report = [f"# usdbtf bench `{cfg.name}`, {stamp}", "", f"`{command}`" if command else "", "", "## machine", "",
              format_machine(machine), "", "## inputs", "", *_describe(cfg)]
    failures = {}
    for name in wanted:
        section = available.get(name)
        missing = missing_modules(section) if section else [PLANNED[name][0]]
        if missing:
            why = (f"pending: module {', '.join(missing)} not present"
                   + (f" ({PLANNED[name][1]})" if name in PLANNED else ""))
            doc["pending"][name] = why
            say(f"\n## {name}: {why}")
            continue
        t = time.perf_counter()
        try:
            res = section.run(ctx)
        except Exception as exc:  # noqa: BLE001 - one broken section must not lose the others' results
            failures[name] = f"{type(exc).__name__}: {exc}"
            doc["sections"][name] = {"error": failures[name]}
            say(f"\n## {name}: FAILED: {type(exc).__name__}: {exc}")
            continue
        seconds = time.perf_counter() - t
        bad = next((r for r in res.rows if _failed(r)), None)
        if bad is not None:
            failures[name] = f"{describe_row(bad)}: {bad['status']}"
        csv_path = write_csv(res.rows, out / f"{name}.csv", res.csv_keys)
        doc["sections"][name] = {"title": section.title, "rows": res.rows, "summary": res.summary,
                                 "csv": str(csv_path), "plots": [str(p) for p in res.plots], "seconds": seconds}
        report += ["", f"## {section.title}", ""]
        for table in res.tables:
            report += [table, ""]
        report += [f"- {n}" for n in res.notes]
        report += [f"- table: `{_rel(csv_path, out)}`"] + [f"- plot: `{_rel(p, out)}`" for p in res.plots]
        report.append(f"- section time: {seconds:.1f} s")
    if doc["pending"]:
        report += ["", "## pending sections", ""] + [f"- `{n}`: {why}" for n, why in doc["pending"].items()]
    if failures:
        report += ["", "## failures", ""] + [f"- `{n}`: {why}" for n, why in failures.items()]
    doc["failures"] = failures
    doc["status"] = "failed" if failures else "ok"
    doc["total_seconds"] = time.perf_counter() - t_start
    doc["load_average_at_end"] = list(os.getloadavg())
    report += ["", f"total: {doc['total_seconds']:.1f} s; load average at end: "
               + ", ".join(f"{x:.2f}" for x in doc["load_average_at_end"]) + f"; status {doc['status']}"]
    text = "\n".join(report).replace("\n\n\n", "\n\n") + "\n"
    (out / "report.md").write_text(text)
    write_json(out / "results.json", doc)
    say("\n" + "=" * 100 + "\n" + text)
    say(f"report: {out / 'report.md'}")
    return doc


def config_from(name: str, **overrides) -> Config:
    """A named configuration with the non-None ``overrides`` applied (explicit solvers or
    codecs replace the configuration's solver/codec pairs by their cross product)."""
    given = {k: v for k, v in overrides.items() if v is not None}
    if "solvers" in given or "codecs" in given:
        given.setdefault("solver_codecs", None)
    return replace(CONFIGS[name], **given)
