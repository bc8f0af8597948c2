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
so a second build with unchanged inputs runs nothing.  Every ``Mesh`` prim bound to a recipe's
material also gets an unwrap, quilt and package step (:mod:`usdbtf.usd.scenes.binding`), and the
built stage composes the results over the user's scene: ``SCENE.built.usda`` beside the scene
(``usdbtf build -o PATH``: elsewhere), a visible file next to the one the user opens, since it is
the product; the build folder ``.usdbtf-build/SCENE/`` keeps only intermediates and the record
``built_stage.json`` that names it (``usdbtf inspect --validate SCENE`` reports it).  The built
stage is written atomically; an existing file there is replaced only when it is the built stage
of a previous build of this scene (named in that record), or, with ``--force``, another usdbtf
built stage.

SCons runs independent steps at once (``jobs``; ``usdbtf build --jobs``, default the CPU count):
each step is its own ``usdbtf`` process writing its own outputs, so the bytes do not depend on
the order or the parallelism.

Scene text is data, never code:

* ``btf:build:options`` is split with :mod:`shlex` and parsed by the compress command's own
  argument parser; only the options in :data:`usdbtf.compress.arguments.SCENE_OPTIONS`
  are allowed, and what reaches the command line is rebuilt from the parsed, typed values.
  Anything else is an error naming the prim and the attribute.
* The SConstruct is fixed text; the steps (paths, options) are in ``steps.json`` beside it.
  SCons nodes are made from the raw paths without substitution, and every step is a Python
  function action that runs ``usdbtf`` with an argument list (no shell, no ``$`` expansion).
* Outputs are never the scene (or a layer of its layer stack), never inside or around a
  source, and are marked precious so SCons never deletes them before a rebuild: a failed
  rebuild keeps the last good compressed folder and asset (each is replaced only when the
  new one is complete).  An existing output this build did not write before is refused
  unless ``--force`` (and even then only a usdbtf output of the same kind is replaced).
"""
from __future__ import annotations

import logging
import argparse
import contextlib
import hashlib
import json
import os
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from ... import numeric
from ...atomic import atomic_file, related, tidy_owned
from ...compress.format import METADATA as COMPRESSED_METADATA
from ...errors import BTFError, OutputRefused, error_for_status
from ...lifetime import child_environment, guarded_module_argv
from ..material import NS

log = logging.getLogger(__name__)

__all__ = ["Recipe", "plan", "build", "sconstruct", "parse_options", "BUILD_DIR", "built_stage_path",
           "superseding_stage", "STAGE_RECORD"]

BUILD_DIR = ".usdbtf-build"
_STEPS = "steps.json"
_FAILURE = "failure.json"
_OWNED = "outputs.json"
_TIMES = "step_times.jsonl"
_FULL_RECORD = "full_build.json"
#: The build folder's record of the built stage: {"built_stage": its path relative to the folder}.
STAGE_RECORD = "built_stage.json"
# Where builds before issue 41 wrote the built stage (inside the hidden build folder); a build
# removes it, so that no stale copy is left to open.
_OLD_BUILT_STAGE = "scene.usda"
#: Suffixes the built stage may have (text, crate, either).
STAGE_SUFFIXES = (".usda", ".usdc", ".usd")


@dataclass(frozen=True)
class Recipe:
    """What to build for one bound BTF material (absolute paths; ``options`` is the
    checked, canonical compress argument list; ``shape`` the compress arguments the scene's
    needs add (:mod:`usdbtf.usd.scenes.plan`: ``--coverage``, ``--max-texels``, ``--target-error``),
    ``requirements`` those needs as canonical JSON, part of the compress step's signature;
    ``stand_in``: the scene never shows it, so it is built as a one-direction stand-in that
    keeps the scene's reference valid, and its meshes get no atlas or quilt)."""

    material: str
    source: Path
    options: tuple[str, ...]
    asset: Path
    shape: tuple[str, ...] = ()
    requirements: str = ""
    stand_in: bool = False

    @property
    def compressed(self) -> Path:
        """The compressed folder package reads: the source itself, or an intermediate."""
        if (self.source / COMPRESSED_METADATA).is_file():
            return self.source
        return self.asset.parent / f"{self.asset.stem}_compressed"

    def outputs(self) -> list[Path]:
        """Every path this recipe writes (the intermediate compressed folder, the asset's pieces)."""
        from ..asset.package import asset_pieces

        pieces = [self.asset.parent / name for name, _, _ in asset_pieces(self.asset)]
        return ([self.compressed] if self.compressed != self.source else []) + pieces


class _OptionsParser(argparse.ArgumentParser):
    def error(self, message):
        raise _BadOptions(" ".join(str(message).split()))


class _BadOptions(Exception):
    pass


def parse_options(text, where: str) -> tuple[str, ...]:
    """``btf:build:options`` -> the canonical compress argument list, or BTFError naming ``where``.

    Split like a shell would (quotes, no expansion), parsed by the compress command's
    parser, restricted to :data:`~usdbtf.compress.arguments.SCENE_OPTIONS`, and rebuilt
    from the typed values, so nothing of the original text reaches a command line."""
    from ...compress.arguments import SCENE_OPTIONS, add_arguments

    if text is None:
        return ()
    if not isinstance(text, str):
        raise BTFError(f"{where}: must be a string of usdbtf compress options, got {type(text).__name__}")
    try:
        tokens = shlex.split(text, comments=False, posix=True)
    except ValueError as exc:
        raise BTFError(f"{where}: cannot split {text!r}: {exc}") from None
    parser = _OptionsParser(prog="btf:build:options", add_help=False, allow_abbrev=False)
    add_arguments(parser)
    base = ["input", "-o", "output"]
    try:
        defaults = parser.parse_args(base)
        parsed = parser.parse_args(base + tokens)
    except _BadOptions as exc:
        raise BTFError(f"{where}: {exc} (in {text!r})") from None
    flags = {a.dest: a.option_strings[-1] for a in parser._actions if a.option_strings}
    out = []
    for dest, value in vars(parsed).items():
        if value == getattr(defaults, dest, None):
            continue
        if dest not in SCENE_OPTIONS:
            name = flags.get(dest, dest)
            raise BTFError(f"{where}: {name} is not allowed in a scene (allowed: "
                           f"{', '.join(flags[d] for d in SCENE_OPTIONS)})")
        out += [flags[dest], repr(value) if isinstance(value, float) else str(value)]
    return tuple(out)


def _anchored(prim, name: str) -> Path | None:
    """Absolute path of an asset attribute, anchored to the layer that authored it
    (outputs do not exist yet, so they cannot be resolved)."""
    from pxr import Sdf

    attr = prim.GetAttribute(NS + name)
    if not attr or not attr.HasAuthoredValue():
        return None
    value = attr.Get()
    if not isinstance(value, Sdf.AssetPath) or not value.path or "\0" in value.path:
        raise BTFError(f"{prim.GetPath()}: {NS}{name} must be an asset path, got {value!r}")
    for spec in attr.GetPropertyStack():
        if spec.HasDefaultValue():
            return Path(os.path.abspath(Sdf.ComputeAssetPathRelativeToLayer(spec.layer, value.path)))
    return Path(os.path.abspath(value.path))


def _bound_materials(stage) -> dict[str, list[str]]:
    """{material path: [prims bound to it]} over active, composed, imageable prims."""
    from pxr import Usd, UsdGeom, UsdShade

    purposes = (UsdShade.Tokens.allPurpose, UsdShade.Tokens.preview, UsdShade.Tokens.full)
    bound: dict[str, list[str]] = {}
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):       # instanced meshes bind too
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


def _check_outputs(scene: Path, path: str, recipe: Recipe, protected: list[Path]) -> None:
    """The recipe's outputs must leave the scene's layers and the source alone."""
    for out in recipe.outputs():
        for p in protected:
            rel = related(out, p)
            if rel:
                raise OutputRefused(f"{scene}: {path}: {NS}build:asset: {out} {rel} {p}, a layer of the scene "
                                    "being built; choose another asset path")
        if out != recipe.source:
            rel = related(out, recipe.source)
            if rel:
                raise OutputRefused(f"{scene}: {path}: {NS}build:asset: {out} {rel} the source {recipe.source}; "
                                    "choose another asset path")


def plan(scene, *, source_facts=None, target_error: float | None = None) -> tuple[list[Recipe], dict]:
    """(recipes of bound BTF materials, report) for ``scene``.

    The report lists ``bound`` materials with the prims bound to them and
    ``without_recipe`` (bound materials that have nothing to build).

    source_facts : a callable, source path -> :class:`usdbtf.usd.scenes.plan.MaterialFacts`: shape the
        build by the scene (:mod:`usdbtf.usd.scenes.plan`): materials the scene never shows are left
        out (``report["skipped"]``; one whose source has measured directions is built as a
        one-direction, k = 1 stand-in instead, ``report["stand_ins"]``, so that the scene's
        reference to its asset resolves), the others compress only what the scene needs
        (``report["needs"]``: {material: Need}).  None: everything bound, in full (``--full``).
    target_error : the screen-space percent error target (shaped builds)."""
    from ...usdstage import composition_cycle, composition_error_text, open_usd, usd_warnings_silenced
    from ..asset.package import ROOT_FORMATS

    scene = Path(scene)
    # Composition errors are expected before the first build: the materials reference
    # the assets this builds.
    with usd_warnings_silenced():
        stage = open_usd(scene, composition_errors=False)
    # A cycle is never expected: the layers on it compose nothing, so the scene would seem to
    # bind no material at all.
    cycle = composition_cycle(stage)
    if cycle is not None:
        raise BTFError(f"{scene}: composition error: {composition_error_text(cycle)}")
    protected = [Path(layer.realPath) for layer in stage.GetLayerStack(includeSessionLayers=False)
                 if layer.realPath] + [scene]
    bound = _bound_materials(stage)
    recipes, without = [], []
    for path in sorted(bound):
        prim = stage.GetPrimAtPath(path)
        source = _anchored(prim, "build:source") if prim else None
        if source is None:
            without.append(path)
            continue
        asset = _anchored(prim, "build:asset")
        if asset is None or asset.suffix not in ROOT_FORMATS:
            raise BTFError(f"{scene}: {path} has btf:build:source but no btf:build:asset "
                           f"({'/'.join(ROOT_FORMATS)}) to write")
        if not source.exists():
            raise BTFError(f"{scene}: {path}: btf:build:source {source} does not exist")
        attr = prim.GetAttribute(NS + "build:options")
        options = parse_options(attr.Get() if attr else None, f"{scene}: {path}: {NS}build:options")
        recipe = Recipe(path, source, options, asset)
        _check_outputs(scene, path, recipe, protected)
        recipes.append(recipe)
    outputs = [o for r in recipes for o in r.outputs()]
    if len(set(outputs)) != len(outputs):
        raise BTFError(f"{scene}: two materials write the same btf:build:asset")
    report = {"bound": bound, "without_recipe": without, "shaped": source_facts is not None, "layers": protected}
    if source_facts is not None:
        with usd_warnings_silenced():   # the materials' assets are not built yet (see above)
            recipes, report["needs"], report["skipped"] = _shaped(stage, scene, recipes, bound, source_facts,
                                                                  target_error)
    from .binding import binding_targets, bindings

    if source_facts is not None:
        report["stand_ins"] = [r.material for r in recipes if r.stand_in]
    shown = [r for r in recipes if not r.stand_in]      # a stand-in's meshes are never seen: no atlas, no quilt
    chains = bindings(stage, shown, binding_targets(stage, [r.material for r in shown]), work_folder(scene))
    report["bindings"] = chains
    return recipes, report


def _shaped(stage, scene: Path, recipes: list[Recipe], bound: dict, source_facts, target_error):
    """(the recipes of the materials the scene needs, with the compress arguments that shape
    them; {material: Need}; [materials left out])."""
    from dataclasses import replace

    from .plan import analyse

    facts = {r.material: _facts(source_facts, r) for r in recipes}
    needs = analyse(stage, {r.material: bound[r.material] for r in recipes}, facts, target_error=target_error)
    kept, skipped = [], []
    for r in recipes:
        need = needs[r.material]
        if not need.needed and not need.stand_in:
            log.info(f"{r.material}: not built: {need.why_not}")
            skipped.append(r.material)
            continue
        shape, options = [], list(r.options)
        if need.stand_in:
            log.info(f"{r.material}: a stand-in only (one view and one light, k = 1): {need.why_not}")
            options = _without_rate_options(options) + ["--k", "1"]
        if need.coverage() is not None:
            shape += ["--coverage", str(coverage_path(scene, r))]
        if need.max_texels is not None:
            shape += ["--max-texels", str(need.max_texels)]
        requirements = need.requirements()
        target = need.target_error if need.full is None and not need.stand_in else None
        if target is not None and "--target-error" in options:
            at = options.index("--target-error")
            if float(options[at + 1]) <= target:
                target = None                 # the recipe's own target is the stricter one
            else:
                del options[at:at + 2]
        if target is not None:
            shape += ["--target-error", repr(float(target))]
        requirements["target_error"] = target
        kept.append(replace(r, options=tuple(options), shape=tuple(shape), stand_in=need.stand_in,
                            # Nothing shaped is the full build: the same signature, nothing to rebuild.
                            requirements=json.dumps(requirements, sort_keys=True) if shape else ""))
    return kept, needs, skipped


def _without_rate_options(options: list[str]) -> list[str]:
    """``options`` without what sets k or the error/byte target (each is a flag and its value:
    the canonical list :func:`parse_options` makes)."""
    out, skip = [], False
    for item in options:
        if skip:
            skip = False
        elif item in _RATE_OPTIONS:
            skip = True
        else:
            out.append(item)
    return out


_RATE_OPTIONS = ("--k", "--target-error", "--max-bytes", "--error-domain")


def _facts(source_facts, recipe: Recipe):
    """The plan's facts of ``recipe``'s source; one it cannot read is built whole (its compress
    step then says what is wrong with it, as a build always did)."""
    import numpy as np

    from .plan import MaterialFacts

    try:
        return source_facts(recipe.source)
    except BTFError as exc:
        return MaterialFacts(np.zeros((0, 2)), np.zeros((0, 2)), 1, 1, None,
                             whole=f"its source could not be read for the plan ({exc}): built whole")


def coverage_path(scene: Path, recipe: Recipe) -> Path:
    """Where the build writes the coverage document of ``recipe``'s material."""
    digest = hashlib.sha256(recipe.material.encode()).hexdigest()[:10]
    return work_folder(Path(os.path.abspath(scene))) / "materials" / f"{recipe.asset.stem}_{digest}" / "coverage.json"


def built_stage_path(scene) -> Path:
    """The default built stage of ``scene``: ``SCENE.built.usda`` beside it (``scene.usda`` ->
    ``scene.built.usda``), listed next to the file the user opens."""
    scene = Path(scene)
    return scene.with_name(f"{scene.stem}.built.usda")


def _recorded_stage(work: Path) -> Path | None:
    """The built stage the build folder ``work`` records (absolute), or None."""
    try:
        doc = json.loads((work / STAGE_RECORD).read_text())
    except (OSError, ValueError):
        return None
    name = doc.get("built_stage") if isinstance(doc, dict) else None
    return Path(os.path.normpath(work / name)) if isinstance(name, str) and name and "\0" not in name else None


def superseding_stage(scene) -> Path | None:
    """The built stage that supersedes the user's ``scene`` (a local file): the one its last
    build recorded (:data:`STAGE_RECORD` in its build folder), when it is still there and still
    a usdbtf built stage; None otherwise (never built, or a stage or path the resolver names)."""
    from ...outputs import BUILT_STAGE, is_kind

    try:
        scene = Path(scene)
        if not scene.is_file():
            return None
        stage = _recorded_stage(work_folder(Path(os.path.abspath(scene))))
    except (OSError, ValueError):
        return None
    return stage if stage is not None and is_kind(stage, BUILT_STAGE) else None


def work_folder(scene: Path) -> Path:
    """The build folder of ``scene``: SConstruct, steps, the bound meshes' chains, the built scene."""
    return Path(scene).parent / BUILD_DIR / Path(scene).stem


def _source_files(folder: Path) -> list[str]:
    """Every file of a measured-BTF input: a manifest folder, a UBO folder, a zip."""
    if folder.is_file():
        return [str(folder)]
    return sorted(str(Path(d) / f) for d, _, fs in os.walk(folder) for f in fs if not f.startswith("."))


def steps(recipes: list[Recipe], dask: dict | None = None, chains: list | None = None) -> dict:
    """The data the SConstruct builds from: one compress (when needed) and one package step
    per recipe, each with its targets, sources and ``usdbtf`` argument list, then the
    unwrap, quilt and package ``commands`` of every bound mesh's chain
    (:mod:`usdbtf.usd.scenes.binding`); with ``dask`` (:func:`_cluster_info`) the steps run as tasks
    on that cluster."""
    from .binding import binding_steps

    out = []
    for r in recipes:
        step = {"material": r.material, "asset": str(r.asset),
                "package_source": str(r.compressed / COMPRESSED_METADATA),
                "package": ["package", "--force", "-q", "-o", str(r.asset), "--", str(r.compressed)]}
        if r.compressed != r.source:
            coverage = [r.shape[r.shape.index("--coverage") + 1]] if "--coverage" in r.shape else []
            step["compress"] = {"sources": _source_files(r.source) + coverage, "requirements": r.requirements,
                                "argv": ["compress", "--force", "-q", *r.options, *r.shape, "-o", str(r.compressed),
                                         "--", str(r.source)]}
        else:
            step["compressed_files"] = _source_files(r.source)
        out.append(step)
    # The numeric platform decides the bits of every step's output (usdbtf.numeric): a build
    # cached on one platform is not another's, so it enters every step's signature.
    compressed = {r.material: (str(r.compressed / COMPRESSED_METADATA),
                               [] if r.compressed != r.source else _source_files(r.source)) for r in recipes}
    doc = {"python": sys.executable, "failure": _FAILURE, "times": _TIMES, "steps": out, "platform": numeric.platform(),
           "commands": binding_steps(chains or [], compressed)}
    if dask is not None:
        doc["dask"] = dask
    return doc


def sconstruct(recipes: list[Recipe] | None = None) -> str:
    """The SConstruct text: fixed, whatever the scene says (the steps are data in steps.json)."""
    return _SCONSTRUCT


_SCONSTRUCT = '''# Generated by `usdbtf build`: one compress (when needed) and one package step per bound
# BTF material, read from steps.json.  Content signatures: unchanged inputs rebuild nothing.
# Scene data never becomes code or a command line here: nodes are made from the raw paths
# (no $ substitution) and each step is a Python function running usdbtf with an argument list.
import json
import os
import subprocess
import sys
import time

Decider("content")
SConsignFile(".sconsign")
env = Environment(tools=[], ENV={})
HERE = os.getcwd()
with open(os.path.join(HERE, "steps.json")) as fh:
    DATA = json.load(fh)


def node(path):
    return env.fs.File(path)


def usdbtf_step(argv, label):
    def run_step(target, source, env):
        start = time.time()
        if "dask" in DATA:       # a task on the cluster (usdbtf build --dask)
            from usdbtf.cluster import run_command

            status, stderr = run_command(DATA["dask"], argv, label)
        else:
            res = subprocess.run([DATA["python"], "-m", "usdbtf.cli", *argv], stdin=subprocess.DEVNULL,
                                 capture_output=True, text=True)
            status, stderr = res.returncode, res.stderr
        if status:
            lines = [x for x in stderr.splitlines() if x.startswith("usdbtf ")] or \\
                stderr.strip().splitlines() or ["exit status %d" % status]
            with open(os.path.join(HERE, DATA["failure"]), "w") as out:
                json.dump({"status": status, "message": lines[-1]}, out)
            sys.stderr.write(stderr)
        with open(os.path.join(HERE, DATA["times"]), "a") as out:   # the build's report reads it
            out.write(json.dumps({"label": label, "seconds": time.time() - start}) + "\\n")
        return status

    return Action(run_step, strfunction=lambda target, source, env: label)


# The numeric platform (BLAS kernel, numpy SIMD level) decides the bits: part of every signature.
PLATFORM = env.Value(json.dumps(DATA.get("platform", {}), sort_keys=True))
targets = []
for s in DATA["steps"]:
    if "compress" in s:
        c = s["compress"]
        # What the scene needs of the material (directions, resolution, error): its signature too.
        needs = [env.Value(c["requirements"])] if c.get("requirements") else []
        sources = env.Command(node(s["package_source"]), [node(p) for p in c["sources"]] + [PLATFORM] + needs,
                              usdbtf_step(c["argv"], "usdbtf-step compress " + json.dumps(s["material"])))
    else:
        sources = [node(s["package_source"])] + [node(p) for p in s["compressed_files"]]
    targets += sources if "compress" in s else []
    targets += env.Command(node(s["asset"]), list(sources) + [PLATFORM],
                           usdbtf_step(s["package"], "usdbtf-step package " + json.dumps(s["material"])))
for c in DATA.get("commands", []):     # the bound meshes' unwrap, quilt and package steps
    targets += env.Command([node(p) for p in c["targets"]], [node(p) for p in c["sources"]] + [PLATFORM],
                           usdbtf_step(c["argv"], "usdbtf-step " + c["label"]))
env.Precious(targets)    # never deleted before a rebuild: a failed one keeps the last good build
env.NoClean(targets)
Default(targets)
'''


def _owned(work: Path) -> set[str]:
    try:
        doc = json.loads((work / _OWNED).read_text())
    except (OSError, ValueError):
        return set()
    return {p for p in doc if isinstance(p, str)} if isinstance(doc, list) else set()


def _claim_outputs(scene: Path, recipes: list[Recipe], work: Path, force: bool) -> None:
    """Refuse outputs that exist but this build did not write (unless ``force``), then
    record every output as this build's."""
    owned = _owned(work)
    mine = []
    for r in recipes:
        for out in r.outputs():
            if os.path.lexists(out) and str(out) not in owned and not force:
                raise OutputRefused(f"{scene}: {r.material}: {out} exists and was not written by a build of this "
                                    "scene; pass --force to replace it (if it is a usdbtf output of the same kind)")
            mine.append(str(out))
    work.mkdir(parents=True, exist_ok=True)
    with atomic_file(work / _OWNED, owner_checked=True) as tmp:
        tmp.write_text(json.dumps(sorted(owned | set(mine)), indent=1) + "\n")


def build(scene, *, force: bool = False, dask=None, source_facts=None, target_error: float | None = None,
          output=None, jobs: int | None = None) -> dict:
    """Build what ``scene`` needs; returns the report (plan + ``ran``: the steps SCons ran,
    ``times``: {step label: seconds}, ``built_scene``: the built stage's path when the scene
    binds meshes to a recipe's material).

    output : the built stage to write (None: :func:`built_stage_path`, ``SCENE.built.usda``
        beside the scene); .usda, .usdc or .usd.
    jobs : how many steps SCons runs at once (None: the CPUs this process may use; with
        ``dask``, the cluster's threads); the outputs are the same whatever it is.
    force : replace existing outputs this build did not write before (only usdbtf outputs
        of the same kind; see the module docstring).
    source_facts, target_error : shape the build by the scene (:func:`plan`); without
        ``source_facts`` every bound material is built in full.
    dask : a cluster address (:func:`usdbtf.cluster.parse_address`): the steps run as Dask
        tasks there, as many at once as it has threads (each runs ``usdbtf`` on a worker,
        which must read and write the same paths); the outputs are the same."""
    scene = Path(scene).resolve()
    recipes, report = plan(scene, source_facts=source_facts, target_error=target_error)
    report["times"] = {}
    for path in report["without_recipe"]:
        log.info(f"{path}: bound, no btf:build recipe (nothing to build)")
    if not recipes:
        log.info(f"{len(report['bound'])} bound BTF material(s), none with a btf:build recipe: nothing to build")
        report.update(recipes=recipes, ran=[], costs={m: {"bytes": 0, "seconds": 0.0, "full_bytes": None,
                                                          "full_seconds": None} for m in report.get("skipped", [])})
        return report
    work = work_folder(scene)
    stage_out = Path(os.path.abspath(output)) if output is not None else built_stage_path(scene)
    if report["bindings"]:              # refused before anything runs
        _check_stage_output(scene, stage_out, recipes, report, work, force)
    elif output is not None:
        log.warning(f"{scene}: no mesh is bound to a material with a recipe, so there is no built stage to write "
                    f"at {stage_out}: the scene itself is what to open")
    made = [p for p in (work.parent, work) if not os.path.lexists(p)]
    _claim_outputs(scene, recipes, work, force)
    with contextlib.ExitStack() as stack:
        dask_info = None
        if jobs is None:
            jobs = default_jobs()
        if dask is not None:
            from ...cluster import command_info, session

            dask_info, jobs = command_info(stack.enter_context(session(dask)))
        for name, text in (("SConstruct", sconstruct()),
                           (_STEPS, json.dumps(steps(recipes, dask_info, report["bindings"]), indent=1) + "\n")):
            _write_if_changed(work / name, text)
        for chain in report["bindings"]:
            chain.folder.mkdir(parents=True, exist_ok=True)
            _write_if_changed(chain.mesh_layer, chain.mesh_text)
        for r in recipes:
            coverage = (report.get("needs") or {}).get(r.material)
            if coverage is not None and coverage.coverage() is not None:
                coverage_path(scene, r).parent.mkdir(parents=True, exist_ok=True)
                _write_if_changed(coverage_path(scene, r), json.dumps(coverage.coverage(), indent=1) + "\n")
        (work / _FAILURE).unlink(missing_ok=True)
        (work / _TIMES).unlink(missing_ok=True)
        missing = [p for r in recipes for p in {r.compressed, r.asset.parent} if not os.path.lexists(p)]
        env = dict(os.environ)
        pipeline = str(Path(__file__).resolve().parents[3])
        env["PYTHONPATH"] = pipeline + os.pathsep + env.get("PYTHONPATH", "")
        # SCons, and the usdbtf steps it runs, die with this process (usdbtf.lifetime); stopped
        # (SIGTERM, Ctrl-C), this process kills SCons and its steps remove their own staging.
        try:
            proc = subprocess.run(guarded_module_argv("SCons", "-Q", "--no-site-dir", "-j", str(jobs), "-f",
                                                      str(work / "SConstruct"), "-C", str(work)),
                                  capture_output=True, text=True, env=child_environment(env),
                                  stdin=subprocess.DEVNULL)
        except BaseException:
            _remove_empty(missing)
            raise
    ran = [line for line in proc.stdout.splitlines() if line.startswith("usdbtf-step ")]
    report["times"] = _step_times(work)
    if proc.returncode:
        _remove_empty(missing)
        failure = _failure(work)
        if not any(os.path.lexists(o) for r in recipes for o in r.outputs()):
            _remove_made(made)         # nothing was built: leave no build folder behind
        if failure is not None:
            raise error_for_status(failure[0], f"{scene}: build failed: {failure[1]}")
        detail = proc.stderr.strip().splitlines() or proc.stdout.strip().splitlines() or ["?"]
        raise BTFError(f"{scene}: build failed: {detail[-1]}")
    _remove_old_built_stage(work)
    if report["bindings"]:
        from .binding import built_scene_text

        text = built_scene_text(scene, _open_scene(scene), report["bindings"], stage_out.parent)
        _write_stage(scene, stage_out, text, work, force)
        report["built_scene"] = stage_out
        log.info(f"{len(report['bindings'])} bound mesh chain(s); the built stage: {stage_out}")
    for r in recipes:
        log.info(f"{r.material}: {r.asset}")
    log.info(f"{len(recipes)} bound BTF material(s); {len(ran)} step(s) run" + ("" if ran else " (all up to date)"))
    report.update(recipes=recipes, ran=ran)
    report["costs"] = _costs(work, recipes, report)
    return report


def default_jobs() -> int:
    """The CPUs this process may run on (at least 1): SCons's default ``-j`` for a build."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _owns_stage(work: Path, out: Path) -> bool:
    """Whether ``out`` is the built stage the last build of this scene wrote (its record)."""
    recorded = _recorded_stage(work)
    return recorded is not None and related(recorded, out) == "is"


def _check_stage_output(scene: Path, out: Path, recipes: list[Recipe], report: dict, work: Path,
                        force: bool) -> None:
    """Refuse a built stage path that is a layer of the scene, a recipe's source or output, or in
    the build folder, and an existing file there that this scene's last build did not write
    (unless ``force``, and then only a usdbtf built stage); see the module docstring."""
    from ...atomic import check_output, current_policy, output_policy
    from ...errors import UsageError
    from ...outputs import BUILT_STAGE

    if out.suffix.lower() not in STAGE_SUFFIXES:
        raise UsageError(f"{out}: the built stage is a USD layer; name it *.usda, *.usdc or *.usd")
    for p in report.get("layers", [scene]):
        rel = related(out, p)
        if rel:
            raise OutputRefused(f"{out}: the built stage {rel} {p}, a layer of the scene being built; "
                                "choose another -o path")
    for r in recipes:
        for p in [r.source, *r.outputs()]:
            rel = related(out, p)
            if rel:
                raise OutputRefused(f"{out}: the built stage {rel} {p}, what {r.material} is built from or into; "
                                    "choose another -o path")
    if related(out, work.parent) in ("is", "is inside"):
        raise OutputRefused(f"{out}: is inside the build folder {work.parent} (intermediates only); "
                            "choose another -o path")
    with output_policy(force=force or _owns_stage(work, out), inputs=(*current_policy().inputs, scene)):
        check_output(out, folder=False, kind=BUILT_STAGE, what="built stage")


def _write_stage(scene: Path, out: Path, text: str, work: Path, force: bool) -> None:
    """Write the built stage ``out`` (usda ``text``; exported as crate for .usdc/.usd) atomically,
    unless it already holds it, and record it in the build folder (:data:`STAGE_RECORD`)."""
    from ...atomic import current_policy, output_policy
    from ...outputs import BUILT_STAGE

    if not (out.suffix == ".usda" and out.is_file() and _read_text(out) == text):
        with output_policy(force=force or _owns_stage(work, out), inputs=(*current_policy().inputs, scene)), \
                atomic_file(out, kind=BUILT_STAGE) as tmp:
            if out.suffix.lower() == ".usda":
                tmp.write_text(text)
            else:
                from pxr import Sdf

                layer = Sdf.Layer.CreateAnonymous(".usda")
                layer.ImportFromString(text)
                if not layer.Export(str(tmp)):
                    raise BTFError(f"{out}: the built stage could not be written as {out.suffix}")
    else:       # unchanged: still clean what a run killed after its swap left beside it
        tidy_owned(out, kind=BUILT_STAGE)
    _write_if_changed(work / STAGE_RECORD, json.dumps({"built_stage": os.path.relpath(out, work)}, indent=1) + "\n")


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError):
        return None


def _remove_old_built_stage(work: Path) -> None:
    """Remove the built stage an older build wrote inside the build folder (``scene.usda``,
    recognised by its comment), so that only the visible one is left to open."""
    old = work / _OLD_BUILT_STAGE
    text = _read_text(old) if old.is_file() and not old.is_symlink() else None
    if text is not None and "written by usdbtf build: the scene with every bound mesh" in text[:400]:
        old.unlink()


def _remove_empty(missing: list[Path]) -> None:
    """Remove the folders of ``missing`` that SCons made for a target it did not build (empty)."""
    for p in sorted(missing, key=lambda q: len(q.parts), reverse=True):
        with contextlib.suppress(OSError):
            p.rmdir()


def _folder_bytes(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) if path.is_dir() else 0


def _step_material(label: str) -> str:
    """The material a step label names ("usdbtf-step compress \"/M\"", "usdbtf-step quilt /M /prim")."""
    parts = label.split(" ")
    return json.loads(parts[2]) if len(parts) > 2 and parts[2].startswith('"') else (parts[2] if len(parts) > 2 else "")


def _costs(work: Path, recipes: list[Recipe], report: dict) -> dict:
    """{material: {"bytes": what its outputs hold now (compressed folder, asset, bound meshes'
    chains), "seconds": its steps' time in this run (None: none ran), "full_bytes",
    "full_seconds": the last ``--full`` build's (None: none recorded)}}; a ``--full`` build
    records its own as the reference."""
    costs = {}
    for r in recipes:
        chains = [c.folder for c in report["bindings"] if c.material == r.material]
        spent = [t for label, t in report["times"].items() if _step_material(label) == r.material]
        costs[r.material] = {"bytes": sum(_folder_bytes(p) for p in [*r.outputs(), *chains]
                                          if p != r.source),
                             "seconds": sum(spent) if spent else None}
    for material in report.get("skipped", []):
        costs[material] = {"bytes": 0, "seconds": 0.0}
    try:
        record = json.loads((work / _FULL_RECORD).read_text())
    except (OSError, ValueError):
        record = {}
    record = record if isinstance(record, dict) else {}
    if not report.get("shaped"):
        for material, cost in costs.items():
            old = record.get(material) if isinstance(record.get(material), dict) else {}
            record[material] = {"bytes": cost["bytes"],
                                "seconds": cost["seconds"] if cost["seconds"] is not None else old.get("seconds")}
        with atomic_file(work / _FULL_RECORD, owner_checked=True) as tmp:
            tmp.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    for material, cost in costs.items():
        ref = record.get(material) if isinstance(record.get(material), dict) else {}
        cost["full_bytes"], cost["full_seconds"] = ref.get("bytes"), ref.get("seconds")
    return costs


def _write_if_changed(path: Path, text: str) -> None:
    """Write ``text`` at ``path`` unless it already holds it (content signatures then see no change)."""
    if not path.is_file() or path.read_text() != text:
        with atomic_file(path, owner_checked=True) as tmp:
            tmp.write_text(text)
    else:
        tidy_owned(path)         # a run killed after its swap left the lock: clean it all the same


def _open_scene(scene: Path):
    from ...usdstage import open_usd, usd_warnings_silenced

    with usd_warnings_silenced():
        return open_usd(scene, composition_errors=False)


def _remove_made(made: list[Path]) -> None:
    """Remove the build folders this run made (``made``: outermost first), once nothing in them
    is a build output: a failed first build leaves the scene's folder as it found it."""
    if made:
        shutil.rmtree(made[-1], ignore_errors=True)
    for folder in reversed(made[:-1]):
        with contextlib.suppress(OSError):
            folder.rmdir()             # only if empty: another scene's build may live there


def _step_times(work: Path) -> dict:
    """{step label: seconds} of the steps this build ran (the SConstruct appends them)."""
    times = {}
    try:
        lines = (work / _TIMES).read_text().splitlines()
        (work / _TIMES).unlink()
    except OSError:
        return times
    for line in lines:
        with contextlib.suppress(ValueError, KeyError, TypeError):
            doc = json.loads(line)
            times[str(doc["label"])] = float(doc["seconds"])
    return times


def _failure(work: Path) -> tuple[int, str] | None:
    try:
        doc = json.loads((work / _FAILURE).read_text())
        (work / _FAILURE).unlink()
        return int(doc["status"]), str(doc["message"])
    except (OSError, ValueError, KeyError, TypeError):
        return None

