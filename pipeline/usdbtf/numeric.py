"""The numeric platform: what, besides usdbtf's code and its inputs, decides the bits it writes.

Two libraries compute usdbtf's floating-point values with code chosen for the CPU they run on:

* the **BLAS** (OpenBLAS in numpy's wheels) picks a GEMM kernel per CPU family when it loads
  (``OPENBLAS_CORETYPE`` overrides the choice).  Kernels sum the products of a GEMM in
  different orders, so Haswell, SkylakeX, SandyBridge, Nehalem and Prescott each round a
  product their own way.  Its **thread count** can change the order too; usdbtf removes that
  by construction: every GEMM whose bits reach an output runs on one BLAS thread
  (:func:`usdbtf.compress.parallel.one_blas_thread`), cut into pieces of a fixed shape that
  usdbtf's own threads or Dask workers compute.
* **numpy** dispatches its elementwise loops to the widest SIMD level the CPU has (``X86_V3``:
  AVX2 and FMA; ``X86_V4``: AVX-512).  Its AVX-512 ``power`` (SVML) rounds differently from
  libm's, so usdbtf's curves use its float32 ``log`` and ``exp`` instead (numpy's own code:
  the same bits with AVX2 and AVX-512); below x86-64-v3 those are libm's, other bits again.

Both choices are made when the library loads, from the environment.  So that a farm of
mixed CPUs builds the same bytes, ``import usdbtf`` pins them (:func:`pin`), before numpy
loads and only where the user has not set them, to the **reference platform** x86-64-v3: the
``Haswell`` BLAS kernel and numpy at ``X86_V3``.  Every Intel CPU since Haswell (2013) and
every AMD CPU since Zen (2017) runs it, and it computes the same bits on all of them (IEEE
arithmetic, the same instructions in the same order).  ``USDBTF_NUMERIC=native`` keeps the
libraries' own choice (faster where AVX-512 pays, other bytes).  On a CPU below x86-64-v3,
or with a user's own ``OPENBLAS_CORETYPE``, the platform is that CPU's: its bytes are its own,
and :func:`platform` says so, for the Dask worker check, ``usdbtf --version --json``, the
compressed folder's provenance and ``build``'s signatures.

OpenCV's SIMD dispatch (colour transforms, table lookups) was checked not to change a bit
(``OPENCV_CPU_DISABLE`` down to SSE4.2 gave the same files), so it is not pinned.

One more library decides bytes without computing a float: **zlib**.  The asset's coefficient
and basis pages are deflated by Python's ``zlib`` module (:func:`usdbtf.imageio.encode_png_rle`),
which links the zlib of the Python build (the system's ``libz`` for a distribution's Python).
Another zlib may deflate other bytes for the same settings (zlib-ng's compatibility library,
which some newer distributions ship as ``libz``, does).  Rate control measures those bytes, so they can
move k too.  :func:`platform` records the runtime version, so the Dask worker check, the
provenance and ``build``'s signatures name a different one; the pixels are the same either way.
"""
from __future__ import annotations

import contextlib
import functools
import os
import sys
import threading

__all__ = ["REFERENCE", "pinned_environment", "pin", "platform", "platform_label", "platform_differences",
           "cpu_flags", "runs_reference", "is_reference", "PLATFORM_VARIABLES", "PLATFORM_NAMES", "runnable_kernels", "OPENBLAS_KERNEL_FLAGS", "one_blas_thread", "single_blas_thread"]

#: The reference platform's settings (x86-64-v3): the BLAS kernel and numpy's SIMD ceiling.
REFERENCE = {"blas_kernel": "Haswell", "numpy_simd": "X86_V3"}
#: numpy's dispatch targets above X86_V3, by the names numpy >= 2.4 uses and those before.
_ABOVE_V3 = {"new": ("X86_V4", "AVX512_ICL", "AVX512_SPR"),
             "old": ("AVX512F", "AVX512CD", "AVX512_KNL", "AVX512_KNM", "AVX512_SKX", "AVX512_CLX",
                     "AVX512_CNL", "AVX512_ICL", "AVX512_SPR", "AVX512FP16")}
#: /proc/cpuinfo flags of x86-64-v3 (lzcnt is ``abm`` there).
_V3_FLAGS = frozenset({"avx", "avx2", "fma", "bmi1", "bmi2", "f16c", "movbe", "abm", "sse4_2", "popcnt"})
#: OpenBLAS kernels (``OPENBLAS_CORETYPE``) and the /proc/cpuinfo flags each needs to run:
#: the CPUs the tests and bench_numeric emulate on one machine.
OPENBLAS_KERNEL_FLAGS = {"Haswell": frozenset({"avx2", "fma"}), "Zen": frozenset({"avx2", "fma"}),
                         "SkylakeX": frozenset({"avx512f", "avx512bw", "avx512vl", "avx512dq", "avx512cd"}),
                         "SandyBridge": frozenset({"avx"}), "Nehalem": frozenset({"sse4_2", "ssse3"}),
                         "Prescott": frozenset({"pni"})}
#: The keys of :func:`platform`, with the words messages use for them.
PLATFORM_NAMES = {"blas": "BLAS", "blas_kernel": "BLAS kernel", "numpy_simd": "numpy SIMD", "zlib": "zlib"}
#: The variables that choose the platform when the libraries load.
PLATFORM_VARIABLES = ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")
#: The opt-out: ``USDBTF_NUMERIC=native`` leaves the libraries' choices alone.
OPT_OUT = "USDBTF_NUMERIC"


@functools.lru_cache(maxsize=1)
def cpu_flags() -> frozenset:
    """The CPU's feature flags from /proc/cpuinfo (empty where there is none)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        pass
    return frozenset()


def runnable_kernels() -> list[str]:
    """The OpenBLAS kernels of :data:`OPENBLAS_KERNEL_FLAGS` this CPU can run."""
    return [name for name, need in OPENBLAS_KERNEL_FLAGS.items() if need <= cpu_flags()]


def runs_reference() -> bool:
    """Whether this CPU runs the reference platform (an x86-64 CPU with every v3 feature)."""
    import platform as _platform

    return _platform.machine().lower() in ("x86_64", "amd64") and _V3_FLAGS <= cpu_flags()


def _numpy_names() -> tuple:
    """numpy's names of its dispatch targets above X86_V3 (read from its metadata: numpy is
    not loaded yet when this is needed)."""
    try:
        from importlib.metadata import version

        major, minor = (int(p) for p in version("numpy").split(".")[:2])
    except Exception:       # noqa: BLE001 - no numpy metadata: the newer names
        return _ABOVE_V3["new"]
    return _ABOVE_V3["new"] if (major, minor) >= (2, 4) else _ABOVE_V3["old"]


def pinned_environment() -> dict[str, str]:
    """{variable: value} that pins the reference platform on this CPU; empty where the CPU
    cannot run it (below x86-64-v3, or not x86-64).  What ``usdbtf env`` prints and
    :func:`pin` applies."""
    if not runs_reference():
        return {}
    return {"OPENBLAS_CORETYPE": REFERENCE["blas_kernel"], "NPY_DISABLE_CPU_FEATURES": " ".join(_numpy_names())}


def pin(environ=None) -> dict[str, str]:
    """Set :func:`pinned_environment`'s variables that ``environ`` (default ``os.environ``)
    does not set already, while numpy is not loaded in this process and ``USDBTF_NUMERIC``
    is not ``native``.  Child processes (build steps, local Dask workers) inherit them.
    Returns what was set."""
    env = os.environ if environ is None else environ
    if env.get(OPT_OUT, "").strip().lower() == "native" or "numpy" in sys.modules:
        return {}
    # A user's own setting of a variable is theirs: the platform is then what it makes.
    wanted = {name: value for name, value in pinned_environment().items() if not env.get(name)}
    env.update(wanted)
    return wanted


@functools.lru_cache(maxsize=1)
def platform() -> dict[str, str]:
    """What decides the bits of this process's arithmetic, beside library versions:
    {"blas": library and version, "blas_kernel": the kernel it runs, "numpy_simd": the
    widest SIMD level numpy dispatches to, "zlib": the runtime version of the zlib that deflates
    the asset's pages}.  Loads numpy."""
    import zlib

    import numpy as np

    blas, kernel = "unknown", "unknown"
    lib = _numpy_blas(np)
    if lib is not None:
        blas = f"{lib.get('internal_api', '?')} {lib.get('version', '?')}"
        kernel = str(lib.get("architecture") or "unknown")
    return {"blas": blas, "blas_kernel": kernel, "numpy_simd": _numpy_simd(np), "zlib": zlib.ZLIB_RUNTIME_VERSION}


def _numpy_blas(np) -> dict | None:
    """threadpoolctl's record of the BLAS numpy calls: the one loaded from numpy's own files
    (other packages bring their own OpenBLAS -- OpenCV's wheels do -- which usdbtf's GEMMs
    never run), else the first BLAS loaded."""
    try:
        from threadpoolctl import threadpool_info

        libs = [lib for lib in threadpool_info() if lib.get("user_api") == "blas"]
    except Exception:       # noqa: BLE001 - threadpoolctl is a dependency; say unknown, not fail
        return None
    # Real paths on both sides: numpy imported through a symlinked environment (a venv linked
    # into a worktree) names its files by the link, the loader by the target or the link.
    home = os.path.dirname(os.path.dirname(os.path.realpath(np.__file__)))

    def folder(lib: dict) -> str:
        return os.path.dirname(os.path.realpath(lib.get("filepath") or "/"))

    mine = [lib for lib in libs if os.path.basename(folder(lib)).startswith("numpy")
            and os.path.dirname(folder(lib)) == home]
    return (mine or libs or [None])[0]


def _numpy_simd(np) -> str:
    """The widest dispatch target numpy runs here (``X86_V4``, ``X86_V3``, ``AVX512_SKX``...),
    ``baseline`` when it dispatches to none."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__ as targets, __cpu_features__ as have
    except ImportError:     # numpy < 2
        try:
            from numpy.core._multiarray_umath import __cpu_dispatch__ as targets, __cpu_features__ as have
        except ImportError:
            return "unknown"
    enabled = [name for name in targets if have.get(name)]
    return enabled[-1] if enabled else "baseline"


def is_reference(p: dict | None = None) -> bool:
    """Whether platform ``p`` (default this process's) is the reference platform."""
    p = p or platform()
    return all(p.get(key) == value for key, value in REFERENCE.items())


def platform_label(p: dict | None = None) -> str:
    """One line: ``openblas 0.3.31 kernel Haswell, numpy SIMD X86_V3``."""
    p = p or platform()
    return f"{p['blas']} kernel {p['blas_kernel']}, numpy SIMD {p['numpy_simd']}"


def platform_differences(theirs: dict, mine: dict) -> str:
    """What differs between two :func:`platform` dicts, naming both sides (empty when equal):
    ``BLAS kernel SkylakeX (here Haswell)``."""
    return ", ".join(f"{PLATFORM_NAMES.get(k, k)} {theirs.get(k, 'missing')} (here {mine[k]})"
                     for k in mine if theirs.get(k) != mine[k])


# -- thread counts -------------------------------------------------------------------------------
def single_blas_thread(fn):
    """Decorator: ``fn`` runs inside :func:`one_blas_thread` (a stage function whose output
    comes from GEMMs, for library callers outside the CLI)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)
    return wrapper


@contextlib.contextmanager
def one_blas_thread():
    """BLAS on one thread inside the block (threadpoolctl; a no-op where it is missing).

    Every GEMM whose bits reach an output runs inside one: a thread count changes how some
    kernels (OpenBLAS's Haswell among them) round a product, and usdbtf parallelises over
    pieces of a fixed shape itself.  The CLI runs every command in one; for library callers
    the stage functions take it themselves (:func:`single_blas_thread`: compress, synth,
    rectify, decompress and ``reconstruct``, unwrap, quilt, render, package and the fallback
    fit).  The BLAS thread count is a process-wide setting and threads enter and leave such
    blocks at once: the first to enter sets one thread, the last to leave puts back what was
    there.  Nested and concurrent blocks cost a lock and a counter (an outer block: 10 us)."""
    global _blas_depth, _blas_limiter
    controller = _controller()
    if controller is None:     # pragma: no cover - a declared dependency
        yield
        return
    with _blas_lock:
        if _blas_depth == 0:
            _blas_limiter = controller.limit(limits=1, user_api="blas")
        _blas_depth += 1
    try:
        yield
    finally:
        with _blas_lock:
            _blas_depth -= 1
            if _blas_depth == 0:
                _blas_limiter.restore_original_limits()
                _blas_limiter = None


_blas_lock = threading.Lock()
_blas_depth = 0
_blas_limiter = None


@functools.lru_cache(maxsize=1)
def _controller():
    """threadpoolctl's view of the loaded BLAS (scanning the libraries once per process)."""
    import numpy  # noqa: F401 - loads its BLAS first: threadpoolctl sees only loaded libraries

    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:        # pragma: no cover
        return None
    return ThreadpoolController()
