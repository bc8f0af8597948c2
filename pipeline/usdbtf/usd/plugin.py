"""Finding and registering the usdBtf schema plugin.

The plugin is a folder (``plugin/`` at the top of the project) holding a
``plugInfo.json`` that includes ``usdBtf/resources/`` (the generated schema and the
Storm shaders).  USD must know it before its schema registry is first used (the
first ``Usd.Stage`` or ``Usd.SchemaRegistry`` query), or ``BtfMaterialAPI`` is
silently unknown for the life of the process; ``import usdbtf`` therefore calls
:func:`register_lazily` before anything else can.  DCCs and usdview find it through
``PXR_PLUGINPATH_NAME=<project>/plugin``.
"""
from __future__ import annotations

import os
import sys

from ..errors import BTFError
from ..plugin_folder import plugin_dir

API_SCHEMA = "BtfMaterialAPI"


def register() -> bool:
    """Register the plugin with USD (idempotent).  Returns False when the folder is absent."""
    folder = plugin_dir()
    if not (folder / "plugInfo.json").is_file():
        return False
    from pxr import Plug

    Plug.Registry().RegisterPlugins(str(folder))
    return True


def register_lazily() -> bool:
    """Make the plugin known to USD without importing USD when it is not loaded yet.

    USD reads ``PXR_PLUGINPATH_NAME`` when its plugin registry starts, so putting the
    folder there is enough before ``pxr`` is imported (and it costs no import: the
    command line's ``--version``/``--help`` stay fast; child processes inherit it).  When
    ``pxr`` is already loaded its registry may exist already: register now.  Idempotent.
    Returns False when the folder is absent.
    """
    folder = plugin_dir()
    if not (folder / "plugInfo.json").is_file():
        return False
    if "pxr" in sys.modules:
        return register()
    paths = [p for p in os.environ.get("PXR_PLUGINPATH_NAME", "").split(os.pathsep) if p]
    if str(folder) not in paths:
        os.environ["PXR_PLUGINPATH_NAME"] = os.pathsep.join([str(folder), *paths])
    return True


def require_schema() -> None:
    """Raise a clear BTFError when ``BtfMaterialAPI`` is not known to this process."""
    from pxr import Usd

    if Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(API_SCHEMA) is None:
        raise BTFError(f"the {API_SCHEMA} schema is not registered: set PXR_PLUGINPATH_NAME to {plugin_dir()} "
                       f"(or import usdbtf before creating any USD stage)")
