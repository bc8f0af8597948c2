"""Zip the usdbtf Blender add-on for Blender's normal installation (an extension package).

    python scripts/blender_addon_zip.py -o usdbtf-blender-0.1.0.zip

The zip holds ``plugin/blender/usdbtf`` at its root (``blender_manifest.toml``, the Python,
its licence) and the generated ``usdbtf_surface.osl`` (``plugin/usdBtf/resources/osl``, the one
copy in the source tree, which the add-on reads when it runs from a checkout), as ``blender --command extension build`` lays an
extension out: Blender 4.2+ installs it with Edit > Preferences > Get Extensions > Install from
Disk (or drag and drop).  The entries are sorted and dated 1980-01-01, so the same sources
give the same bytes.  Refuses when the OSL is stale (``python -m usdbtf.gpu.shaders``
regenerates it) or the output exists.
"""
from __future__ import annotations

import argparse
import sys
import zipfile
from pathlib import Path

ADDON = Path(__file__).resolve().parent.parent / "plugin" / "blender" / "usdbtf"
PLUGIN = ADDON.parent.parent
#: zip entry -> its file in the source tree
FILES = {name: ADDON / name for name in ("__init__.py", "network.py", "principled.py", "blender_manifest.toml", "LICENSE")}
FILES["usdbtf_surface.osl"] = PLUGIN / "usdBtf" / "resources" / "osl" / "usdbtf_surface.osl"


def build_zip(output: Path) -> Path:
    """Write the extension zip to ``output`` (which must not exist)."""
    from usdbtf.atomic import atomic_file
    from usdbtf.gpu.shaders import stale_plugin_files

    osl_rel = FILES["usdbtf_surface.osl"].relative_to(PLUGIN).as_posix()
    stale = [rel for rel in stale_plugin_files() if rel == osl_rel]
    if stale:
        raise SystemExit(f"blender_addon_zip: error: {stale[0]}: stale (run python -m usdbtf.gpu.shaders)")
    if output.exists():
        raise SystemExit(f"blender_addon_zip: error: {output}: exists (remove it first)")
    with atomic_file(output, owner_checked=True) as tmp:     # refused above when it exists
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
            for name in sorted(FILES):
                info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
                info.external_attr = 0o644 << 16
                archive.writestr(info, FILES[name].read_bytes(), zipfile.ZIP_DEFLATED)
    return output


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("-o", "--output", type=Path, required=True)
    args = p.parse_args(argv)
    print(build_zip(args.output))
    return 0


if __name__ == "__main__":
    sys.exit(main())
