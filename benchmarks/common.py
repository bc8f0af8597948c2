"""Helpers shared by the benchmarks: what machine this is, timing, and memory of subprocesses.

Import from a benchmark script in this folder (``python benchmarks/bench_x.py`` puts the
folder on ``sys.path``)::

    from common import machine_info, format_machine, run_measured, time_call, median

Everything here is standard library (plus numpy for the BLAS description) so a
benchmark can describe the machine before it imports anything heavy.

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

import ctypes
import datetime as _dt
import importlib.metadata
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

__all__ = ["REPO", "OUT", "median", "time_call", "run_measured", "RunResult", "machine_info", "format_machine",
           "warm_page_cache", "dir_bytes", "timestamp", "write_json", "fmt_bytes", "cli_command"]

REPO = Path(__file__).resolve().parent.parent
OUT = REPO / "benchmarks" / "out"


# -- statistics --------------------------------------------------------------------------------
def median(values) -> float:
    values = [v for v in values if v is not None]
    return float(statistics.median(values)) if values else float("nan")


def time_call(fn, repeats: int = 5, warmup: int = 1) -> dict:
    """Time ``fn()`` in this process: ``warmup`` untimed calls, then ``repeats`` timed ones.

    Returns {"median_s", "min_s", "max_s", "samples_s", "warmup"}.
    """
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t)
    return {"median_s": median(samples), "min_s": min(samples), "max_s": max(samples),
            "samples_s": samples, "warmup": warmup}


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


class _TreeSampler(threading.Thread):
    """Samples the summed PSS/RSS of the descendants of ``pid`` (not ``pid`` itself) until stopped."""

    def __init__(self, pid: int, interval: float):
        super().__init__(daemon=True)
        self.pid, self.interval = pid, interval
        self.peak_pss_kb = self.peak_rss_sum_kb = 0
        self.peak_processes = 0
        self.samples = 0
        self.available = os.path.exists("/proc/self/smaps_rollup")
        self._stop_event = threading.Event()

    def run(self):
        while self.available:
            pids = _descendants(self.pid)[1:]      # the tree below the wrapper process
            vals = [_rollup_kb(p) for p in pids]
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
_WRAPPER = r"""
import os, sys, time
out, cmd = sys.argv[1], sys.argv[2:]
t = time.perf_counter()
try:
    pid = os.posix_spawnp(cmd[0], cmd, os.environ)
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
        proc = subprocess.Popen([sys.executable, "-I", "-S", "-c", _WRAPPER, res.name, *cmd], cwd=cwd, env=env,
                                stdout=out, stderr=err, stdin=subprocess.DEVNULL)
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
                     stdout=stdout, stderr=stderr)


def cli_command(name: str = "usdbtf") -> list:
    """The project's console script in .venv, else ``python -m usdbtf.cli`` with this interpreter."""
    exe = REPO / ".venv" / "bin" / name
    if exe.is_file() and os.access(exe, os.X_OK):
        return [str(exe)]
    return [sys.executable, "-m", "usdbtf.cli"]


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


def dir_bytes(folder) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(folder) for f in fs)


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


# -- machine -----------------------------------------------------------------------------------
def _read(path) -> str | None:
    try:
        return Path(path).read_text()
    except OSError:
        return None


def _cpu() -> dict:
    info = {"logical_cpus": os.cpu_count()}
    try:
        info["usable_cpus"] = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        info["usable_cpus"] = None
    text = _read("/proc/cpuinfo") or ""
    m = re.search(r"^model name\s*:\s*(.+)$", text, re.M)
    info["model"] = m.group(1).strip() if m else (platform.processor() or platform.machine())
    cores = set()
    phys = core = None
    for line in text.splitlines() + [""]:
        if line.startswith("physical id"):
            phys = line.split(":")[1].strip()
        elif line.startswith("core id"):
            core = line.split(":")[1].strip()
        elif not line.strip():
            if core is not None:
                cores.add((phys, core))
            phys = core = None
    info["physical_cores"] = len(cores) or None
    flags = re.search(r"^flags\s*:\s*(.+)$", text, re.M)
    if flags:
        have = set(flags.group(1).split())
        info["simd"] = [f for f in ("avx2", "fma", "avx512f", "avx512_bf16", "amx_tile") if f in have]
    quota = _read("/sys/fs/cgroup/cpu.max")
    if quota:
        q, period = quota.split()[:2]
        info["cgroup_cpu_quota"] = None if q == "max" else round(int(q) / int(period), 2)
    hyp = re.search(r"^flags\s*:.*\bhypervisor\b", text, re.M)
    info["virtualised"] = bool(hyp)
    return info


def _memory() -> dict:
    info = {}
    text = _read("/proc/meminfo") or ""
    for key, name in (("MemTotal", "total_bytes"), ("MemAvailable", "available_bytes_at_start")):
        m = re.search(rf"^{key}:\s*(\d+) kB", text, re.M)
        if m:
            info[name] = int(m.group(1)) * 1024
    limit = (_read("/sys/fs/cgroup/memory.max") or "").strip()
    if limit:
        info["cgroup_limit_bytes"] = None if limit == "max" else int(limit)
    return info


def _version(dist: str) -> str | None:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def _blas_runtime(np) -> dict:
    """Ask the BLAS library numpy actually loaded (OpenBLAS only) for its config and threads."""
    maps = _read("/proc/self/maps") or ""
    libs = sorted({line.split()[-1] for line in maps.splitlines()
                   if re.search(r"(openblas|mkl_rt|libblis|libblas|flexiblas)[^/]*\.so", line)})
    out = {"loaded_libraries": libs}
    for lib in libs:
        if "openblas" not in lib:
            continue
        try:
            dll = ctypes.CDLL(lib)
        except OSError:
            continue
        for prefix in ("scipy_", ""):
            for suffix in ("64_", ""):
                get_config = getattr(dll, f"{prefix}openblas_get_config{suffix}", None)
                if get_config is None:
                    continue
                get_config.restype = ctypes.c_char_p
                out["config"] = get_config().decode()
                core = getattr(dll, f"{prefix}openblas_get_corename{suffix}", None)
                if core is not None:
                    core.restype = ctypes.c_char_p
                    out["core"] = core().decode()
                threads = getattr(dll, f"{prefix}openblas_get_num_threads{suffix}", None)
                if threads is not None:
                    threads.restype = ctypes.c_int
                    out["threads"] = threads()
                return out
    return out


def machine_info(extra_packages=()) -> dict:
    """CPU, memory, OS, Python, package versions, numpy's BLAS (build and runtime), git state."""
    import numpy as np

    info = {"cpu": _cpu(), "memory": _memory(),
            "os": platform.platform(), "python": sys.version.split()[0], "python_executable": sys.executable}
    try:
        info["load_average_at_start"] = list(os.getloadavg())
    except OSError:
        pass
    pkgs = ["numpy", "OpenImageIO", "usd-core", "opencolorio", "matplotlib", "usdbtf", *extra_packages]
    info["versions"] = {p: _version(p) for p in pkgs}
    try:
        from pxr import Usd
        info["versions"]["pxr.Usd.GetVersion"] = ".".join(map(str, Usd.GetVersion()))
    except Exception:      # noqa: BLE001 - optional
        pass
    blas = {}
    try:
        deps = np.show_config(mode="dicts").get("Build Dependencies", {})
        b = deps.get("blas", {})
        blas["build"] = {k: b.get(k) for k in ("name", "version", "openblas configuration") if b.get(k)}
        simd = np.show_config(mode="dicts").get("SIMD Extensions", {})
        blas["numpy_simd_found"] = simd.get("found")
    except Exception:      # noqa: BLE001 - numpy < 1.26
        pass
    blas["runtime"] = _blas_runtime(np)
    blas["thread_env"] = {k: os.environ[k] for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                      "MKL_NUM_THREADS", "BLIS_NUM_THREADS") if k in os.environ}
    info["blas"] = blas
    info["git"] = _git()
    return info


def _git() -> dict:
    def git(*a):
        try:
            r = subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True, timeout=10)
            return r.stdout.strip() if r.returncode == 0 else None
        except (OSError, subprocess.SubprocessError):
            return None
    head = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": head, "dirty": bool(status) if head else None}


def format_machine(info: dict) -> str:
    """Human-readable lines (also fine as a markdown list)."""
    cpu, mem, blas = info["cpu"], info["memory"], info.get("blas", {})
    cores = f"{cpu.get('usable_cpus')} usable / {cpu.get('logical_cpus')} logical CPUs"
    if cpu.get("physical_cores"):
        cores += f", {cpu['physical_cores']} physical cores"
    if cpu.get("cgroup_cpu_quota"):
        cores += f", cgroup quota {cpu['cgroup_cpu_quota']} CPUs"
    ram = fmt_bytes(mem.get("total_bytes"))
    if mem.get("cgroup_limit_bytes"):
        ram += f" (cgroup limit {fmt_bytes(mem['cgroup_limit_bytes'])})"
    rt = blas.get("runtime", {})
    build = blas.get("build", {})
    blas_line = f"{build.get('name', '?')} {build.get('version', '')}".strip()
    if rt.get("config"):
        blas_line += f"; runtime: {rt['config'].strip()}"
    if rt.get("core"):
        blas_line += f", core {rt['core']}"
    if rt.get("threads") is not None:
        blas_line += f", {rt['threads']} threads"
    if blas.get("thread_env"):
        blas_line += f" (env {blas['thread_env']})"
    v = info.get("versions", {})
    vers = ", ".join(f"{k} {v[k]}" for k in ("numpy", "OpenImageIO", "usd-core", "opencolorio", "usdbtf") if v.get(k))
    lines = [
        f"- CPU: {cpu.get('model')} ({cores}{', virtualised' if cpu.get('virtualised') else ''}"
        f"{', ' + ' '.join(cpu['simd']) if cpu.get('simd') else ''})",
        f"- RAM: {ram}",
        f"- OS: {info.get('os')}; Python {info.get('python')}",
        f"- BLAS (numpy): {blas_line}",
        f"- versions: {vers}",
    ]
    if info.get("load_average_at_start"):
        lines.append("- load average at start: " + ", ".join(f"{x:.2f}" for x in info["load_average_at_start"]))
    g = info.get("git", {})
    lines.append(f"- git: {g.get('commit') or 'no commit'}{' (dirty)' if g.get('dirty') else ''}")
    return "\n".join(lines)


if __name__ == "__main__":
    print(format_machine(machine_info()))
