"""Run by tests/test_openpbr.py with the Python of a ``.venv-storm-*`` environment, whose
``pxr`` (inside the bpy wheel) is a USD built with MaterialX: tests/fresh_usd_validate.py's
report (every UsdValidation validator on every ``lod`` selection), plus
"materialx_known": whether Sdr knows MaterialX's ``open_pbr_surface`` there, so the
MaterialX nodes of an asset are checked against their real definitions.
"""
import importlib.util
import json
import os
import sys
from pathlib import Path


def _pxr_from_bpy():
    spec = importlib.util.find_spec("bpy")
    root = Path(list(spec.submodule_search_locations)[0])
    libraries = root / "lib" / "materialx" / "libraries"
    if libraries.is_dir():
        os.environ.setdefault("PXR_MTLX_STDLIB_SEARCH_PATHS", str(libraries))
    for site in sorted(root.glob("*/python/lib/python3*/site-packages")):
        if (site / "pxr").is_dir():
            sys.path.insert(0, str(site))
            return


if __name__ == "__main__":
    _pxr_from_bpy()
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import io
    from contextlib import redirect_stdout

    import fresh_usd_validate
    from pxr import Sdr

    buf = io.StringIO()
    with redirect_stdout(buf):
        fresh_usd_validate.main(sys.argv[1:])
    report = json.loads(buf.getvalue())
    report["materialx_known"] = "ND_open_pbr_surface_surfaceshader" in Sdr.Registry().GetShaderNodeIdentifiers()
    print(json.dumps(report))
