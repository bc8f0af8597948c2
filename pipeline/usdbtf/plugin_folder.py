"""Where usdbtf's USD plugin folder is (the schema, the Storm shaders, the MaterialX nodes).

A base module so that both the GPU code (which generates files into the plugin) and the USD
code (which registers it) can find the folder, and agree on the Storm shader's name, without
importing each other.
"""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["ENV_PLUGIN_DIR", "SHADER_ID", "plugin_dir"]

ENV_PLUGIN_DIR = "USDBTF_PLUGIN_DIR"
#: The Storm shader's Sdr identifier: the file name of its definition under
#: ``usdBtf/resources/sdr/`` (Sdr's filesystem discovery names a node after its file) and of
#: its glslfx under ``shaders/``.
SHADER_ID = "UsdBtfSurface"


def plugin_dir() -> Path:
    """The folder to put on ``PXR_PLUGINPATH_NAME``: ``$USDBTF_PLUGIN_DIR``, else the
    project's ``plugin/`` (source checkouts and editable installs)."""
    override = os.environ.get(ENV_PLUGIN_DIR)
    if override:
        return Path(override)
    return Path(__file__).resolve().parents[2] / "plugin"
