"""``usdbtf --version`` and ``usdbtf CMD --help`` start fast: they import none of the heavy
libraries (numpy, USD, OpenImageIO, OpenCV, OpenColorIO, Dask...), whatever the load of the
machine -- a count of what was imported, not a timing (issue 17)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("numpy", "pxr", "OpenImageIO", "cv2", "PyOpenColorIO", "scipy", "matplotlib", "trimesh", "dask",
         "distributed", "serial", "SCons", "xatlas")

_PROBE = """
import contextlib, io, json, sys
from usdbtf.cli import build_parser, main
from usdbtf.commands import command_modules
heavy = {heavy!r}
report = {{}}
def run(argv):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        try:
            main(argv)
        except SystemExit as exc:
            status = exc.code
    report[" ".join(argv)] = {{"status": status, "heavy": [m for m in heavy if m in sys.modules],
                               "modules": len(sys.modules), "text": out.getvalue()[:200]}}
run(["--version"])
names = sorted(next(a for a in build_parser()._actions if a.dest == "command").choices)
for name in names:
    run([name, "--help"])
print(json.dumps(report))
"""


def test_version_and_help_import_no_heavy_library():
    code = _PROBE.format(heavy=HEAVY)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT / "pipeline")})
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["--version"]["text"].startswith("usdbtf ")
    assert len(report) >= 18, sorted(report)          # every command's --help ran
    for argv, r in report.items():
        assert r["status"] == 0, (argv, r)
        assert r["heavy"] == [], f"usdbtf {argv} imported {r['heavy']}"
    # The interpreter itself loads ~30 modules; argparse, pathlib and usdbtf's light modules
    # bring it to ~150.  numpy alone would add more than 100.
    assert max(r["modules"] for r in report.values()) < 250


def test_import_usdbtf_loads_no_usd():
    code = "import sys, usdbtf; print([m for m in %r if m in sys.modules])" % (HEAVY,)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT / "pipeline")})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
