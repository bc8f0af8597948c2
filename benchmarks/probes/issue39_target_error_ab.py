"""Issue 39 before/after: ``usdbtf compress INPUT --target-error T`` with a baseline pipeline
(e.g. ``git archive main pipeline``) and this worktree's, in the same run; for each, the
choice (k, step, folder and asset bytes, attempts), compress's estimate and the exact error
of what it wrote over every sample and texel on the input files' 8-bit values (the paper's
metric, ``usdbtf.compress.decompress.compare``), plus its split over fitted / unfitted /
held-out texels (``issue39_heldout_split.py``).  CPU seconds of each compress (children).

    .venv/bin/python benchmarks/probes/issue39_target_error_ab.py INPUT TARGET BASE_PIPELINE OUT \
        [-- extra compress options]
"""
from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[2]


def main() -> None:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    src, target, base, out = argv
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, load {os.getloadavg()[0]:.2f}")
    print(f"input: {src}; --target-error {target} {' '.join(extra)}")
    for label, pipeline in (("baseline", Path(base).resolve()), ("this branch", HERE / "pipeline")):
        folder = Path(out) / label.replace(" ", "_")
        if folder.exists():
            subprocess.run(["rm", "-rf", str(folder)], check=True)
        env = dict(os.environ, PYTHONPATH=str(pipeline))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([sys.executable, "-c", "import sys; from usdbtf.cli import main; sys.exit(main())", "compress",
                        src, "-o", str(folder), "--target-error", target, *extra], env=env, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
        ch = json.loads((folder / "btf-compressed.json").read_text())["choice"]
        print(f"[{label}] pipeline {pipeline}: k {ch['k']}, step {ch['step']:.4g}, folder bytes {ch.get('folder_bytes')}, "
              f"asset bytes {ch['bytes']}, attempts {ch['attempts']}, compress CPU {cpu:.1f} s")
        sys.stdout.flush()
        subprocess.run([sys.executable, str(HERE / "benchmarks/probes/issue39_heldout_split.py"), src, str(folder)],
                       check=True, env=dict(os.environ, PYTHONPATH=str(HERE / "pipeline")))


if __name__ == "__main__":
    main()
