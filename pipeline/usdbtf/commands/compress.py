"""``usdbtf compress``: apparent-BRDF basis + coefficient textures."""
from __future__ import annotations

from pathlib import Path

from . import log

ORDER = 20


def add_parser(sub) -> None:
    from ..compress import SOLVERS
    from ..compress.codecs import CODECS
    p = sub.add_parser("compress", help="apparent-BRDF basis + coefficient textures")
    p.add_argument("input", type=Path, help="manifest folder, btf.json, or UBO2003 zip/folder")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.add_argument("--solver", default="rsvd", choices=SOLVERS, help="rsvd (default) or paper (the 2003 method)")
    p.add_argument("--k", type=int, help="number of basis vectors (maximum when a target is given; default 150)")
    p.add_argument("--target-error", type=float, metavar="PCT", help="percent error to reach (scene-linear)")
    p.add_argument("--max-bytes", type=int, metavar="B", help="byte budget for basis + coefficient textures")
    p.add_argument("--codec", choices=sorted(CODECS), help="texture storage (default jxl; paper solver: jpeg)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--fit-texels", type=int, help="rsvd: texels sampled to fit the basis "
                   "(default 2048; 4096 with --max-bytes or --target-error)")
    p.add_argument("--power-iterations", type=int, default=1, help="rsvd: power iterations")
    p.add_argument("--region", type=int, help="paper: side of the central fitting region in texels")
    p.add_argument("--workers", type=int, help="decode processes (default: CPU count)")
    p.add_argument("--memory-budget", type=float, default=1.0, metavar="GB",
                   help="hold the stored values in memory up to this size, else stream them from disk "
                        "twice (default 1.0)")
    p.add_argument("--json", action="store_true", help="print a JSON summary of the written folder on stdout "
                   "(the keys of `usdbtf info --json`)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..compress import Options, compress_to_folder
    from ..io import open_btf

    btf = open_btf(args.input)
    btf.metadata["_path"] = str(args.input)
    opts = Options(solver=args.solver, k=args.k, target_error=args.target_error, max_bytes=args.max_bytes,
                   codec=args.codec, seed=args.seed, fit_texels=args.fit_texels,
                   power_iterations=args.power_iterations, region=args.region, workers=args.workers,
                   memory_budget=args.memory_budget * 1e9)
    extra = {key: v for key, v in btf.metadata.items() if not key.startswith("_")}
    opts.extra = {"source_metadata": extra} if extra else {}
    compress_to_folder(btf, args.output, opts, log=log(args.quiet))
    if args.json:
        from ..summary import compressed_summary
        from . import print_json

        print_json(compressed_summary(args.output))
    return 0
