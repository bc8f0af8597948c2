#!/usr/bin/env python
"""Wall and CPU seconds of compress's inner steps, in process (issue 27: where the time goes).

Wraps the functions compress calls between its logged steps (the domain candidates' fits,
the basis fit, the rate-distortion tables, the probe, quantise, encode, the trim, the
evaluations, the projection) with timers and runs ``compress`` once on INPUT with the given
options; prints each call's wall and CPU seconds (CPU: this process, all threads) as it
returns, then the totals with the decode workers' CPU.  Nothing is written.

    .venv/bin/python benchmarks/profile_compress_steps.py INPUT "max_bytes=3418156"
    .venv/bin/python benchmarks/profile_compress_steps.py INPUT "k=150"
"""
from __future__ import annotations

import functools
import logging
import os
import resource
import sys
import time


def timed(module, name: str) -> None:
    fn = getattr(module, name)

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        t, c = time.perf_counter(), time.process_time()
        result = fn(*args, **kwargs)
        print(f"    [{name}: {time.perf_counter() - t:.2f} s, CPU {time.process_time() - c:.2f} s]", flush=True)
        return result

    setattr(module, name, wrapper)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    logging.basicConfig(level=logging.INFO, format="%(relativeCreated)7.0f ms %(message)s")
    from usdbtf.compress import core, domain_choice, ratecontrol, ratedist
    from usdbtf.compress.options import CompressOptions
    from usdbtf.io import open_btf

    for module, name in [(ratedist, "rd_table"), (ratecontrol, "_coefficient_factor"), (ratecontrol, "_basis_factor"),
                         (ratecontrol, "encode"), (ratecontrol, "encode_coefficients"), (ratecontrol, "encode_first"),
                         (ratecontrol, "quantise"), (ratecontrol, "truncate_encoded"), (domain_choice, "fit_basis"),
                         (core, "fit_source"), (core, "held_out_errors"), (core, "error_curve"),
                         (core, "choose_domain"), (ratecontrol, "held_out_error"), (core, "project"),
                         (core, "sampled_coefficients"), (core, "step_for_k"), (core, "load_source"),
                         (core, "rate_control")]:
        timed(module, name)
    # "k=150,max_bytes=..." -> CompressOptions keywords (numbers only: no code is evaluated).
    options = {}
    for item in filter(None, (argv[1] if len(argv) > 1 else "").split(",")):
        key, value = item.split("=")
        options[key.strip()] = float(value) if "." in value else int(value)
    print(f"input {argv[0]}; options {options}; load {os.getloadavg()[0]:.1f}", flush=True)
    t = time.perf_counter()
    core.compress(open_btf(argv[0]), CompressOptions(**options))
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(f"total {time.perf_counter() - t:.2f} s; CPU {time.process_time():.2f} s in process, "
          f"{kids.ru_utime + kids.ru_stime:.2f} s in decode workers; load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
