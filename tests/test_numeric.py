"""The numeric platform (usdbtf.numeric): the same bytes with any BLAS thread count, under every
OpenBLAS kernel this CPU runs, and on every machine of the reference platform; a Dask worker whose
platform would change bytes is refused by name.

Other CPUs are emulated the way OpenBLAS's dynamic-architecture builds allow: its kernel comes from
``OPENBLAS_CORETYPE`` when the library loads, so each run is a fresh process.
"""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from usdbtf import cluster, numeric
from usdbtf.cli import main
from usdbtf.compress.format import digest_without_platform
from usdbtf.errors import BTFError

#: The variables that choose the platform; a run starts from an environment without them.
PLATFORM_VARS = (*numeric.PLATFORM_VARIABLES, numeric.OPT_OUT, "OPENBLAS_NUM_THREADS",
                 "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def runnable(kernel: str) -> bool:
    return kernel in numeric.runnable_kernels()


def bare_env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in PLATFORM_VARS}
    return {**env, **{k: str(v) for k, v in extra.items()}}


def child_platform(env: dict) -> dict:
    code = ("import json, os, usdbtf; from usdbtf import numeric; "
            "print(json.dumps([numeric.platform(), {k: os.environ.get(k) for k in "
            "('OPENBLAS_CORETYPE', 'NPY_DISABLE_CPU_FEATURES')}]))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.mark.skipif(not numeric.runs_reference(), reason="this CPU is below x86-64-v3: no reference platform")
def test_import_pins_the_reference_platform_unless_told_otherwise():
    """``import usdbtf`` before numpy pins Haswell + numpy X86_V3; the user's own variable is
    kept; USDBTF_NUMERIC=native pins nothing."""
    plat, env = child_platform(bare_env())
    assert (plat["blas_kernel"], plat["numpy_simd"]) == ("Haswell", "X86_V3")
    assert env["OPENBLAS_CORETYPE"] == "Haswell"          # children (build steps, workers) inherit it
    plat, env = child_platform(bare_env(OPENBLAS_CORETYPE="Prescott"))
    assert env["OPENBLAS_CORETYPE"] == "Prescott" and plat["blas_kernel"] != "Haswell"
    assert plat["numpy_simd"] == "X86_V3"                 # the other variable is still pinned
    plat, env = child_platform(bare_env(USDBTF_NUMERIC="native"))
    assert env == {"OPENBLAS_CORETYPE": None, "NPY_DISABLE_CPU_FEATURES": None}


def test_version_json_reports_the_platform(capsys):
    assert main(["--version", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["usdbtf"] and doc["libraries"]["numpy"]
    assert {k: doc["numeric"][k] for k in numeric.platform()} == numeric.platform()
    assert doc["numeric"]["reference"] == (numeric.platform()["blas_kernel"] == "Haswell"
                                           and numeric.platform()["numpy_simd"] == "X86_V3")


# -- the same bytes under every kernel and thread count ------------------------------------------
@pytest.fixture(scope="module")
def small_btf(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("numeric") / "raw"
    assert main(["synth", "-q", "pebbles", "-o", str(out), "--sampling", "small", "--size", "24", "--seed", "5"]) == 0
    return out


def compress_in_child(src: Path, out: Path, **env) -> tuple[str, dict]:
    proc = subprocess.run([sys.executable, "-m", "usdbtf.cli", "compress", "-q", str(src), "-o", str(out),
                           "--k", "48"], capture_output=True, text=True, env=bare_env(**env), timeout=300)
    assert proc.returncode == 0, proc.stderr
    return digest_without_platform(out)


def test_compress_bytes_depend_on_the_platform_only(small_btf, tmp_path):
    """``compress --k 48`` with 1, 2 and 4 BLAS threads under the pinned platform and under every
    OpenBLAS kernel this CPU runs: every run of one platform writes the same bytes (threads never
    change a bit); the pinned run equals an explicit Haswell run (what every x86-64-v3 machine
    computes).  Kernels give other bytes where their arithmetic differs, and say so in the
    provenance: that is what the Dask check and build signatures compare."""
    runs = {}
    kernels = [None] + numeric.runnable_kernels()
    for kernel in kernels:
        for threads in (1, 2, 4) if kernel in (None, "Haswell") else (1, 4):
            env = {"OPENBLAS_NUM_THREADS": threads}
            if kernel:
                env["OPENBLAS_CORETYPE"] = kernel
            runs[kernel, threads] = compress_in_child(small_btf, tmp_path / f"{kernel}-{threads}", **env)
    by_platform = {}
    for (kernel, threads), (digest, platform) in runs.items():
        by_platform.setdefault(json.dumps(platform, sort_keys=True), set()).add(digest)
    assert all(len(digests) == 1 for digests in by_platform.values()), by_platform
    if numeric.runs_reference():
        assert runs[None, 1][1] == {**runs[None, 1][1], "blas_kernel": "Haswell", "numpy_simd": "X86_V3"}
        assert runs[None, 1][0] == runs["Haswell", 4][0]


def test_dask_worker_on_another_kernel_is_refused_naming_both(tmp_path):
    """A real worker process started with another BLAS kernel: the session refuses it in one
    line that names its kernel and this process's, and says how to start it."""
    from distributed import LocalCluster

    here = numeric.platform()["blas_kernel"]
    other = next((k for k in ("Nehalem", "Prescott", "SandyBridge") if runnable(k) and k != here), None)
    if other is None:
        pytest.skip("this CPU runs no second OpenBLAS kernel")
    with cluster.environ_kept():
        lc = LocalCluster(n_workers=0, processes=True, dashboard_address=":0", silence_logs=logging.ERROR)
    with lc:
        worker = subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", lc.scheduler_address,
                                   "--nthreads", "1", "--no-dashboard"],
                                  env={**os.environ, "OPENBLAS_CORETYPE": other},
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            with pytest.raises(BTFError) as info:
                with cluster.session(lc.scheduler_address, timeout=60):
                    pass
        finally:
            worker.terminate()
            worker.wait(30)
    message = str(info.value)
    assert "\n" not in message
    kernel_of = {"Nehalem": "Nehalem", "Prescott": "(Prescott|Katmai)", "SandyBridge": "Sandybridge|SandyBridge"}
    import re
    assert re.search(rf"BLAS kernel ({kernel_of[other]}) \(here {here}\)", message), message
    assert "usdbtf env" in message


_CURVES_PROBE = r"""
import usdbtf, hashlib, numpy as np
from usdbtf import numeric
from usdbtf.compress.domain import AUTO_CANDIDATES
x = np.random.default_rng(7).random((300, 97), dtype=np.float32) * np.float32(3)
x[::5] = 0
h = hashlib.sha256()
for d in AUTO_CANDIDATES:
    f = d.forward(x.copy())
    h.update(f.tobytes() + d.inverse(f).tobytes() + d.forward(x[:, ::3]).tobytes())
print(numeric.platform()["numpy_simd"], h.hexdigest())
"""


def test_domain_curves_have_the_same_bits_with_avx2_and_avx512():
    """The working-domain curves (every compress value goes through one) give the same bits
    with numpy's AVX-512 loops (``USDBTF_NUMERIC=native``) as on the reference platform: their
    power is numpy's own float32 log and exp, not ``power`` (whose AVX-512 SVML rounds
    differently from libm's).  Below x86-64-v3 (numpy's baseline loops call libm) the bits are
    that platform's own, as its BLAS's are, and still within float32 accuracy."""
    results = {}
    for label, env in (("native", bare_env(USDBTF_NUMERIC="native")), ("pinned", bare_env()),
                       ("baseline", bare_env(NPY_DISABLE_CPU_FEATURES="X86_V3 X86_V4 AVX512_ICL AVX512_SPR"))):
        proc = subprocess.run([sys.executable, "-c", _CURVES_PROBE], capture_output=True, text=True, env=env,
                              timeout=120)
        assert proc.returncode == 0, proc.stderr
        results[label] = proc.stdout.split()
    assert results["baseline"][0] == "baseline", results
    if numeric.runs_reference():
        assert results["pinned"][0] == "X86_V3"
        assert results["native"][1] == results["pinned"][1], results


def test_domain_power_is_accurate():
    """The curves' power against a float64 one: within 1e-5 relative wherever the result is a
    normal float32 (the curves feed 16-bit codes: a step is 1.5e-5 of full scale)."""
    import numpy as np

    from usdbtf.compress.domain import _power

    x = np.concatenate([np.geomspace(1e-30, 1e4, 200_001, dtype=np.float32), [0.0, -0.0, 1.0]]).astype(np.float32)
    for e in (1 / 1.6, 1 / 2.2, 1 / 2.4, 1.6, 2.2, 2.4, 4.0):
        want = np.power(x.astype(np.float64), float(np.float32(e)))
        got = _power(x.copy(), np.float32(e)).astype(np.float64)
        normal = (want > 1.2e-38) & (want < 3e38)
        rel = np.abs(got[normal] - want[normal]) / want[normal]
        assert rel.max() < 1e-5, (e, rel.max())
        assert got[-3] == 0 and not np.signbit(got[-2]) and got[-1] == 1
    strided = np.ones((4, 6), np.float32) * 4
    _power(strided[:, ::2], np.float32(0.5))
    assert (strided[:, ::2] == 2).all() and (strided[:, 1::2] == 4).all()


def test_platform_names_numpys_blas_through_a_symlinked_environment(tmp_path, monkeypatch):
    """The BLAS `platform()` records is numpy's own even when the environment is reached
    through a symlink (a venv linked into a worktree) and another package's OpenBLAS (OpenCV's
    wheels bring one) is listed first: the real paths are compared."""
    import numpy as np
    import threadpoolctl

    real = Path(os.path.realpath(np.__file__)).parent.parent          # site-packages
    linked = tmp_path / "site-packages"
    linked.symlink_to(real, target_is_directory=True)
    foreign = {"user_api": "blas", "internal_api": "openblas", "version": "0.3.15", "architecture": "Haswell",
               "filepath": str(tmp_path / "cv2" / "libopenblas.so")}
    ours = {"user_api": "blas", "internal_api": "openblas", "version": "0.3.31", "architecture": "Haswell",
            "filepath": str(linked / "numpy.libs" / "libscipy_openblas64_.so")}
    monkeypatch.setattr(threadpoolctl, "threadpool_info", lambda: [foreign, ours])
    assert numeric._numpy_blas(np)["version"] == "0.3.31"
    ours["filepath"] = str(real / "numpy.libs" / "libscipy_openblas64_.so")
    monkeypatch.setattr(np, "__file__", str(linked / "numpy" / "__init__.py"))
    assert numeric._numpy_blas(np)["version"] == "0.3.31"
