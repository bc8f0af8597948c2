"""``usdbtf <stage>``: thin command-line mains over the library.

Every command reads real files, writes its output atomically, and on bad input
prints one line naming the file or sample and exits with status 2.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from . import __version__
from .errors import BTFError

EXIT_BAD_INPUT = 2


def _log(quiet: bool):
    return (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))


# -- synth -----------------------------------------------------------------
def cmd_synth(args) -> int:
    from . import synth
    from .manifest import write_manifest
    from .sampling import preset

    t0 = time.perf_counter()
    sampling = preset(args.sampling)
    material = synth.make_material(args.preset, args.size, args.seed)

    def images():
        for block in synth.render(material, sampling):
            yield from (block if block.ndim == 4 else [block])

    meta = {"physical_size_m": [args.physical_size, args.physical_size],
            "synthetic": {"preset": args.preset, "size": args.size, "seed": args.seed, "sampling": args.sampling,
                          "usdbtf_version": __version__}}
    space = args.color_space or ("sRGB Encoded Rec.709 (sRGB)" if args.bit_depth in ("uint8", "uint16")
                                 else "Linear Rec.709 (sRGB)")
    write_manifest(args.output, sampling, images(), color_space=space, bit_depth=args.bit_depth, ext=args.format,
                   array_space=synth.COLOR_SPACE if hasattr(synth, "COLOR_SPACE") else "Linear Rec.709 (sRGB)",
                   metadata=meta)
    _log(args.quiet)(f"wrote {len(sampling)} samples of {args.preset} ({args.size}x{args.size}, {args.bit_depth} "
                     f"{space}) to {args.output} in {time.perf_counter() - t0:.1f} s")
    return 0


# -- compress --------------------------------------------------------------
def cmd_compress(args) -> int:
    from .compress import Options, compress_to_folder
    from .io import open_btf

    btf = open_btf(args.input)
    btf.metadata["_path"] = str(args.input)
    opts = Options(solver=args.solver, k=args.k, target_error=args.target_error, max_bytes=args.max_bytes,
                   codec=args.codec, seed=args.seed, fit_texels=args.fit_texels,
                   power_iterations=args.power_iterations, region=args.region, workers=args.workers,
                   memory_budget=args.memory_budget * 1e9)
    extra = {key: v for key, v in btf.metadata.items() if not key.startswith("_")}
    opts.extra = {"source_metadata": extra} if extra else {}
    compress_to_folder(btf, args.output, opts, log=_log(args.quiet))
    return 0


# -- decompress ------------------------------------------------------------
def cmd_decompress(args) -> int:
    from .compress import read_compressed
    from .compress.decompress import decompress_to_folder, parse_samples

    cbtf = read_compressed(args.input)
    idx = parse_samples(args.samples, cbtf.n_samples)
    if args.k is not None and not (1 <= args.k <= cbtf.k):
        raise BTFError(f"--k must be in 1..{cbtf.k} for {args.input}")
    decompress_to_folder(cbtf, args.output, samples=idx, k=args.k)
    _log(args.quiet)(f"wrote {len(idx)} reconstructed samples (k = {args.k or cbtf.k}) to {args.output}")
    return 0


# -- error -----------------------------------------------------------------
def cmd_error(args) -> int:
    from .io import open_btf
    from .compress.decompress import compare, parse_samples
    import numpy as np

    orig = open_btf(args.original)
    other = open_btf(args.reconstruction)
    if (other.width, other.height) != (orig.width, orig.height):
        raise BTFError(f"{args.reconstruction}: size {other.width}x{other.height} differs from "
                       f"{args.original}'s {orig.width}x{orig.height}")
    # Match samples by direction, so a partial reconstruction (--samples) compares correctly.
    key = {tuple(np.round(np.r_[v, l], 6)): i for i, (v, l) in enumerate(zip(orig.sampling.view, orig.sampling.light))}
    pos = []
    for v, l in zip(other.sampling.view, other.sampling.light):
        i = key.get(tuple(np.round(np.r_[v, l], 6)))
        if i is None:
            raise BTFError(f"{args.reconstruction}: sample view {v.tolist()} light {l.tolist()} is not in {args.original}")
        pos.append(i)
    pos = np.asarray(pos)
    order = {int(o): n for n, o in enumerate(pos)}
    wanted = parse_samples(args.samples, orig.n_samples) if args.samples else np.sort(pos)
    missing = [int(w) for w in wanted if int(w) not in order]
    if missing:
        raise BTFError(f"{args.reconstruction}: has no reconstruction of original sample {missing[0]} "
                       f"({orig.names[missing[0]]})")
    report = compare(orig, lambda sel: other.read_samples([order[int(s)] for s in sel]), wanted)
    print(json.dumps(report, indent=1))
    return 0


# -- info ------------------------------------------------------------------
def cmd_info(args) -> int:
    path = Path(args.path)
    from .compress.format import METADATA, folder_bytes

    if (path / METADATA).is_file():
        from .compress import read_compressed

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
    from .io import open_btf

    btf = open_btf(path)
    print(f"{path}: BTF, {btf.n_samples} samples of {btf.width}x{btf.height}, {btf.bit_depth} {btf.color_space}")
    print(f"  views {len({tuple(v) for v in btf.sampling.view})}, lights {len({tuple(v) for v in btf.sampling.light})}, "
          f"interpolated {int(btf.interpolated.sum())}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from .sampling import PRESETS as SAMPLINGS
    from .compress import SOLVERS
    from .compress.codecs import CODECS

    p = argparse.ArgumentParser(prog="usdbtf", description="Measured BTF materials to USD assets.")
    p.add_argument("--version", action="version", version=f"usdbtf {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="<stage>")

    s = sub.add_parser("synth", help="write a synthetic BTF (manifest folder) from a procedural material")
    s.add_argument("preset", help="material: pebbles, ridged_fabric or fuzzy_moss")
    s.add_argument("-o", "--output", required=True, type=Path)
    s.add_argument("--sampling", default="small", choices=sorted(SAMPLINGS), help="direction set (default small)")
    s.add_argument("--size", type=int, default=128, help="texels per side (default 128)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--format", default="png", choices=["png", "exr", "tif", "jpg"], help="image file type")
    s.add_argument("--bit-depth", default="uint8", choices=["uint8", "uint16", "half", "float"])
    s.add_argument("--color-space", help="OCIO space of the files (default sRGB for integers, linear Rec.709 for floats)")
    s.add_argument("--physical-size", type=float, default=0.05, help="edge length of the tile in metres (default 0.05)")
    s.set_defaults(func=cmd_synth)

    c = sub.add_parser("compress", help="apparent-BRDF basis + coefficient textures")
    c.add_argument("input", type=Path, help="manifest folder, btf.json, or UBO2003 zip/folder")
    c.add_argument("-o", "--output", required=True, type=Path)
    c.add_argument("--solver", default="rsvd", choices=SOLVERS, help="rsvd (default) or paper (the 2003 method)")
    c.add_argument("--k", type=int, help="number of basis vectors (maximum when a target is given; default 150)")
    c.add_argument("--target-error", type=float, metavar="PCT", help="percent error to reach (scene-linear)")
    c.add_argument("--max-bytes", type=int, metavar="B", help="byte budget for basis + coefficient textures")
    c.add_argument("--codec", choices=sorted(CODECS), help="texture storage (default jxl; paper solver: jpeg)")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--fit-texels", type=int, help="rsvd: texels sampled to fit the basis "
                   "(default 2048; 4096 with --max-bytes or --target-error)")
    c.add_argument("--power-iterations", type=int, default=1, help="rsvd: power iterations")
    c.add_argument("--region", type=int, help="paper: side of the central fitting region in texels")
    c.add_argument("--workers", type=int, help="decode processes (default: CPU count)")
    c.add_argument("--memory-budget", type=float, default=1.0, metavar="GB",
                   help="hold the stored values in memory up to this size, else stream them from disk "
                        "twice (default 1.0)")
    c.set_defaults(func=cmd_compress)

    d = sub.add_parser("decompress", help="write the reconstruction as a manifest folder")
    d.add_argument("input", type=Path, help="compressed BTF folder")
    d.add_argument("-o", "--output", required=True, type=Path)
    d.add_argument("--samples", help="indices to write, e.g. 0-99,200 (default all)")
    d.add_argument("--k", type=int, help="use only the first k basis vectors")
    d.set_defaults(func=cmd_decompress)

    e = sub.add_parser("error", help="percent error, RMSE, PSNR of a reconstruction against the original")
    e.add_argument("original", type=Path)
    e.add_argument("reconstruction", type=Path)
    e.add_argument("--samples", help="restrict to these original sample indices")
    e.set_defaults(func=cmd_error)

    i = sub.add_parser("info", help="summarise a BTF or a compressed BTF")
    i.add_argument("path", type=Path)
    i.set_defaults(func=cmd_info)

    for sp in (s, c, d):
        sp.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BTFError as exc:
        print(f"usdbtf {args.command}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"usdbtf {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
