"""What machine a benchmark ran on: CPU, memory, OS, package versions, numpy's BLAS
(build and runtime, threads), git state.  ``format_machine`` gives markdown list lines."""
from __future__ import annotations

import ctypes
import importlib.metadata
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

from ..lifetime import dying_with_parent
from .measure import REPO, fmt_bytes

__all__ = ["machine_info", "format_machine"]


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
    from .. import numeric

    info["numeric_platform"] = numeric.platform()
    info["git"] = _git()
    return info


def _git() -> dict:
    if REPO is None:
        return {"commit": None, "dirty": None}

    def git(*a):
        try:
            r = subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True, timeout=10,
                               **dying_with_parent())
            return r.stdout.strip() if r.returncode == 0 else None
        except (OSError, subprocess.SubprocessError):
            return None
    head = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": head, "dirty": bool(status) if head else None}


def format_machine(info: dict) -> str:
    """Human-readable lines (also fine as a markdown list)."""
    from .. import numeric

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
        f"- numeric platform (decides the output bits): "
        f"{numeric.platform_label(info['numeric_platform']) if info.get('numeric_platform') else '?'}",
        f"- versions: {vers}",
    ]
    if info.get("load_average_at_start"):
        lines.append("- load average at start: " + ", ".join(f"{x:.2f}" for x in info["load_average_at_start"]))
    g = info.get("git", {})
    lines.append(f"- git: {g.get('commit') or 'no commit'}{' (dirty)' if g.get('dirty') else ''}")
    return "\n".join(lines)
