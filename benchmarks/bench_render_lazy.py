#!/usr/bin/env python
"""``usdbtf render`` peak memory of a two-material scene: an older tree against the working tree
(issue 39, "consumers read the one copy lazily").

The scene (inputs cached under ``--workdir``, made by the working tree's ``usdbtf``): a 64²
synthetic material (pebbles, sampling "small", ``compress --k 48 --codec png``) quilted to
``--atlas`` texels a side (``usdbtf quilt --size``: the size of a built scene's 2k atlases) and
packaged twice (``usdbtf package``: a swatch quad at the quilt's physical size), as two assets
"A" and "B", so two materials (each read and rendered on its own, as two built materials are;
one quilt to keep the inputs' cost down on a shared machine); a stage referencing both assets
side by side, a camera (/World/Cam) and a distant light.
One frame ``--size`` (default 480 x 320) rendered by ``usdbtf render SCENE --camera /World/Cam``.

Each side renders the same scene in a child under ``nice`` (wall time and peak RSS from
usdbtf.bench.measure.run_measured), interleaved, ``--repeats`` times; "before" is an older
commit's ``pipeline/`` (``git archive``, on PYTHONPATH, as benchmarks/ab_compress.sh does).
The frames are compared: largest absolute difference over the RGBA pixels (0 = identical).

Usage (repository root)::

    nice .venv/bin/python benchmarks/bench_render_lazy.py --before 8154a6a --repeats 2
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from common import OUT, REPO, cli_command, format_machine, machine_info, median, run_measured, timestamp, write_json

sys.path.insert(0, str(Path(__file__).parent))
from bench_package_quilt import run_cli  # noqa: E402

MATERIALS = ("A", "B")
PRESET = "pebbles"


def say(msg: str = "") -> None:
    print(msg, flush=True)


def scene(workdir: Path, cli, atlas: int) -> Path:
    """The scene of the module docstring (made once)."""
    out = workdir / f"scene_{atlas}" / "scene.usda"
    if out.is_file():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    assets = []
    swatch, quilt = workdir / f"{PRESET}64_k48", workdir / f"{PRESET}64_k48_Q{atlas}"
    for name in MATERIALS:
        asset = out.parent / name / f"{name}.usda"
        if not (swatch / "btf-compressed.json").is_file():
            run_cli(cli, "synth", PRESET, "-o", workdir / f"{PRESET}64", "--size", 64, "-q")
            run_cli(cli, "compress", workdir / f"{PRESET}64", "-o", swatch, "--k", 48, "--codec", "png", "-q")
        if not (quilt / "btf-compressed.json").is_file():
            run_cli(cli, "quilt", swatch, "--size", atlas, atlas, "-o", quilt, "-q")
        if not asset.is_file():
            run_cli(cli, "package", quilt, "-o", asset, "-q")
        assets.append(asset)
    from pxr import Gf, Usd, UsdGeom

    from usdbtf.camera import parse_camera
    from usdbtf.usd.scenes.scene import add_camera, add_distant

    side = atlas / 64 * 0.05                                          # the quilt's physical size, metres
    stage = Usd.Stage.CreateNew(str(out))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    for i, asset in enumerate(assets):
        xf = UsdGeom.Xform.Define(stage, f"/World/M{i}")
        xf.GetPrim().GetReferences().AddReference(f"./{asset.relative_to(out.parent)}")
        xf.AddTranslateOp().Set(Gf.Vec3d((i - 0.5) * 1.05 * side, 0.0, 0.0))
    add_camera(stage, "/World/Cam", {None: parse_camera(f"eye=0,{-1.2 * side},{1.3 * side} target=0,0,0 up=0,0,1 "
                                                        "fov=40", 480, 320)})
    add_distant(stage, "/World/Sun", (0.3, -0.5, 1.0), 3.14159)
    stage.Save()
    return out


def render_once(pipeline: Path | None, scene_path: Path, out: Path, size) -> dict:
    env = dict(os.environ)
    if pipeline is not None:
        env["PYTHONPATH"] = str(pipeline)
        # Its own schema plugin (this process's usdbtf import set the working tree's in the environment).
        env["PXR_PLUGINPATH_NAME"] = str(Path(pipeline).parent / "plugin")
    r = run_measured(["nice", sys.executable, "-m", "usdbtf.cli", "--force", "render", str(scene_path), "--camera",
                      "/World/Cam", "--size", *map(str, size), "-o", str(out), "--no-png", "-q"], env=env,
                     pss_interval=0)
    if r.returncode != 0:
        raise SystemExit(f"render ({pipeline or 'working tree'}) failed:\n{r.stderr[-3000:]}")
    return {"wall_s": r.wall_s, "max_rss_bytes": r.max_rss_bytes}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--before", default="8154a6a", help="the older commit")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--atlas", type=int, default=2048)
    p.add_argument("--size", type=int, nargs=2, default=[480, 320])
    p.add_argument("--workdir", type=Path, default=OUT / "data" / "render_lazy")
    args = p.parse_args(argv)
    os.environ.setdefault("OCIO", "ocio://default")
    say(f"# bench_render_lazy\n{format_machine(machine_info())}")
    scene_path = scene(args.workdir, cli_command(), args.atlas)
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    say(f"- scene {scene_path}: 2 materials (64² pebbles, k 48, quilted to {args.atlas}², packaged as two assets), "
        f"frame {args.size[0]}x{args.size[1]}")
    tmp = Path(tempfile.mkdtemp(prefix="render_lazy_"))
    try:
        rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", args.before], capture_output=True,
                             text=True, check=True).stdout.strip()
        archive = subprocess.run(["git", "-C", str(REPO), "archive", rev, "pipeline", "plugin"], capture_output=True,
                                 check=True).stdout
        (tmp / "old").mkdir()
        subprocess.run(["tar", "-x", "-C", str(tmp / "old")], input=archive, check=True)
        sides = {f"before {rev}": tmp / "old" / "pipeline", f"after {head} (working tree)": None}
        runs = {s: [] for s in sides}
        frames = {}
        for rep in range(args.repeats):
            for side, pipeline in sides.items():
                exr = tmp / f"{len(frames) % 2}.exr"
                r = render_once(pipeline, scene_path, exr, args.size)
                runs[side].append(r)
                import OpenImageIO as oiio

                frames[side] = oiio.ImageBuf(str(exr)).get_pixels(oiio.FLOAT)
                say(f"  repeat {rep + 1} {side}: {r['wall_s']:.1f} s, peak RSS {r['max_rss_bytes'] / 1e9:.2f} GB")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    a, b = frames.values()
    diff = float(np.abs(a - b).max())
    lines = ["| side | render s (median) | peak RSS GB (median) |", "|---|---|---|"]
    for side in sides:
        lines.append(f"| {side} | {median(r['wall_s'] for r in runs[side]):.1f} | "
                     f"{median(r['max_rss_bytes'] for r in runs[side]) / 1e9:.2f} |")
    say("\n" + "\n".join(lines))
    say(f"\nframes: largest |difference| {diff:.3g} (max pixel value {float(np.abs(b).max()):.3g}); "
        f"covered pixels {int((b[..., 3] > 0).sum())}")
    path = write_json(OUT / f"render_lazy_{timestamp()}.json", {"args": {k: str(v) for k, v in vars(args).items()},
                                                                "runs": runs, "max_abs_diff": diff})
    say(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
