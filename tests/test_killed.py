"""Killed means stopped (issue 44): a job that a farm kills with SIGTERM (or Ctrl-C's SIGINT)
or SIGKILL leaves no process behind, no output written after the kill, and every output that
existed before byte for byte as it was; SIGTERM also leaves no lock and no staging folder,
and a re-run after either succeeds with the bytes of an undisturbed run.

Each multi-process command runs as a real process in its own session (``python -m
usdbtf.cli``): compress from a folder (forked decoders and encoders), from a zip (its zip
readers) and from a Bonn ``.btf`` (the UBO2014 reader, forked encoders), package of a quilted
mesh (forked texture encoders), build (SCons and the ``usdbtf`` steps it runs), render of a
scene's frames, compress ``--dask local:2`` (a local Dask cluster).  It is killed at a moment
the test watches for, not after a fixed sleep (a loaded machine only makes the run slower):
*early* once the output's lock exists (build: once SCons runs), *mid* once a worker process
runs (render, which has none: once the first frame is written), *writing* once a staging
folder exists beside an output.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import psutil
import pytest

import bonn_btf_writer as bonn
from hostile_helpers import snapshot
from usdbtf.atomic import LOCK_TAG, TMP_TAG
from usdbtf.cli import main

ROOT = Path(__file__).resolve().parents[1]
#: Seconds a killed run has to be gone, children and all.
GONE_WITHIN = 5.0
#: Seconds the test then waits for anything that would still write.
QUIET_FOR = 1.5


def cli_ok(*argv) -> None:
    assert main([str(a) for a in argv]) == 0, argv


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """Small inputs of every kind: a 24-texel pebbles capture of the 13 x 13 ``small`` sampling
    (folder, UBO zip, Bonn DFMF ``.btf``); a 12-texel one (``src12``: the scene's material, and
    through its compress ``c`` a quilt on an unwrapped sphere), whose package and build steps
    spend less time fitting their fallbacks.
    """
    from quilt_render_data import write_sphere
    from usdbtf.io import open_btf

    root = tmp_path_factory.mktemp("killed_inputs")
    cli_ok("synth", "pebbles", "-o", root / "src", "--sampling", "small", "--size", 24, "-q")
    btf = open_btf(root / "src")
    # The same capture as a UBO2003 zip: one tv###_pv### folder per view, angles in the names.
    with zipfile.ZipFile(root / "src.zip", "w", zipfile.ZIP_STORED) as zf:
        for i, (path, view, light) in enumerate(zip(btf.paths, btf.sampling.view, btf.sampling.light)):
            tv, pv = (int(round(a)) % 360 for a in view)
            tl, pl = (int(round(a)) % 360 for a in light)
            zf.write(path, f"tv{tv:03d}_pv{pv:03d}/{i:05d} tl{tl:03d} pl{pl:03d} tv{tv:03d} pv{pv:03d}.png")
    # A Bonn DFMF file: 6 views x 6 lights of 24 x 24 texels, 8 components per channel.
    views = np.radians([[0, 0], [20, 0], [20, 120], [40, 60], [40, 240], [60, 180]])
    rgb = 0.1 + 0.7 * np.random.default_rng(4).random((36, 24 * 24, 3))
    channels = [bonn.factorise(bonn.rgb_to_model11(rgb)[..., c], 8) for c in range(3)]
    bonn.dfmf_file(root / "src.btf", channels, views_rad=views, lights_rad=views, width=24, height=24)
    cli_ok("synth", "pebbles", "-o", root / "src12", "--sampling", "small", "--size", 12, "-q")
    cli_ok("compress", root / "src12", "-o", root / "c", "--k", 6, "--codec", "png", "-q")
    write_sphere(root / "sphere.obj", radius=0.03, subdivisions=2)
    cli_ok("unwrap", root / "sphere.obj", "-o", root / "uv", "--btf", root / "c", "-q")
    cli_ok("quilt", root / "c", "--atlas", root / "uv" / "mesh.usda", "-o", root / "q", "--block", 4, "-q")
    return root


def _scene_home(i: Path, home: Path) -> None:
    """A scene with a build recipe for the capture, a moving camera over three frames, a light."""
    from usdbtf.bench.scenes import Quad, Shot, write_scene

    write_scene(home / "scene.usda", {"Pebbles": i / "src12"}, [Quad("Floor", "Pebbles", 0.05, (0, 0, 0))],
                [Shot("Cam", [(-0.01 + 0.01 * n, 0.0, 0.12) for n in range(3)], [(0, 0, 0)], fov=40)],
                frames=(1, 3), resolution=(48, 32), options="--k 4 --codec png")


class Case:
    """One command: ``argv`` run in ``home`` (a fresh copy per run of what ``setup`` puts there),
    the ``outputs`` it writes (relative to ``home``)."""

    def __init__(self, name, argv, outputs, *, previous=None, setup=None, timeout=120, same_as=None):
        self.name, self.argv, self.outputs = name, argv, outputs
        self.previous, self.setup, self.timeout = previous, setup, timeout
        #: A case whose undisturbed and previous outputs this one's are, byte for byte.
        self.same_as = same_as


def _compress(name, source, *extra, same_as=None):
    # A previous output (k 2) that the run replaces with --force: kept byte for byte until the swap.
    return Case(name, lambda i: ["compress", i / source, "-o", "C", "--k", 4, "--codec", "png", "--force", *extra],
                ["C"], previous=lambda i: ["compress", i / source, "-o", "C", "--k", 2, "--codec", "png"],
                same_as=same_as)


def _built_scene_home(i: Path, home: Path) -> None:
    shutil.copytree(_BUILT[i], home, dirs_exist_ok=True)


_BUILT: dict = {}

CASES = {c.name: c for c in [
    _compress("compress-folder", "src"),
    _compress("compress-zip", "src.zip"),
    _compress("compress-btf", "src.btf"),
    # A Dask compress writes the in-process bytes: its re-run is held to the folder case's.
    _compress("compress-dask", "src", "--dask", "local:2", same_as="compress-folder"),
    Case("package-quilt", lambda i: ["package", i / "q", "-o", "pkg/a.usda"], ["pkg"]),
    Case("build", lambda i: ["build", "scene.usda"], ["build"], setup=_scene_home),
    Case("render-frames", lambda i: ["render", "scene.usda", "--camera", "/World/Cam", "--frames", "1:3",
                                     "-o", "f.####.exr", "--threads", 2, "--force"],
         ["f.0001.exr", "f.0002.exr", "f.0003.exr", "f.0001.png", "f.0002.png", "f.0003.png"],
         setup=_built_scene_home),
]}

#: (case, signal, moment): every command with SIGTERM and SIGKILL, the moments spread over them
#: (once each where the processes are the same: compress-folder's SIGKILL at "mid" is
#: compress-zip's, build's SIGKILL at "mid" kills the same SCons and steps as at "writing").
RUNS = [
    ("compress-folder", "SIGTERM", "early"), ("compress-folder", "SIGTERM", "writing"),
    ("compress-folder", "SIGINT", "mid"), ("compress-folder", "SIGKILL", "writing"),
    ("compress-zip", "SIGTERM", "mid"), ("compress-zip", "SIGKILL", "mid"),
    ("compress-btf", "SIGTERM", "writing"), ("compress-btf", "SIGKILL", "writing"),
    ("package-quilt", "SIGTERM", "mid"), ("package-quilt", "SIGKILL", "writing"),
    ("build", "SIGTERM", "mid"), ("build", "SIGKILL", "writing"),
    ("render-frames", "SIGTERM", "mid"), ("render-frames", "SIGKILL", "writing"),
    ("compress-dask", "SIGTERM", "mid"),
    ("compress-dask", "SIGKILL", "writing"),
]


def _env() -> dict:
    return dict(os.environ, OCIO="ocio://default",
                PYTHONPATH=str(ROOT / "pipeline") + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _start(argv, home: Path) -> subprocess.Popen:
    """``usdbtf ARGV`` in ``home``, in a session of its own (its processes: that session)."""
    return subprocess.Popen([sys.executable, "-m", "usdbtf.cli", "-q", *map(str, argv)], cwd=home, env=_env(),
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _run(argv, home: Path, timeout: float = 180) -> None:
    proc = _start(argv, home)
    _, err = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, err


def _session(sid: int) -> list[psutil.Process]:
    """The live processes of session ``sid`` (zombies, already dead, are not counted)."""
    out = []
    for p in psutil.process_iter():
        try:
            if os.getsid(p.pid) == sid and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except (OSError, psutil.Error):
            continue
    return out


def _pieces(snap: dict) -> dict:
    """A folder's snapshot as {top-level entry: its own snapshot}."""
    out: dict = {}
    for key, value in snap.items():
        if key != ".":
            top, _, rest = key.partition("/")
            out.setdefault(top, {})[rest or "."] = value
    return out


def _alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.Error:
        return False


def _names(home: Path) -> list[Path]:
    return [Path(d) / n for d, dirs, files in os.walk(home) for n in dirs + files]


def _leftovers(home: Path) -> list[str]:
    return sorted(str(p.relative_to(home)) for p in _names(home) if TMP_TAG in p.name or p.name.endswith(LOCK_TAG))


def _reached(moment: str, proc: subprocess.Popen, home: Path, case: Case) -> bool:
    if moment == "early":
        if case.name == "build":
            return bool(_children(proc))
        return any(p.name.endswith(LOCK_TAG) for p in _names(home))
    if moment == "mid":
        if case.name == "render-frames":
            return (home / case.outputs[0]).exists()
        if case.name == "build":      # a usdbtf step that SCons runs
            return any("usdbtf.cli" in " ".join(_cmdline(c)) for c in _children(proc))
        return bool(_children(proc))
    return any(TMP_TAG in p.name for p in _names(home))


def _children(proc) -> list[psutil.Process]:
    try:
        return psutil.Process(proc.pid).children(recursive=True)
    except psutil.Error:
        return []


def _cmdline(p: psutil.Process) -> list[str]:
    try:
        return p.cmdline()
    except psutil.Error:
        return []


def _outputs(home: Path, case: Case) -> dict:
    """{output: its snapshot}, without what a killed run leaves inside an output folder."""
    return {o: {k: v for k, v in snapshot(home / o).items() if TMP_TAG not in k and LOCK_TAG not in k}
            for o in case.outputs}


@pytest.fixture(scope="module")
def clean(inputs, tmp_path_factory) -> dict:
    """{case: (the outputs of an undisturbed run, those of the previous run or {})}."""
    cache: dict = {}

    def get(case: Case):
        if case.same_as is not None:
            cache[case.name] = get(CASES[case.same_as])
            _PREVIOUS[case.name] = _PREVIOUS[case.same_as]
        if case.name not in cache:
            # At the depth of a test's home: outputs record their sources by relative path.
            home = tmp_path_factory.mktemp(f"clean_{case.name}") / "home"
            home.mkdir()
            if case.setup is not None:
                case.setup(inputs, home)
            if case.previous is not None:
                _run(case.previous(inputs), home)
                _PREVIOUS[case.name] = tmp_path_factory.mktemp(f"previous_{case.name}")
                for o in case.outputs:
                    shutil.copytree(home / o, _PREVIOUS[case.name] / o, symlinks=True)
            previous = _outputs(home, case) if case.previous else {}
            _run(case.argv(inputs), home, case.timeout)
            cache[case.name] = (_outputs(home, case), previous)
            if case.name == "build":
                _BUILT[inputs] = home
        return cache[case.name]

    return get


_PREVIOUS: dict = {}


def _prepare(case: Case, inputs: Path, home: Path) -> None:
    """What ``home`` holds before a run: the case's setup, a copy of the previous output."""
    if case.setup is not None:
        case.setup(inputs, home)
    if case.previous is not None:
        for o in case.outputs:
            shutil.copytree(_PREVIOUS[case.name] / o, home / o, symlinks=True)


@pytest.mark.parametrize("name,sig,moment", RUNS,
                         ids=["-".join(r.values if hasattr(r, "values") else r) for r in RUNS])
def test_a_killed_run_stops_and_the_next_one_succeeds(inputs, clean, tmp_path, name, sig, moment):
    case = CASES[name]
    if name == "render-frames":
        clean(CASES["build"])                   # the built scene it renders
    want, previous = clean(case)
    home = tmp_path / "home"
    home.mkdir()
    _prepare(case, inputs, home)
    before = _outputs(home, case)
    assert before == (previous or before)

    proc = _start(case.argv(inputs), home)
    deadline = time.monotonic() + 120
    seen = set()
    while not _reached(moment, proc, home, case):
        seen.update(c.pid for c in _children(proc))
        assert proc.poll() is None, f"the run ended before the {moment} moment: {proc.stderr.read()}"
        assert time.monotonic() < deadline, f"no {moment} moment within 120 s"
        time.sleep(0.002)
    os.kill(proc.pid, getattr(signal, sig))
    killed = time.monotonic()
    try:
        code = proc.wait(timeout=GONE_WITHIN)
    except subprocess.TimeoutExpired:
        code = None
    # Every process of the run is gone within GONE_WITHIN seconds of the signal.
    while _session(proc.pid) and time.monotonic() < killed + GONE_WITHIN:
        time.sleep(0.05)
    left = [(p.pid, _cmdline(p)[:4]) for p in _session(proc.pid)] + \
        [(pid, "(a child seen during the run)") for pid in seen if _alive(pid)]
    err = proc.stderr.read() if code is not None else ""
    assert not left, f"processes left {time.monotonic() - killed:.1f} s after {sig}: {left}; stderr {err}"
    assert code == {"SIGTERM": 143, "SIGINT": 130, "SIGKILL": -9}[sig], err
    if sig != "SIGKILL":
        assert err.strip().splitlines()[-1] in (f"usdbtf {case.argv(inputs)[0]}: terminated",
                                                 f"usdbtf {case.argv(inputs)[0]}: interrupted"), err
        # A stopped command removes its locks and staging folders (its steps' too).
        assert _leftovers(home) == []
    # Nothing is written after the kill: the folder stays as it was left.
    after = snapshot(home)
    time.sleep(QUIET_FOR)
    assert snapshot(home) == after, "something was written after the run was killed"
    # Each output is as it was before, or the undisturbed run's (a kill after its swap), never a mixture.
    got = _outputs(home, case)
    for o in case.outputs:
        if o == "build":     # the steps' outputs, each published on its own: each whole or absent
            for piece, files in _pieces(got[o]).items():
                if files != {".": "<dir>"} or sig != "SIGKILL":    # (SCons makes a target's folder first)
                    assert files in (_pieces(before[o]).get(piece), _pieces(want[o])[piece]), f"{o}/{piece}"
        elif got[o] != {".": "<dir>"} or before[o]:     # (a folder made for the output, left by SIGKILL)
            assert got[o] in (before[o], want[o]), f"{o}: neither the previous nor the new output"

    # The next run cleans what the killed one left and writes the undisturbed run's bytes.
    _run(case.argv(inputs), home, case.timeout)
    assert _outputs(home, case) == want
    assert _leftovers(home) == []


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def remote_worker():
    """A real ``dask scheduler`` and one ``dask worker`` (one thread), each its own process."""
    from distributed import Client

    bindir = Path(sys.executable).parent
    address = f"tcp://127.0.0.1:{_free_port()}"
    common = dict(env=_env(), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                  start_new_session=True)
    procs = [subprocess.Popen([str(bindir / "dask"), "scheduler", "--host", "127.0.0.1", "--port",
                               address.rsplit(":", 1)[1], "--no-dashboard"], **common)]
    try:
        procs.append(subprocess.Popen([str(bindir / "dask"), "worker", address, "--nthreads", "1", "--nworkers", "1",
                                       "--host", "127.0.0.1", "--no-dashboard", "--no-nanny"], **common))
        deadline = time.monotonic() + 60
        while True:
            try:
                with Client(address, timeout=5) as client:
                    client.wait_for_workers(1, timeout=max(1.0, deadline - time.monotonic()))
                break
            except OSError:
                assert time.monotonic() < deadline, "no Dask scheduler and worker within 60 s"
                time.sleep(0.3)
        yield address, procs[1]
    finally:
        for p in reversed(procs):
            p.kill()
            p.wait()


#: A client that runs one usdbtf command as a task (what ``build --dask``'s steps do) and waits.
_CLIENT = """import sys
from usdbtf.cluster import environment, run_command
status, err = run_command({"scheduler": sys.argv[1], "environment": environment()}, sys.argv[2:], "compress C")
sys.exit(status)
"""


def test_a_killed_remote_client_stops_its_task_on_the_worker(inputs, clean, remote_worker, tmp_path):
    """``--dask tcp://``: a client killed (SIGKILL: it cleans nothing) while its task's usdbtf
    command runs on a remote worker: the scheduler cancels the task, the worker stops the
    command (SIGTERM: it removes its staging folder and lock), nothing is written after, and
    the worker stays up for the next client, whose run gives the undisturbed bytes."""
    address, worker = remote_worker
    want, _ = clean(CASES["compress-folder"])
    home = tmp_path / "home"
    home.mkdir()
    argv = ["compress", inputs / "src", "-o", home / "C", "--k", 4, "--codec", "png", "--force"]
    client = subprocess.Popen([sys.executable, "-c", _CLIENT, address, *map(str, argv)], env=_env(),
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              start_new_session=True)
    deadline = time.monotonic() + 120
    # Killed once the command runs on the worker: it has seconds of work left, so an output
    # that appears was written after the kill.
    while not (steps := [c for c in psutil.Process(worker.pid).children(recursive=True)
                         if "usdbtf.cli" in _cmdline(c)]):
        assert client.poll() is None, client.stderr.read()
        assert time.monotonic() < deadline, "the command did not start on the worker within 120 s"
        time.sleep(0.002)
    client.kill()
    killed = time.monotonic()
    client.wait()
    gone, alive = psutil.wait_procs(steps, timeout=GONE_WITHIN)
    assert not alive, f"the command still runs {time.monotonic() - killed:.1f} s after its client was killed"
    assert _leftovers(home) == []
    after = snapshot(home)
    time.sleep(QUIET_FOR)
    assert snapshot(home) == after, "something was written after the client was killed"
    assert snapshot(home) == {".": "<dir>"}, "the stopped command wrote"
    assert worker.poll() is None
    _run(argv, home)        # the next run (here, not on the cluster) gives the undisturbed bytes
    assert _outputs(home, CASES["compress-folder"]) == want


#: A process that takes a frame through a rig's camera command (a program that is not usdbtf)
#: which takes a minute.
_GRABBER = """import sys
from usdbtf.rig.camera import CommandCamera
CommandCamera(sys.executable + " -c 'import time; time.sleep(60)' {out}", sys.argv[1]).grab("t", 0)
"""


@pytest.mark.parametrize("sig", ["SIGKILL", "SIGTERM"])
def test_a_program_usdbtf_starts_dies_with_it(tmp_path, sig):
    """A program that is not usdbtf (here a rig's camera command; Storm and Cycles renders,
    glslang and ffmpeg are started the same way, usdbtf.lifetime.dying_with_parent) dies with
    the process that started it, whichever way that one ends."""
    proc = subprocess.Popen([sys.executable, "-c", _GRABBER, str(tmp_path)], env=_env(), stdin=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 60
    while not (programs := [c for c in _children(proc) if "time.sleep(60)" in " ".join(_cmdline(c))]):
        assert proc.poll() is None and time.monotonic() < deadline, "the camera command did not start"
        time.sleep(0.01)
    os.kill(proc.pid, getattr(signal, sig))
    proc.wait(GONE_WITHIN)
    _, alive = psutil.wait_procs(programs, timeout=GONE_WITHIN)
    assert not alive, f"the camera command outlived its parent ({sig})"


def test_a_stop_that_surfaces_as_a_librarys_error_is_still_a_stop():
    """A SIGTERM that lands inside a library's clean-up can come out as that library's error
    (concurrent.futures: "cannot join thread before it is started" when the signal interrupts
    the start of its manager thread); the command still ends as terminated (143), not as an
    internal error (1)."""
    from usdbtf import cli

    with pytest.raises(cli.Terminated):
        with cli._signals_raise():
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(1)
            except cli.Terminated:
                pass                   # swallowed where it landed ...
            raise RuntimeError("cannot join thread before it is started")   # ... and replaced
    # Outside a command nothing is remembered.
    with cli._signals_raise():
        pass


#: A command's code that leaves a generator over a worker pool suspended, held by a reference
#: cycle (as a traceback can hold one when SIGTERM lands outside the generator, in a progress
#: bar), then stops: 20 queued items of 1 s each on 2 workers.
_LINGERING = """import os, sys, time
from usdbtf import cli
from usdbtf.compress.parallel import iter_processes

def slow(i):
    time.sleep(1.0)
    return os.getpid()

class Cycle:
    pass

try:
    with cli._pools_stopped_on_exception():
        results = iter_processes(slow, range(20), processes=2)
        print(next(results), flush=True)
        held = Cycle()
        held.me, held.results = held, results
        del held, results
        raise cli.Terminated()
except cli.Terminated:
    sys.exit(143)
"""


def test_a_stopped_command_stops_the_pool_a_suspended_generator_holds():
    """A pool whose generator an exception left suspended (held by a reference cycle, so not
    closed until a collection) is stopped as the command ends: without that, Python's exit
    waited for every item still queued, with the CLI and a worker alive 5 s after SIGTERM (the
    flaky package-quilt-SIGTERM-mid case)."""
    started = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", _LINGERING], env=_env(), stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    worker = int(proc.stdout.readline())
    code = proc.wait(timeout=30)
    took = time.monotonic() - started
    assert code == 143, proc.stderr.read()
    assert not _alive(worker) and not _session(proc.pid)
    assert took < 6.0, f"the command took {took:.1f} s to end: it waited for the queued items (10 s)"


#: A SIGTERM that lands just after a pool forks its first worker, before the pool records it:
#: the interruption the CLI's handler delivers, raised right after the fork returns.
_SIGNAL_AT_FORK = """
import multiprocessing.process as mpp, sys
from usdbtf import atomic, lifetime
from usdbtf.cli import Terminated
real = mpp.BaseProcess.start
def start(self):
    real(self)
    if not getattr(mpp, "_fired", False):
        mpp._fired = True
        print(self.pid, flush=True)
        atomic.interrupt(Terminated())
mpp.BaseProcess.start = start
try:
    with lifetime.forked_pool(2) as pool:
        pool.submit(int).result()
except Terminated:
    sys.exit(143)
"""


def test_a_signal_while_a_pool_forks_stops_every_worker():
    """A SIGTERM raised between a worker's fork and the pool's record of it left a worker no
    stop_pool killed, which multiprocessing's exit then joined for ever (the flaky
    compress-zip-SIGTERM-mid case: the command and a worker alive 5 s after SIGTERM).  The pool
    forks its workers in a critical section: the signal is raised once every one is recorded."""
    proc = subprocess.Popen([sys.executable, "-c", _SIGNAL_AT_FORK], env=_env(), stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    worker = int(proc.stdout.readline())
    try:
        code = proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail("the command did not end within 20 s of the signal: it waited for an unrecorded worker")
    assert code == 143, proc.stderr.read()
    deadline = time.monotonic() + 5
    while (_alive(worker) or _session(proc.pid)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(worker) and not _session(proc.pid)


def test_a_stale_lock_beside_an_unchanged_build_file_is_cleaned(tmp_path):
    """A build killed (SIGKILL) just after it swapped its SConstruct in leaves the lock file
    beside it; the next build finds the text unchanged and writes nothing, yet still cleans the
    lock and any staging folder the killed run left there."""
    from usdbtf.atomic import LOCK_TAG, TMP_TAG
    from usdbtf.usd.scenes.build import _write_if_changed

    path = tmp_path / "SConstruct"
    path.write_text("text\n")
    (tmp_path / f".SConstruct{LOCK_TAG}").write_text("")          # its holder is gone
    (tmp_path / f".SConstruct{TMP_TAG}dead").mkdir()
    _write_if_changed(path, "text\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["SConstruct"]
    assert path.read_text() == "text\n"
