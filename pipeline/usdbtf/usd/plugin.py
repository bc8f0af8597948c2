"""Finding and registering the usdBtf schema plugin.

The plugin is a folder (``plugin/`` at the top of the project) holding a
``plugInfo.json`` that includes ``usdBtf/resources/`` (the generated schema and the
Storm shaders).  USD must know it before its schema registry is first used (the
first ``Usd.Stage`` or ``Usd.SchemaRegistry`` query), or ``BtfMaterialAPI`` is
silently unknown for the life of the process; ``import usdbtf`` therefore calls
:func:`register` before anything else can.  DCCs and usdview find it through
``PXR_PLUGINPATH_NAME=<project>/plugin``.
"""
from __future__ import annotations

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


def require_schema() -> None:
    """Raise a clear BTFError when ``BtfMaterialAPI`` is not known to this process."""
    from pxr import Usd

    if Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(API_SCHEMA) is None:
        raise BTFError(f"the {API_SCHEMA} schema is not registered: set PXR_PLUGINPATH_NAME to {plugin_dir()} "
                       f"(or import usdbtf before creating any USD stage)")
