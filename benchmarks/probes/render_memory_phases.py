#!/usr/bin/env python
"""Where ``usdbtf render`` of a scene's own camera spends its memory (issue 39), in process.

Runs the steps of ``usdbtf render SCENE --camera CAMERA --size W H`` (usdbtf.commands.render's
scene path: the stage's shots read lazily, a Renderer per BTF material, one frame by
render_parts, the EXR written) and prints, per step, the peak RSS of the process during the step
(Linux VmHWM, reset before each step through /proc/self/clear_refs) and the RSS after it, from
a bare interpreter on: the imports (numpy, usdbtf, USD, OpenImageIO) are the fixed part.  Then
per material what the texture holds after the frame: its whole levels, and (a tree with tiled
levels) its tiles per level and their bytes.  Run it with ``PYTHONPATH`` (and
``PXR_PLUGINPATH_NAME``) at another tree's pipeline/ (plugin/) to measure that tree.

    nice .venv/bin/python benchmarks/probes/render_memory_phases.py SCENE [--camera /World/Cam] [--size 480 320]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py

import argparse
import os
import tempfile
import time


def _status(key: str) -> int:
    """A /proc/self/status field in bytes (VmRSS, VmHWM)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    raise KeyError(key)


def step(rows: list, name: str, fn):
    """Run ``fn`` as one step: its wall seconds, the peak RSS during it, the RSS after it."""
    with open("/proc/self/clear_refs", "w") as f:       # reset VmHWM to the current RSS
        f.write("5")
    t0 = time.perf_counter()
    out = fn()
    rows.append((name, time.perf_counter() - t0, _status("VmHWM"), _status("VmRSS")))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", type=_Path)
    p.add_argument("--camera", default="/World/Cam")
    p.add_argument("--size", type=int, nargs=2, default=[480, 320])
    args = p.parse_args(argv)
    os.environ.setdefault("OCIO", "ocio://default")
    rows = [("interpreter", 0.0, _status("VmHWM"), _status("VmRSS"))]

    def imports():
        import numpy  # noqa: F401
        import OpenImageIO  # noqa: F401
        from pxr import Usd  # noqa: F401

        import usdbtf.render  # noqa: F401
        import usdbtf.usd.scenes.shots  # noqa: F401

    step(rows, "imports (numpy, usdbtf, USD, OIIO)", imports)
    from common import format_machine, machine_info
    from usdbtf.color import WORKING_SPACE
    from usdbtf.render import Renderer, RenderOptions, RenderResult, render_parts, write_render
    from usdbtf.usd.scenes.shots import scene_shots

    print(f"# render_memory_phases\n{format_machine(machine_info())}\n- scene {args.scene}, camera {args.camera}, "
          f"frame {args.size[0]}x{args.size[1]}; usdbtf from {_Path(usdbtf_file()).parents[1]}")
    materials, shots = step(rows, "read the stage's shots (lazy)",
                            lambda: scene_shots(args.scene, args.camera, args.size[0], None, lazy=True))
    renderers = step(rows, "a Renderer per material",
                     lambda: {m: Renderer(c, RenderOptions()) for m, c in materials.items()})
    shot = shots[0]
    image = step(rows, "render_parts (the frame)",
                 lambda: render_parts([(renderers[m], mesh) for m, mesh in shot.parts], shot.camera, shot.lights))
    with tempfile.TemporaryDirectory() as tmp:
        step(rows, "write the EXR", lambda: write_render(RenderResult(image, WORKING_SPACE), _Path(tmp) / "f.exr"))
    print("\n| step | s | peak RSS during (GB) | RSS after (GB) |\n|---|---|---|---|")
    for name, s, hwm, rss in rows:
        print(f"| {name} | {s:.1f} | {hwm / 1e9:.3f} | {rss / 1e9:.3f} |")
    print("\n| material | held whole (levels: MB) | tiles per level (count) | tile MB |\n|---|---|---|---|")
    for m, r in renderers.items():
        t = r.texture
        whole = {n: round(a.nbytes / 1e6) for n, a in t.levels.items()}
        held = getattr(t, "_held", {})
        tiles = {n: int((h.slot >= 0).sum()) for n, h in held.items()}
        tile_mb = sum(h.pool.nbytes for h in held.values()) / 1e6
        print(f"| {m} | {whole or '-'} | {tiles or '-'} | {tile_mb:.0f} |")
    print(f"\ncovered pixels {int((image[..., 3] > 0).sum())}")
    return 0


def usdbtf_file() -> str:
    import usdbtf

    return usdbtf.__file__


if __name__ == "__main__":
    raise SystemExit(main())
