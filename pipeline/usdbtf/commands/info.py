"""``usdbtf info``: summarise a BTF or a compressed BTF."""
from __future__ import annotations

from pathlib import Path


from ._args import add_outside_paths_flag

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
    # The size of the image files themselves (a manifest's declared size is checked against them).
    from ..imageio import read_info

    first = read_info(btf.paths[0]) if getattr(btf, "paths", None) else None
    w, h = (first.width, first.height) if first else (btf.width, btf.height)
    print(f"{path}: BTF, {btf.n_samples} samples of {w}x{h}, {btf.bit_depth} {btf.color_space}")
    print(f"  views {len({tuple(v) for v in btf.sampling.view})}, lights {len({tuple(v) for v in btf.sampling.light})}, "
          f"interpolated {int(btf.interpolated.sum())}")
    return 0
