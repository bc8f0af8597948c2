"""The benchmark's sections: one module each in this package, found at run time.

A section module defines ``SECTION = Section(...)``: its name, a title, an order, the
modules it needs (``requires``; the section is reported *pending* while one is missing, so
a stage that has not landed yet does not break the suite) and ``run(ctx) -> SectionResult``.
A new benchmark (e.g. quilting once :mod:`usdbtf.quilt` exists) is a new module here;
:data:`PLANNED` names the sections the project expects, so the report can list those that
have no module yet.
"""
from __future__ import annotations

import importlib
import importlib.util
import pkgutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

__all__ = ["Section", "SectionResult", "Context", "discover", "PLANNED", "missing_modules"]

# Sections the issue asks for whose stage is built elsewhere: name -> (module, what it measures).
PLANNED = {
    "quilt": ("usdbtf.quilt", "quilting: time vs seam error against m and block size"),
    "render": ("usdbtf.render", "rendering: time vs image error against k"),
}


@dataclass
class Context:
    """What a section gets: the configuration, where to write, how to run and report.

    config : usdbtf.bench.suite.Config.
    out : this run's output folder (the section writes under ``out / name``).
    workdir : dataset cache shared between runs.
    cli : argv prefix of the ``usdbtf`` command.
    say : callable(str) for progress lines.
    """

    config: object
    out: Path
    workdir: Path
    cli: list
    say: Callable[[str], None] = print


@dataclass
class SectionResult:
    """rows + columns: the section's table (also its CSV); tables: markdown blocks (with
    headings) for the report; plots: PNG paths; notes: lines printed under the tables."""

    rows: list = field(default_factory=list)
    csv_keys: list = field(default_factory=list)
    tables: list = field(default_factory=list)
    plots: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Section:
    name: str
    title: str
    order: int
    run: Callable[[Context], SectionResult]
    requires: tuple = ()


def missing_modules(section: Section) -> list:
    """The modules ``section`` requires that cannot be imported here."""
    return [m for m in section.requires if importlib.util.find_spec(m) is None]


def discover() -> dict:
    """name -> Section for every module in this package that defines ``SECTION``, in order."""
    found = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        section = getattr(module, "SECTION", None)
        if isinstance(section, Section):
            found.append(section)
    return {s.name: s for s in sorted(found, key=lambda s: (s.order, s.name))}
