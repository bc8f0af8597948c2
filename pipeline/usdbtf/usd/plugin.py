"""Finding the usdBtf USD plugin and the environment that makes any USD process know it.

The plugin is a folder (``plugin/`` at the top of the project) holding a
``plugInfo.json`` that includes ``usdBtf/resources/``: the generated ``BtfMaterialAPI``
schema, the Storm shader's Sdr definition (``sdr/UsdBtfSurface.usda``), its glslfx
(``shaders/``) and the MaterialX nodedefs (``materialx/``).

Two USD mechanisms find them, both driven by environment variables that USD reads once,
when its libraries load (:func:`environment` lists them; ``usdbtf env`` prints them as the
shell lines a studio puts in its launcher):

* ``PXR_PLUGINPATH_NAME`` -> the plugin folder: the schema (and ``$TOOLS/usdBtf/shaders``);
* Sdr's filesystem discovery (``PXR_SDR_FS_PLUGIN_SEARCH_PATHS``, searched recursively,
  and ``PXR_SDR_FS_PLUGIN_ALLOWED_EXTS``; before USD 25.05 the same discovery was Ndr's and
  read ``PXR_NDR_FS_PLUGIN_SEARCH_PATHS`` / ``PXR_NDR_FS_PLUGIN_ALLOWED_EXTS``, so both
  families are set and each build reads its own): a ``.usda`` file is parsed by usdShade's
  shader-definition parser, which every USD build (usd-core included) has; the node's
  identifier is the file's stem and its definition the root prim of that name, so
  ``sdr/UsdBtfSurface.usda`` defines ``UsdBtfSurface`` and usdShadeValidators'
  ShaderSdrCompliance finds it.  ``glslfx`` is allowed as well, for Storm: in a build
  with imaging, ``shaders/UsdBtfSurface.glslfx`` becomes the ``glslfx`` node Storm asks
  for; usd-core has no glslfx parser and ignores it.
* ``PXR_MTLX_PLUGIN_SEARCH_PATHS`` -> the MaterialX nodedefs (builds with MaterialX).

USD announces every overridden ``TfEnvSetting`` (the Sdr variables are such settings from
25.05 on) with a banner on stderr when it loads; ``TF_ENV_SETTING_ALERTS_ENABLED``, itself a
TfEnvSetting of libtf, is USD's switch for those banners: :data:`QUIET` sets it to 0 unless
the user chose otherwise (:func:`defaults`).

``import usdbtf`` applies the same environment to its own process (:func:`register`)
before USD loads, so the process validates exactly what any other process set up by
``usdbtf env`` sees; there is no registration in Python beyond that.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

from ..errors import BTFError
from ..plugin_folder import SHADER_ID, plugin_dir

API_SCHEMA = "BtfMaterialAPI"
#: Variables whose list separator is ':' on every platform (Tf splits extensions on ':').
_COLON_LISTS = ("PXR_SDR_FS_PLUGIN_ALLOWED_EXTS", "PXR_NDR_FS_PLUGIN_ALLOWED_EXTS")
#: USD's switch for the "X is overridden" banners it prints when it loads (libtf's
#: TF_ENV_SETTING_ALERTS_ENABLED); usdbtf's environment overrides settings by design.
QUIET = "TF_ENV_SETTING_ALERTS_ENABLED"
#: Sdr's filesystem-discovery variables, per USD release: Ndr's names before 25.05.
DISCOVERY_FAMILIES = ("PXR_SDR_FS_PLUGIN", "PXR_NDR_FS_PLUGIN")


def resources_dir(plugin: Path | None = None) -> Path:
    """``<plugin>/usdBtf/resources``: generatedSchema.usda, sdr/, shaders/, materialx/."""
    return (plugin or plugin_dir()) / "usdBtf" / "resources"


def environment(plugin: Path | None = None) -> dict[str, list[str]]:
    """{variable: [entries usdbtf needs on it, in order]} for a USD process to know the
    plugin: the schema, the Storm shader's Sdr definition (and glslfx), MaterialX nodedefs.
    Entries are prepended to whatever the variable already holds."""
    plugin = Path(plugin or plugin_dir()).resolve()
    res = resources_dir(plugin)
    env = {"PXR_PLUGINPATH_NAME": [str(plugin)]}
    for family in DISCOVERY_FAMILIES:          # USD >= 25.05 reads the first, 24.x-25.02 the second
        env[f"{family}_SEARCH_PATHS"] = [str(res / "sdr"), str(res / "shaders")]
        env[f"{family}_ALLOWED_EXTS"] = ["usda", "glslfx"]
    env["PXR_MTLX_PLUGIN_SEARCH_PATHS"] = [str(res / "materialx")]
    return env


def defaults() -> dict[str, str]:
    """{variable: value} set only where the variable is unset: the banners off (:data:`QUIET`)."""
    return {QUIET: "0"}


def list_separator(variable: str) -> str:
    """How ``variable``'s entries are joined: ':' for extension lists, else the OS path separator."""
    return ":" if variable in _COLON_LISTS else os.pathsep


def merged_value(variable: str, entries: list[str], current: str | None) -> str:
    """``current`` with the missing ``entries`` put in front (no duplicates)."""
    sep = list_separator(variable)
    have = [e for e in (current or "").split(sep) if e]
    return sep.join([e for e in entries if e not in have] + have)


def apply_environment(env=None, plugin: Path | None = None) -> bool:
    """Put :func:`environment` into ``env`` (default ``os.environ``); True when anything
    changed.  USD reads these when it loads, so this only affects USD in this process when
    it runs before the first ``from pxr import ...`` (it always affects child processes)."""
    env = os.environ if env is None else env
    changed = False
    for variable, entries in environment(plugin).items():
        value = merged_value(variable, entries, env.get(variable))
        if value != env.get(variable):
            env[variable] = value
            changed = True
    for variable, value in defaults().items():
        env.setdefault(variable, value)
    return changed


def register() -> bool:
    """Make the plugin known to this process (idempotent): apply :func:`environment`
    (before USD loads, when ``import usdbtf`` comes first), then register the plugin folder
    with Plug (which also works after USD has loaded, until the schema registry is first
    used).  Returns False when the folder is absent."""
    folder = plugin_dir()
    if not (folder / "plugInfo.json").is_file():
        return False
    apply_environment()       # before USD loads, when import usdbtf comes first (banners off: defaults)
    from pxr import Plug

    Plug.Registry().RegisterPlugins(str(folder))
    return True


def register_lazily() -> bool:
    """Make the plugin known to USD without importing USD when it is not loaded yet.

    USD reads :func:`environment`'s variables when its libraries load, so applying them
    is enough before ``pxr`` is imported (and it costs no import: the
    command line's ``--version``/``--help`` stay fast; child processes inherit it).  When
    ``pxr`` is already loaded its registry may exist already: register now.  Idempotent.
    Returns False when the folder is absent.
    """
    folder = plugin_dir()
    if not (folder / "plugInfo.json").is_file():
        return False
    if "pxr" in sys.modules:
        return register()
    apply_environment()
    return True


def require_schema() -> None:
    """Raise a clear BTFError when ``BtfMaterialAPI`` is not known to this process."""
    from pxr import Usd

    if Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(API_SCHEMA) is None:
        raise BTFError(f"the {API_SCHEMA} schema is not registered: set PXR_PLUGINPATH_NAME to {plugin_dir()} "
                       f"(or import usdbtf before creating any USD stage)")


def shader_known() -> bool:
    """Whether Sdr in this process has the Storm shader's definition (``UsdBtfSurface``)."""
    from pxr import Sdr

    return Sdr.Registry().GetShaderNodeByIdentifier(SHADER_ID) is not None


def environment_hint() -> str:
    """What to tell a user whose process lacks the plugin's environment."""
    return ("start the process with the environment `usdbtf env` prints "
            "(or import usdbtf before anything imports pxr)")
