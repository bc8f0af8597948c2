"""Run every UsdValidation validator USD knows on a layer."""
from __future__ import annotations

from pathlib import Path


def validation_issues(path, *, severities=("Error",)) -> list[str]:
    """One line per issue of the given severities ("Error", "Warn", "Info") that any
    registered validator reports for the stage rooted at ``path`` (payloads loaded)."""
    from pxr import UsdValidation

    from .read import open_usd, usd_warnings_silenced
    from .storm import register_shader_definitions

    register_shader_definitions()   # so ShaderSdrCompliance knows the plugin's UsdBtfSurface

    with usd_warnings_silenced():   # what USD would print, the validators report below
        stage = open_usd(path, composition_errors=False)
        validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
        errors = UsdValidation.ValidationContext(validators).Validate(stage)
    lines = []
    for err in errors:
        if err.HasNoError() or str(err.GetType()).rsplit(".", 1)[-1] not in severities:
            continue
        sites = ", ".join(str(s.GetPrim().GetPath()) if s.IsPrim() else str(s.GetLayer().identifier if s.GetLayer() else "")
                          for s in err.GetSites()) or Path(path).name
        lines.append(f"[{err.GetIdentifier()}] {sites}: {' '.join(err.GetMessage().split())}")
    return lines


def validate_layer(path) -> list[str]:
    """The errors (not warnings) every validator reports for ``path``; empty when it passes."""
    return validation_issues(path)
