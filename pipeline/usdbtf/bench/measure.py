"""Measuring a benchmark run: wall time, CPU time and peak memory of subprocesses, medians,
and small file helpers.  Standard library only (numpy only to serialise arrays).

Definitions used by every benchmark
-----------------------------------
wall time      ``time.perf_counter()`` around the whole subprocess: interpreter start,
               imports, file decoding, everything the user waits for.
peak RSS       the kernel's high-water mark of resident memory (``ru_maxrss`` from
               ``wait4`` on the command, run under a ~10 MB wrapper process so it does
               not inherit the benchmark's own peak; see ``_WRAPPER``).  Linux reports
               the maximum over the command and every descendant it reaped (e.g. a
               process pool's workers), not their sum.
peak tree PSS  sampled every ``pss_interval`` seconds: the sum of ``Pss`` over the child
               and all its live descendants (``/proc/<pid>/smaps_rollup``), i.e. the
               memory the whole process tree holds with shared pages counted once.  A
               sample can miss a peak shorter than the interval.
MB / GB        10^6 / 10^9 bytes.
"""
from __future__ import annotations

import datetime as _dt
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from ..lifetime import dying_with_parent

__all__ = ["REPO", "default_out", "median", "time_call", "cpu_seconds", "run_measured", "run_repeated",
           "run_repeated_apart", "failure_reason", "RunResult", "cli_command", "warm_page_cache", "timestamp",
           "write_json", "fmt_bytes"]


def _find_repo() -> Path | None:
    """The source checkout this package runs from (it holds benchmarks/), else None."""
    root = Path(__file__).resolve().parents[3]
    return root if (root / "benchmarks").is_dir() and (root / "pipeline" / "usdbtf").is_dir() else None


REPO = _find_repo()


def default_out() -> Path:
    """Where benchmark output goes: benchmarks/out/ in a source checkout, else ./bench-out."""
    return REPO / "benchmarks" / "out" if REPO is not None else Path.cwd() / "bench-out"


# -- statistics --------------------------------------------------------------------------------
def median(values) -> float:
    values = [v for v in values if v is not None]
    return float(statistics.median(values)) if values else float("nan")


def time_call(fn, repeats: int = 5, warmup: int = 1) -> dict:
    """Time ``fn()`` in this process: ``warmup`` untimed calls, then ``repeats`` timed ones.

    Returns {"median_s", "min_s", "max_s", "samples_s", "cpu_median_s", "cpu_samples_s",
    "warmup"}; CPU seconds are user + system of this process and of children it reaped
    (decode workers), so CPU / wall shows how many cores a step kept busy.
    """
    for _ in range(warmup):
        fn()
    samples, cpu = [], []
    for _ in range(repeats):
        c, t = cpu_seconds(), time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t)
        cpu.append(cpu_seconds() - c)
    return {"median_s": median(samples), "min_s": min(samples), "max_s": max(samples),
            "samples_s": samples, "cpu_median_s": median(cpu), "cpu_samples_s": cpu, "warmup": warmup}


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and its reaped children so far."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


# -- subprocesses ------------------------------------------------------------------------------
def _ppid_map() -> dict:
    """pid -> parent pid for every visible process (/proc scan; /proc/<pid>/task/*/children is
    not available on every kernel)."""
    out = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as fh:
                stat = fh.read()
        except OSError:
            continue
        rest = stat[stat.rfind(b")") + 2:].split()   # after "pid (comm) ": state ppid ...
        if len(rest) > 1:
            out[int(name)] = int(rest[1])
    return out


def _descendants(root: int) -> list:
    parents = _ppid_map()
    children = {}
    for pid, ppid in parents.items():
        children.setdefault(ppid, []).append(pid)
    tree, todo = [], [root]
    while todo:
        pid = todo.pop()
        tree.append(pid)
        todo.extend(children.get(pid, []))
    return tree


def _rollup_kb(pid: int) -> tuple[int, int]:
    """(Rss, Pss) of one process in kB, (0, 0) if it is gone."""
    rss = pss = 0
    try:
        with open(f"/proc/{pid}/smaps_rollup") as fh:
            for line in fh:
                if line.startswith("Rss:"):
                    rss = int(line.split()[1])
                elif line.startswith("Pss:"):
                    pss = int(line.split()[1])
    except OSError:
        pass
    return rss, pss


def _cmdline(pid: int) -> str:
    """The first 160 characters of a process's command line ('' if it is gone)."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().replace(b"\0", b" ").decode(errors="replace").strip()[:160]
    except OSError:
        return ""


class _TreeSampler(threading.Thread):
    """Samples the summed PSS/RSS of the descendants of ``pid`` (not ``pid`` itself) until stopped."""

    def __init__(self, pid: int, interval: float):
        super().__init__(daemon=True)
        self.pid, self.interval = pid, interval
        self.peak_pss_kb = self.peak_rss_sum_kb = 0
        self.peak_processes = 0
        self.peak_rss_kb_by_pid: dict = {}     # pid -> (peak RSS kB, short command line)
        self.samples = 0
        self.available = os.path.exists("/proc/self/smaps_rollup")
        self._stop_event = threading.Event()

    def run(self):
        while self.available:
            pids = _descendants(self.pid)[1:]      # the tree below the wrapper process
            vals = [_rollup_kb(p) for p in pids]
            for p, (r, _) in zip(pids, vals):
                if r and r > self.peak_rss_kb_by_pid.get(p, (0, ""))[0]:
                    self.peak_rss_kb_by_pid[p] = (r, self.peak_rss_kb_by_pid.get(p, (0, None))[1] or _cmdline(p))
            live = sum(1 for r, _ in vals if r)
            self.peak_rss_sum_kb = max(self.peak_rss_sum_kb, sum(r for r, _ in vals))
            self.peak_pss_kb = max(self.peak_pss_kb, sum(p for _, p in vals))
            self.peak_processes = max(self.peak_processes, live)
            self.samples += 1
            if self._stop_event.wait(self.interval):
                break

    def stop(self):
        self._stop_event.set()
        self.join()


@dataclass
class RunResult:
    """One measured subprocess (see the module docstring for the definitions)."""

    cmd: list
    returncode: int
    wall_s: float
    user_s: float
    sys_s: float
    max_rss_bytes: int
    peak_tree_pss_bytes: int | None = None
    peak_tree_rss_sum_bytes: int | None = None
    peak_tree_processes: int | None = None
    pss_samples: int = 0
    outer_wall_s: float | None = None
    stdout: str = ""
    stderr: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def peak_memory_bytes(self) -> int:
        """The larger of peak RSS and sampled peak tree PSS (a conservative single number)."""
        return max(self.max_rss_bytes, self.peak_tree_pss_bytes or 0)

    def to_dict(self, *, output: bool = False) -> dict:
        d = asdict(self)
        d["peak_memory_bytes"] = self.peak_memory_bytes
        if not output:
            d.pop("stdout")
            d["stderr_tail"] = d.pop("stderr")[-2000:]
        return d


# Runs the measured command for run_measured.  Why a separate small process: on exec, Linux
# folds the high-water RSS of the address space being replaced into the new program's
# ru_maxrss, and Python starts children with vfork/posix_spawn, so a child started directly
# from a big benchmark process (e.g. one holding a 2 GB GEMM operand) would report at least the
# benchmark's own peak.  This wrapper (python -I -S, ~10 MB) spawns the command instead, so the
# floor is the wrapper's size; it times the command and reports wait4's rusage.
_WRAPPER = r"""  # USDBTF_PARENT_PID: usdbtf.lifetime.PARENT_ENV
import os, sys, time
out, cmd = sys.argv[1], sys.argv[2:]
t = time.perf_counter()
try:
    pid = os.posix_spawnp(cmd[0], cmd, dict(os.environ, USDBTF_PARENT_PID=str(os.getpid())))
except OSError as exc:
    sys.stderr.write(f"cannot run {cmd[0]}: {exc}\n")
    sys.exit(127)
while True:
    try:
        _, status, ru = os.wait4(pid, 0)
        break
    except InterruptedError:
        pass
wall = time.perf_counter() - t
with open(out, "w") as fh:
    fh.write(f"{wall!r} {status} {ru.ru_maxrss} {ru.ru_utime!r} {ru.ru_stime!r}\n")
code = os.waitstatus_to_exitcode(status)
sys.exit(code if code >= 0 else 128 - code)
"""


def run_measured(cmd, *, cwd=None, env=None, pss_interval: float = 0.2) -> RunResult:
    """Run ``cmd`` (list) and measure wall time, CPU time, peak RSS and sampled peak tree PSS.

    The command runs under a tiny wrapper process (see ``_WRAPPER``) that reaps it with
    ``os.wait4``: the rusage is exactly this command's (plus the descendants it reaped), and
    the wall time excludes the wrapper's own start.  stdout/stderr go to temporary files (no
    pipe can fill up) and are returned as text.  ``pss_interval`` 0 disables the /proc sampler
    (it costs a few ms of CPU per sample).
    """
    cmd = [os.fspath(c) for c in cmd]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err, \
            tempfile.NamedTemporaryFile("r", suffix=".rusage") as res:
        t0 = time.perf_counter()
        # The wrapper dies with this process, and a usdbtf command it runs with the wrapper
        # (usdbtf.lifetime: the wrapper names itself in PARENT_ENV).
        proc = subprocess.Popen([sys.executable, "-I", "-S", "-c", _WRAPPER, res.name, *cmd], cwd=cwd, env=env,
                                stdout=out, stderr=err, stdin=subprocess.DEVNULL, **dying_with_parent())
        sampler = _TreeSampler(proc.pid, pss_interval) if pss_interval > 0 else None
        if sampler is not None:
            sampler.start()
        try:
            proc.wait()
        except BaseException:
            proc.kill()
            proc.wait()
            raise
        finally:
            outer = time.perf_counter() - t0
            if sampler is not None:
                sampler.stop()
        out.seek(0)
        err.seek(0)
        stdout = out.read().decode(errors="replace")
        stderr = err.read().decode(errors="replace")
        fields = res.read().split()
    if len(fields) == 5:
        wall, maxrss_kb, user, system = float(fields[0]), int(fields[2]), float(fields[3]), float(fields[4])
    else:                                    # the wrapper itself failed: no measurement
        wall, maxrss_kb, user, system = outer, 0, float("nan"), float("nan")
    use = sampler is not None and sampler.available and sampler.samples > 0
    return RunResult(cmd=cmd, returncode=proc.returncode, wall_s=wall, user_s=user, sys_s=system,
                     max_rss_bytes=maxrss_kb * 1024,          # Linux: kilobytes
                     peak_tree_pss_bytes=sampler.peak_pss_kb * 1024 if use else None,
                     peak_tree_rss_sum_bytes=sampler.peak_rss_sum_kb * 1024 if use else None,
                     peak_tree_processes=sampler.peak_processes if use else None,
                     pss_samples=sampler.samples if sampler else 0, outer_wall_s=outer,
                     stdout=stdout, stderr=stderr,
                     extra={"peak_rss_by_process": [{"pid": p, "peak_rss_bytes": kb * 1024, "cmd": cmd} for p, (kb, cmd)
                                                    in sorted(sampler.peak_rss_kb_by_pid.items())]} if use else {})


def cli_command(name: str = "usdbtf") -> list:
    """The console script next to this interpreter (or in the checkout's .venv), else
    ``python -m usdbtf.cli`` with this interpreter; with ``--force``, because benchmarks
    rerun commands into their own outputs, and ``--allow-outside-paths``, because their
    subset manifests name the images of the full dataset."""
    candidates = [Path(sys.executable).parent / name]
    if REPO is not None:
        candidates.append(REPO / ".venv" / "bin" / name)
    for exe in candidates:
        if exe.is_file() and os.access(exe, os.X_OK):
            return [str(exe), "--force", "--allow-outside-paths"]
    return [sys.executable, "-m", "usdbtf.cli", "--force", "--allow-outside-paths"]


# -- files -------------------------------------------------------------------------------------
def warm_page_cache(folder) -> dict:
    """Read every file under ``folder`` once (so timed runs do not measure a cold disk)."""
    t = time.perf_counter()
    total = files = 0
    buf = bytearray(1 << 20)
    for d, _, names in os.walk(folder):
        for n in names:
            with open(os.path.join(d, n), "rb", buffering=0) as fh:
                while True:
                    got = fh.readinto(buf)
                    if not got:
                        break
                    total += got
            files += 1
    return {"files": files, "bytes": total, "seconds": time.perf_counter() - t}


def timestamp() -> str:
    return _dt.datetime.now().strftime("%Y%m%d-%H%M%S")


def write_json(path, doc) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1, default=_json_default) + "\n")
    os.replace(tmp, path)
    return path


def _json_default(o):
    try:
        import numpy as np
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:
        pass
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def fmt_bytes(n) -> str:
    """Decimal units: 530.8 MB, 1.23 GB."""
    if n is None:
        return "n/a"
    n = float(n)
    for unit, div in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if abs(n) >= div:
            return f"{n / div:.{2 if unit == 'GB' else 1}f} {unit}"
    return f"{n:.0f} B"


def run_repeated(cmd, repeats: int, *, pss_interval: float = 0.2, on_run=None) -> dict:
    """Run ``cmd`` ``repeats`` times with :func:`run_measured`; stop at the first failure.

    ``cmd`` is one argv list, or a callable ``cmd(i)`` giving repeat ``i``'s argv (0-based).
    ``on_run(i, RunResult)`` is called after each successful run (e.g. to read its output).
    Returns {"command", "runs", "wall_s_samples", "wall_s_median", "wall_s_min", "wall_s_max",
    "user_s_median", "sys_s_median", "cpu_s_median", "max_rss_bytes", "peak_tree_pss_bytes",
    "peak_memory_bytes" (worst run), "stderr" (last run's)} plus "error" (stderr tail) on failure.
    """
    argv = cmd if callable(cmd) else (lambda i: cmd)
    runs = []
    for i in range(repeats):
        r = run_measured(argv(i), pss_interval=pss_interval)
        runs.append(r)
        if r.returncode != 0:
            break
        if on_run is not None:
            on_run(i, r)
    walls = [x.wall_s for x in runs]
    res = {
        "command": " ".join(runs[0].cmd),
        "runs": [x.to_dict() for x in runs],
        "wall_s_samples": walls,
        "wall_s_median": median(walls),
        "wall_s_min": min(walls),
        "wall_s_max": max(walls),
        "user_s_median": median(x.user_s for x in runs),
        "sys_s_median": median(x.sys_s for x in runs),
        "cpu_s_median": median(x.user_s + x.sys_s for x in runs),
        "max_rss_bytes": max(x.max_rss_bytes for x in runs),
        "peak_tree_pss_bytes": max((x.peak_tree_pss_bytes or 0) for x in runs) or None,
        "peak_memory_bytes": max(x.peak_memory_bytes for x in runs),
        "stderr": runs[-1].stderr,
    }
    if runs[-1].returncode != 0:
        res["error"] = runs[-1].stderr[-3000:] or f"exit status {runs[-1].returncode}"
    return res


def run_repeated_apart(command, out, repeats: int, *, pss_interval: float = 0.2) -> tuple[dict, Path]:
    """:func:`run_repeated` with each repeat writing an output of its own.

    ``command(path)`` is the argv that writes its output at ``path``; repeat ``i`` (from 1)
    writes ``out / "run<i>"``, a path no earlier run used.  So a repeat never replaces an
    earlier one's output: every timed run does the same work (writing a new output, as a
    first run does), and an output kind the output guard would not replace cannot stop a
    benchmark.  Each earlier repeat's output is removed once the next one has succeeded
    (untimed, between runs), so at most two are on disk.

    Returns (run_repeated's dict, the folder of the last run: the one that failed, or the
    output to evaluate).
    """
    paths = [Path(out) / f"run{i + 1}" for i in range(repeats)]

    def drop_previous(i, _run):
        if i > 0:
            shutil.rmtree(paths[i - 1], ignore_errors=True)

    res = run_repeated(lambda i: command(paths[i]), repeats, pss_interval=pss_interval, on_run=drop_previous)
    return res, paths[len(res["runs"]) - 1]


def failure_reason(res: dict) -> str:
    """The last non-blank line of a failed :func:`run_repeated`'s error (the command's one-line
    error message), or "?"."""
    lines = [x for x in res.get("error", "").strip().splitlines() if x.strip()]
    return lines[-1].strip() if lines else "?"
