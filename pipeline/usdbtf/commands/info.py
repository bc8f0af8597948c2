"""``usdbtf info``: summarise a BTF or a compressed BTF."""
from __future__ import annotations

from pathlib import Path

from ..argtypes import add_outside_paths_flag

ORDER = 50


def add_parser(sub) -> None:
    p = sub.add_parser("info", help="summarise a BTF or a compressed BTF")
    p.add_argument("path", type=Path)
    add_outside_paths_flag(p)
    p.add_argument("--json", action="store_true", help="print the summary as JSON (keys in docs/unattended-runs-errors-outputs.md)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..compress.format import METADATA
    from ..summary import btf_summary, compressed_summary

    path = Path(args.path)
    if (path / METADATA).is_file():
        s = compressed_summary(path)
        lines = [compressed_text(s)]
    else:
        from ..io import open_btf

        btf = open_btf(path)
        s = btf_summary(path, btf)
        lines = describe_btf(path, btf, s)
    if args.json:
        from . import print_json

        print_json(s)
    else:
        for line in lines:
            print(line)
    return 0


def compressed_text(s: dict) -> str:
    """The human-readable form of :func:`usdbtf.summary.compressed_summary`."""
    b, est = s["bytes"], s["estimated_error"]
    lines = [f"{s['path']}: compressed BTF ({s['solver'] or '?'} solver, {s['codec']} codec)",
             f"  samples     {s['samples']}  ({s['width']}x{s['height']} texels)",
             f"  k           {s['k']}",
             f"  domain      {_domain_text(s.get('domain') or {'curve': 'linear'})}",
             f"  bytes       payload {b.get('payload', '?')} (basis {b.get('basis', '?')}, coefficients "
             f"{b.get('coefficients', '?')}), metadata {b['metadata']}, folder {b['folder']}"]
    if est:
        lines.append(f"  error       {est['percent']:.3f} % (paper's metric), RMSE {est['rmse']:.5f}, "
                     f"PSNR {est['psnr_db']:.2f} dB  [held-out texels, scene-linear]")
    lines.append(f"  colour      working {s['working_space']}; source {s['source']['color_space']} "
                 f"{s['source']['bit_depth']}")
    if s.get("coverage"):
        from ..compress.coverage import coverage_text

        lines.append(f"  coverage    {coverage_text(s['coverage'])}")
    return "\n".join(lines)


def _domain_text(d: dict) -> str:
    """``{"curve": "power", "gamma": 1.6}`` -> "x^(1/1.6) (fitted and quantised on it; inverse after the dot product)"."""
    curve = {"linear": "linear", "srgb": "sRGB curve"}.get(d["curve"]) or f"x^(1/{d.get('gamma', 1):g})"
    return curve if d["curve"] == "linear" else f"{curve} (fitted and quantised on it; readers invert it)"


def describe_btf(path, btf, summary: dict | None = None) -> list[str]:
    """The lines ``usdbtf info`` prints for an input BTF: format, directions, size, colour;
    for Bonn ``.btf`` files also the signature, colour model and component counts.
    ``summary``: :func:`usdbtf.summary.btf_summary` of it, when the caller has it."""
    from ..summary import btf_summary

    s = summary or btf_summary(path, btf)
    nv, nl = s["views"], s["lights"]
    grid = f"{nv} views x {nl} lights" if nv * nl == btf.n_samples else f"{nv} views, {nl} lights"
    lines = [f"{path}: {s['format']} BTF, {grid} = {btf.n_samples} samples of {s['width']}x{s['height']} texels"]
    d = s["file"] or {}
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
