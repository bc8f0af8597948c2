"""``usdbtf build SCENE``: build only the BTF materials a scene actually uses.

A scene names what to build with the BtfMaterialAPI recipe attributes on a Material::

    def Material "Pebbles" (
        prepend apiSchemas = ["BtfMaterialAPI"]
        prepend references = @./build/pebbles.usda@</pebbles/mtl/BtfMaterial>
    )
    {
        uniform asset btf:build:source = @./captures/pebbles@   # measured BTF or compressed folder
        uniform string btf:build:options = "--k 32 --codec png"  # usdbtf compress options
        uniform asset btf:build:asset = @./build/pebbles.usda@   # what `usdbtf package` writes
    }

:func:`plan` composes the scene (payloads loaded, inactive prims and unselected variants
excluded, as USD composes them), computes the material bound to every imageable prim
(all purposes), and keeps the bound materials with a recipe.  Unbound materials are never
looked at again.  :func:`build` writes an SConstruct for those steps (compress, when the
source is not already compressed, then package) and runs SCons with content signatures,
so a second build with unchanged inputs runs nothing.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from ..compress.format import METADATA as COMPRESSED_METADATA
from ..errors import BTFError
from ..manifest import MANIFEST
from .material import NS

BUILD_DIR = ".usdbtf-build"


@dataclass(frozen=True)
class Recipe:
    """What to build for one bound BTF material (absolute paths)."""

    material: str
    source: Path
    options: tuple[str, ...]
    asset: Path

    @property
    def compressed(self) -> Path:
        """The compressed folder package reads: the source itself, or an intermediate."""
        if (self.source / COMPRESSED_METADATA).is_file():
            return self.source
        return self.asset.parent / f"{self.asset.stem}_compressed"


def _anchored(prim, name: str) -> Path | None:
    """Absolute path of an asset attribute, anchored to the layer that authored it
    (outputs do not exist yet, so they cannot be resolved)."""
    from pxr import Sdf

    attr = prim.GetAttribute(NS + name)
    if not attr or not attr.HasAuthoredValue():
        return None
    value = attr.Get()
    for spec in attr.GetPropertyStack():
        if spec.HasDefaultValue():
            return Path(Sdf.ComputeAssetPathRelativeToLayer(spec.layer, value.path))
    return Path(value.path)


def _bound_materials(stage) -> dict[str, list[str]]:
    """{material path: [prims bound to it]} over active, composed, imageable prims."""
    from pxr import UsdGeom, UsdShade

    purposes = (UsdShade.Tokens.allPurpose, UsdShade.Tokens.preview, UsdShade.Tokens.full)
    bound: dict[str, list[str]] = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Imageable):
            continue
        api = UsdShade.MaterialBindingAPI(prim)
        for purpose in purposes:
            material, rel = api.ComputeBoundMaterial(purpose)
            path = material.GetPath() if material else (rel.GetTargets()[0] if rel and rel.GetTargets() else None)
            if path is not None:
                bound.setdefault(str(path), [])
                if str(prim.GetPath()) not in bound[str(path)]:
                    bound[str(path)].append(str(prim.GetPath()))
    return bound


def plan(scene) -> tuple[list[Recipe], dict]:
    """(recipes of bound BTF materials, report) for ``scene``.

    The report lists ``bound`` materials with the prims bound to them and
    ``without_recipe`` (bound materials that have nothing to build)."""
    from .read import open_usd, usd_warnings_silenced

    scene = Path(scene)
    # Composition errors are expected before the first build: the materials reference
    # the assets this builds.
    with usd_warnings_silenced():
        stage = open_usd(scene, composition_errors=False)
    bound = _bound_materials(stage)
    recipes, without = [], []
    for path in sorted(bound):
        prim = stage.GetPrimAtPath(path)
        source = _anchored(prim, "build:source") if prim else None
        if source is None:
            without.append(path)
            continue
        asset = _anchored(prim, "build:asset")
        if asset is None or asset.suffix != ".usda":
            raise BTFError(f"{scene}: {path} has btf:build:source but no btf:build:asset (.usda) to write")
        if not source.exists():
            raise BTFError(f"{scene}: {path}: btf:build:source {source} does not exist")
        options = tuple((prim.GetAttribute(NS + "build:options").Get() or "").split())
        recipes.append(Recipe(path, source, options, asset))
    outputs = [r.asset for r in recipes]
    if len(set(outputs)) != len(outputs):
        raise BTFError(f"{scene}: two materials write the same btf:build:asset")
    return recipes, {"bound": bound, "without_recipe": without}


def _source_files(folder: Path) -> list[str]:
    """Every file of a measured-BTF input: a manifest folder, a UBO folder, a zip."""
    if folder.is_file():
        return [str(folder)]
    return sorted(str(Path(d) / f) for d, _, fs in os.walk(folder) for f in fs if not f.startswith("."))


def sconstruct(recipes: list[Recipe]) -> str:
    """The text of the SConstruct that builds ``recipes`` (targets are index files)."""
    steps = []
    for r in recipes:
        step = {"material": r.material, "asset": str(r.asset), "package_source": str(r.compressed / COMPRESSED_METADATA)}
        if r.compressed != r.source:
            step["compress"] = {"sources": _source_files(r.source), "input": str(r.source),
                                "output": str(r.compressed), "options": list(r.options)}
        else:
            step["compressed_files"] = _source_files(r.source)
        steps.append(step)
    return _SCONSTRUCT.format(python=json.dumps(sys.executable), steps=json.dumps(steps, indent=1))


_SCONSTRUCT = '''# Generated by `usdbtf build`: one compress (when needed) and one package step per
# bound BTF material.  Content signatures: unchanged inputs rebuild nothing.
import json
Decider("content")
SConsignFile(".sconsign")
env = Environment(ENV=dict(__import__("os").environ))
PY = {python}
STEPS = json.loads(r"""{steps}""")
targets = []
for s in STEPS:
    if "compress" in s:
        c = s["compress"]
        compressed = env.Command(s["package_source"], c["sources"],
                                 [[PY, "-m", "usdbtf.cli", "compress", c["input"], "-o", c["output"], "-q"] + c["options"]])
        sources = compressed
    else:
        sources = [s["package_source"]] + s["compressed_files"]
    targets += env.Command(s["asset"], sources,
                           [[PY, "-m", "usdbtf.cli", "package", __import__("os").path.dirname(s["package_source"]),
                             "-o", s["asset"], "-q"]])
Default(targets)
'''


def build(scene, *, log=None) -> dict:
    """Build what ``scene`` needs; returns the report (plan + ``ran``: the commands SCons ran)."""
    log = log or (lambda msg: None)
    scene = Path(scene).resolve()
    recipes, report = plan(scene)
    for path in report["without_recipe"]:
        log(f"{path}: bound, no btf:build recipe (nothing to build)")
    work = scene.parent / BUILD_DIR / scene.stem
    work.mkdir(parents=True, exist_ok=True)
    text = sconstruct(recipes)
    script = work / "SConstruct"
    if not script.is_file() or script.read_text() != text:
        script.write_text(text)
    env = dict(os.environ)
    pipeline = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = pipeline + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, "-m", "SCons", "-Q", "-f", str(script), "-C", str(work)],
                          capture_output=True, text=True, env=env)
    ran = [line for line in proc.stdout.splitlines()
           if "usdbtf.cli" in line and not line.startswith("scons:")]
    if proc.returncode:
        detail = (proc.stderr.strip().splitlines() or proc.stdout.strip().splitlines() or ["?"])
        usdbtf_err = [line for line in detail if line.startswith("usdbtf ")]
        raise BTFError(f"{scene}: build failed: {(usdbtf_err or detail)[-1]}")
    for r in recipes:
        log(f"{r.material}: {r.asset}")
    log(f"{len(recipes)} bound BTF material(s); {len(ran)} step(s) run" + ("" if ran else " (all up to date)"))
    report.update(recipes=recipes, ran=ran)
    return report
