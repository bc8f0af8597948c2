"""``usdbtf compress``: apparent-BRDF basis + coefficient textures."""
from __future__ import annotations

from ..compress.arguments import add_arguments

ORDER = 20


def add_parser(sub) -> None:
    p = sub.add_parser("compress", help="apparent-BRDF basis + coefficient textures")
    add_arguments(p)
    p.add_argument("--json", action="store_true", help="print a JSON summary of the written folder on stdout "
                   "(the keys of `usdbtf info --json`)")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import COMPRESSED
    return [(args.output, COMPRESSED)]


def run(args) -> int:
    from ..compress import CompressOptions, compress, write_compress
    from ..io import open_btf

    btf = open_btf(args.input)
    coverage = None
    if args.coverage is not None:
        from ..sampling import read_coverage

        coverage = read_coverage(args.coverage)
    opts = CompressOptions(solver=args.solver, k=args.k, target_error=args.target_error, max_bytes=args.max_bytes,
                          codec=args.codec, seed=args.seed, fit_texels=args.fit_texels,
                          fit_every_texel=args.fit_every_texel,
                          power_iterations=args.power_iterations, region=args.region, workers=args.workers,
                          memory_budget=args.memory_budget * 1e9, expand_factors=args.expand_factors,
                          factor_rows=args.factor_rows, dask=args.dask, progress=not args.quiet,
                          domain=args.domain, error_domain=args.error_domain, coverage=coverage,
                          max_texels=args.max_texels, effort=args.effort, budget_for=args.budget_for)
    if opts.budget_for == "asset" and opts.budgeted:
        # The bytes a budget counts are the packaged asset's: what packaging adds beside the
        # coefficient pages and basis codes is measured by packaging's own code (compress
        # cannot import usd: layers, docs/architecture.md).
        from ..usd.asset.package import asset_overhead

        opts.asset_overhead = asset_overhead
    extra = {key: v for key, v in btf.metadata.items() if not key.startswith("_")}
    opts.extra = {"source_metadata": extra} if extra else {}
    result = compress(btf, opts)
    write_compress(result, args.output, force=getattr(args, "force", False))
    if args.json:
        from ..summary import compressed_summary
        from . import print_json

        print_json(compressed_summary(args.output))
    return 0
