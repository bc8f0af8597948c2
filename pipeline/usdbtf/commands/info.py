"""``usdbtf info``: summarise a BTF or a compressed BTF."""
from __future__ import annotations

from pathlib import Path


ORDER = 50


def add_parser(sub) -> None:
    p = sub.add_parser("info", help="summarise a BTF or a compressed BTF")
    p.add_argument("path", type=Path)
    p.add_argument("--json", action="store_true", help="print the summary as JSON (keys in the README)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..compress.format import METADATA
    from ..summary import btf_summary, compressed_summary

    path = Path(args.path)
    s = compressed_summary(path) if (path / METADATA).is_file() else btf_summary(path)
    if args.json:
        from . import print_json

        print_json(s)
    elif s["kind"] == "compressed":
        print(compressed_text(s))
    else:
        print(f"{s['path']}: BTF, {s['samples']} samples of {s['width']}x{s['height']}, {s['bit_depth']} "
              f"{s['color_space']}")
        print(f"  views {s['views']}, lights {s['lights']}, interpolated {s['interpolated']}")
    return 0


def compressed_text(s: dict) -> str:
    """The human-readable form of :func:`usdbtf.summary.compressed_summary`."""
    b, est = s["bytes"], s["estimated_error"]
    lines = [f"{s['path']}: compressed BTF ({s['solver'] or '?'} solver, {s['codec']} codec)",
             f"  samples     {s['samples']}  ({s['width']}x{s['height']} texels)",
             f"  k           {s['k']}",
             f"  bytes       payload {b.get('payload', '?')} (basis {b.get('basis', '?')}, coefficients "
             f"{b.get('coefficients', '?')}), metadata {b['metadata']}, folder {b['folder']}"]
    if est:
        lines.append(f"  error       {est['percent']:.3f} % (paper's metric), RMSE {est['rmse']:.5f}, "
                     f"PSNR {est['psnr_db']:.2f} dB  [held-out texels, scene-linear]")
    lines.append(f"  colour      working {s['working_space']}; source {s['source']['color_space']} "
                 f"{s['source']['bit_depth']}")
    return "\n".join(lines)
