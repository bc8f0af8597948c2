"""Run every UsdValidation validator USD knows on a layer, on every ``lod`` selection.

Nothing here registers anything: the process must know the usdBtf plugin the way any USD
process does (the environment ``usdbtf env`` prints; ``import usdbtf`` applies it to its own
process), so a clean result here is a clean result in a studio's publish gate.
"""
from __future__ import annotations

from pathlib import Path

from ..plugin import SHADER_ID, environment_hint

_SEVERITY_NAMES = ("Error", "Warn", "Info")


def _site(site, fallback: str) -> str:
    if site.IsPrim() or site.IsProperty():
        return str(site.GetPrim().GetPath() if site.IsPrim() else site.GetProperty().GetPath())
    layer = site.GetLayer()
    return str(layer.identifier) if layer else fallback


def stage_issues(stage, *, severities=("Error",), name: str = "") -> list[str]:
    """One line per issue of the given severities ("Error", "Warn", "Info") that any
    registered validator reports for an open stage (as composed now: its variant selections)."""
    from pxr import UsdValidation

    from ...usdstage import usd_warnings_silenced

    with usd_warnings_silenced():   # what USD would print, the validators report below
        validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
        errors = UsdValidation.ValidationContext(validators).Validate(stage)
    lines = []
    materialx = _sdr_knows_materialx()
    for err in errors:
        if err.HasNoError() or str(err.GetType()).rsplit(".", 1)[-1] not in severities:
            continue
        sites = ", ".join(_site(s, name) for s in err.GetSites()) or name
        line = f"[{err.GetIdentifier()}] {sites}: {' '.join(err.GetMessage().split())}"
        if not materialx and "MissingShaderIdInRegistry" in str(err.GetIdentifier()) and "shaderId 'ND_" in line:
            # A USD built without MaterialX (usd-core) has no Sdr entry for any MaterialX
            # node: that says nothing about the asset.  A USD with MaterialX checks them.
            continue
        if "MissingShaderIdInRegistry" in str(err.GetIdentifier()) and SHADER_ID in line:
            line += f" ({SHADER_ID} is unknown to Sdr in this process: {environment_hint()})"
        lines.append(line)
    return lines


def _sdr_knows_materialx() -> bool:
    """Whether this process's Sdr registry holds MaterialX's standard nodes (USD built with MaterialX)."""
    from pxr import Sdr

    return "ND_standard_surface_surfaceshader" in Sdr.Registry().GetShaderNodeIdentifiers()


def validation_issues(path, *, severities=("Error",), lod: str | None = None) -> list[str]:
    """:func:`stage_issues` for the stage rooted at ``path`` (payloads loaded; ``lod``
    selects that variant of every ``lod`` variant set)."""
    from ..read import open_stage

    return stage_issues(open_stage(path, lod=lod), severities=severities, name=Path(str(path)).name)


def lod_selections(stage) -> list[str]:
    """Every variant name of every ``lod`` variant set on ``stage`` (first-seen order)."""
    from ..material import LOD_VARIANT_SET

    names: list[str] = []
    for prim in stage.Traverse():
        if prim.HasVariantSets() and prim.GetVariantSets().HasVariantSet(LOD_VARIANT_SET):
            names += [n for n in prim.GetVariantSets().GetVariantSet(LOD_VARIANT_SET).GetVariantNames()
                      if n not in names]
    return names


def validation_by_lod(path, *, severities=("Error",)) -> dict[str, list[str]]:
    """{selection: issues} for the stage as authored ("" key) and for every ``lod`` selection."""
    from ..read import open_stage

    stage = open_stage(path)
    name = Path(str(path)).name
    report = {"": stage_issues(stage, severities=severities, name=name)}
    for lod in lod_selections(stage):
        # Materials of different k offer different levels: each level where it is offered.
        report[lod] = stage_issues(open_stage(path, lod=lod, where_offered=True), severities=severities, name=name)
    return report


def validate_layer(path) -> list[str]:
    """The errors (not warnings) every validator reports for ``path`` on any ``lod``
    selection; empty when it passes.  Each line names the selection it came from."""
    return [f"{f'lod={lod}: ' if lod else ''}{line}"
            for lod, lines in validation_by_lod(path).items() for line in lines]
