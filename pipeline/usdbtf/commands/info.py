"""``usdbtf info``: summarise a BTF or a compressed BTF."""
from __future__ import annotations

from pathlib import Path

from ..argtypes import add_outside_paths_flag

ORDER = 50


def add_parser(sub) -> None:
    p = sub.add_parser("info", help="summarise a BTF or a compressed BTF")
    p.add_argument("path", type=Path)
    add_outside_paths_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    path = Path(args.path)
    from ..compress.format import METADATA, folder_bytes

    if (path / METADATA).is_file():
        from ..compress import read_compressed

        c = read_compressed(path)
        b = c.info.get("bytes", {})
        est = c.info.get("estimated_error", {}).get("linear", {})
        print(f"{path}: compressed BTF ({c.info.get('solver', '?')} solver, {c.codec} codec)")
        print(f"  samples     {c.n_samples}  ({c.width}x{c.height} texels)")
        print(f"  k           {c.k}")
        print(f"  bytes       payload {b.get('payload', '?')} (basis {b.get('basis', '?')}, coefficients "
              f"{b.get('coefficients', '?')}), metadata {(path / METADATA).stat().st_size}, "
              f"folder {folder_bytes(path)}")
        if est:
            print(f"  error       {est['percent']:.3f} % (paper's metric), RMSE {est['rmse']:.5f}, "
                  f"PSNR {est['psnr_db']:.2f} dB  [held-out texels, scene-linear]")
        print(f"  colour      working {c.working_space}; source {c.source.get('color_space')} "
              f"{c.source.get('bit_depth')}")
        return 0
    from ..io import open_btf

    btf = open_btf(path)
    for line in describe_btf(path, btf):
        print(line)
    return 0


def _count(directions) -> int:
    import numpy as np

    return len({tuple(np.round(d, 6)) for d in directions})


def _image_size(btf) -> tuple[int, int]:
    """The size of the image files themselves when the samples are files on disk (a
    manifest's declared size is checked against them), else the reader's size."""
    from ..imageio import read_info

    paths = getattr(btf, "paths", None)
    if paths and Path(paths[0]).is_file():
        first = read_info(paths[0])
        return first.width, first.height
    return btf.width, btf.height


def describe_btf(path, btf) -> list[str]:
    """The lines ``usdbtf info`` prints for an input BTF: format, directions, size, colour;
    for Bonn ``.btf`` files also the signature, colour model and component counts."""
    nv, nl = _count(btf.sampling.view), _count(btf.sampling.light)
    grid = f"{nv} views x {nl} lights" if nv * nl == btf.n_samples else f"{nv} views, {nl} lights"
    fmt = btf.metadata.get("format") or "btf-manifest/1"
    w, h = _image_size(btf)
    lines = [f"{path}: {fmt} BTF, {grid} = {btf.n_samples} samples of {w}x{h} texels"]
    describe = getattr(btf, "describe", None)
    d = describe() if describe else {}
    if "signature" in d:
        lines[0] += f" (signature {d['signature']})"
    lines.append(f"  colour      {btf.bit_depth} {btf.color_space}"
                 + (f", stored as colour model {d['color_model']} ({d['color_model_name']})" if d else ""))
    if d.get("components") is not None:
        per = "view" if d["format"] == "PVF" else "channel"
        counts = ", ".join(f"{per} {i}: {k}" for i, k in enumerate(d["components"]))
        lines.append(f"  components  {counts}  ({d['scalar']} floats)")
    if d:
        extra = [f"{d['file_bytes']} bytes" if d.get("file_bytes") is not None else None,
                 f"{d['ppmm']:g} px/mm" if d["ppmm"] > 0 else None,
                 f"cosine flag {'on' if d['cosine_flag'] else 'off'}", f"{d['rotations']} rotations",
                 "dynamic-range reduction on" if d.get("dynamic_range_reduction") else None,
                 f"{d['stored_texels']} stored texels" if "stored_texels" in d else None]
        lines.append("  file        " + "; ".join(e for e in extra if e))
    ignored = getattr(btf, "ignored", None)
    if ignored:
        lines.append(f"  ignored     {len(ignored)} member(s) that are not samples, e.g. {ignored[0]!r}")
    lines.append(f"  interpolated {int(btf.interpolated.sum())}")
    return lines
