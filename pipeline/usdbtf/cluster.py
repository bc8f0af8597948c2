"""Dask clusters: the ``--dask ADDRESS`` option, parsed as data, and a checked session.

ADDRESS is one of

* ``tcp://HOST:PORT`` or ``tls://HOST:PORT``: a running ``dask scheduler`` (TLS takes its
  certificates from Dask's own configuration, ``distributed.comm.tls.*``);
* ``local:N``: a ``LocalCluster`` of N worker processes on this machine (one thread each),
  started for the command and torn down after it.

The text is parsed into a :class:`ClusterAddress` (scheme whitelist, host name or IP
address, port 1..65535, N 1..256) and rebuilt from those values; nothing of it reaches a
shell.  :func:`session` connects with a timeout (an unreachable scheduler is one error line,
exit status 74, within :data:`CONNECT_TIMEOUT` seconds), waits for a worker, and checks that
every worker runs the same usdbtf code and numeric libraries as this process
(:func:`environment`): the same code on the same libraries is what makes a distributed
result byte-identical to an in-process one.  Tasks check it again on the worker, so a worker
that joins later cannot slip through.

Dask is imported only here, and only when a session starts.
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import hashlib
import ipaddress
import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path

from . import numeric
from .atomic import raise_if_interrupted
from .errors import BTFError, IOFailure
from .lifetime import PARENT_ENV

log = logging.getLogger(__name__)

__all__ = ["ClusterAddress", "parse_address", "session", "environment", "require_environment", "environ_kept",
           "command_info", "run_command", "polled", "CONNECT_TIMEOUT",
           "MAX_LOCAL_WORKERS", "ADDRESS_HELP"]

#: Seconds to reach a scheduler (and for it to have a worker) before giving up.
CONNECT_TIMEOUT = 5.0
#: Seconds a stopped local cluster gets for its workers to die and for its close.
STOP_TIMEOUT = 1.0
#: Largest N of ``local:N``.
MAX_LOCAL_WORKERS = 256
ADDRESS_HELP = ("run on a Dask cluster: tcp://HOST:PORT or tls://HOST:PORT (a running dask scheduler; workers "
                "need the same usdbtf and read the input paths) or local:N (N worker processes on this machine)")

_HOST_LABEL = re.compile(r"^(?!-)[A-Za-z0-9-]{1,63}(?<!-)$")


@dataclass(frozen=True)
class ClusterAddress:
    """A parsed ``--dask`` value: ``scheme`` "tcp", "tls" or "local"; ``host`` and ``port`` for
    a scheduler, ``workers`` for a local cluster."""

    scheme: str
    host: str | None = None
    port: int | None = None
    workers: int | None = None

    @property
    def local(self) -> bool:
        return self.scheme == "local"

    def __str__(self) -> str:
        if self.local:
            return f"local:{self.workers}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}"


def _bad(text: str, why: str) -> argparse.ArgumentTypeError:
    return argparse.ArgumentTypeError(f"{why}, got {text!r} (expected tcp://HOST:PORT, tls://HOST:PORT or local:N)")


def parse_address(text) -> ClusterAddress:
    """``--dask`` text -> :class:`ClusterAddress`; anything else is an argparse error (exit 2).

    Accepted: ``tcp://`` or ``tls://`` + a host name (letters, digits, '-', dots), an IPv4
    address or a bracketed IPv6 address + ``:PORT`` (1..65535); ``local:N`` (1..256)."""
    if isinstance(text, ClusterAddress):
        return text
    if not isinstance(text, str) or not text.isascii() or not text.isprintable() or len(text) > 300:
        raise _bad(str(text)[:80], "not an address")
    m = re.fullmatch(r"local:(\d{1,4})", text)
    if m:
        n = int(m.group(1))
        if not 1 <= n <= MAX_LOCAL_WORKERS:
            raise _bad(text, f"local:N needs 1 <= N <= {MAX_LOCAL_WORKERS}")
        return ClusterAddress("local", workers=n)
    m = re.fullmatch(r"(tcp|tls)://(\[[0-9A-Fa-f:.]+\]|[^:/\[\]@?#\s]+):(\d{1,5})", text)
    if not m:
        raise _bad(text, "not a scheduler address")
    scheme, host, port = m.group(1), m.group(2), int(m.group(3))
    if not 1 <= port <= 65535:
        raise _bad(text, "the port must be 1..65535")
    if host.startswith("["):
        try:
            host = str(ipaddress.IPv6Address(host[1:-1]))
        except ValueError:
            raise _bad(text, "not an IPv6 address") from None
    else:
        try:
            host = str(ipaddress.IPv4Address(host))
        except ValueError:
            labels = host.rstrip(".").split(".")
            if len(host) > 253 or not all(_HOST_LABEL.match(label) for label in labels) or labels[-1].isdigit():
                raise _bad(text, "not a host name or IP address") from None
    return ClusterAddress(scheme, host=host, port=port)


# -- the environment a worker must share -------------------------------------------------------
@functools.lru_cache(maxsize=1)
def environment() -> dict:
    """What makes results byte-identical across processes: usdbtf's version and a digest of
    its code, Python's version, the versions of the libraries that compute values, and the
    numeric platform (:func:`usdbtf.numeric.platform`: the BLAS, its kernel and numpy's SIMD
    level; thread counts change no bit, so they are not in it)."""
    import platform

    from . import __version__

    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    env = {"usdbtf": __version__, "usdbtf code": digest.hexdigest()[:16], "python": platform.python_version()}
    for name, module in (("numpy", "numpy"), ("OpenImageIO", "OpenImageIO"), ("opencolorio", "PyOpenColorIO"),
                         ("opencv", "cv2")):
        try:
            env[name] = str(__import__(module).__version__)
        except ImportError:
            env[name] = "missing"
    env.update(numeric.platform())
    return env


def _differences(theirs: dict, mine: dict) -> str:
    """What differs, each side named: the numeric platform first, in its own words."""
    names = set(numeric.PLATFORM_NAMES)
    plat = numeric.platform_differences({k: theirs.get(k, "missing") for k in names},
                                        {k: mine[k] for k in mine if k in names})
    rest = ", ".join(f"{k} {theirs.get(k, 'missing')} (here {mine[k]})"
                     for k in mine if k not in names and theirs.get(k) != mine[k])
    return ", ".join(part for part in (plat, rest) if part)


def _advice(theirs: dict, mine: dict) -> str:
    """How to make a worker match: the platform's variables when only they differ."""
    if all(theirs.get(k) == mine[k] for k in mine if k not in numeric.PLATFORM_NAMES):
        return ("its arithmetic would write other bytes: start it with the environment `usdbtf env` prints "
                "(the same OPENBLAS_CORETYPE and NPY_DISABLE_CPU_FEATURES as this process)")
    return "install the same usdbtf (and libraries) on every worker"



def require_environment(expected: dict, where: str) -> None:
    """Raise :class:`BTFError` when this process's :func:`environment` differs from ``expected``
    (run on a worker, ``where`` naming it)."""
    mine = environment()
    if mine != expected:
        raise BTFError(f"Dask worker {where}: its usdbtf, libraries or numeric platform differ from the "
                       f"client's: {_differences(mine, expected)}; {_advice(mine, expected)}")


def _worker_environment():
    return environment()


# -- sessions ------------------------------------------------------------------------------------
@contextlib.contextmanager
def session(address, *, timeout: float = CONNECT_TIMEOUT):
    """A checked Dask ``Client`` for ``address`` (text or :class:`ClusterAddress`), closed after.

    ``local:N`` starts a LocalCluster of N single-threaded worker processes (its dashboard on
    a free port when Bokeh is installed) and stops it after.  A scheduler that does not answer
    within ``timeout`` seconds, or that has no worker by then, is an :class:`IOFailure` (exit
    status 74: the network or the cluster failed, not the input data).  Workers whose
    :func:`environment` differs are refused (:class:`BTFError`, exit status 65).  The cluster and its
    dashboard link are logged (info).
    """
    addr = parse_address(address)
    quiet_logs = _quiet_dask_logs()
    with quiet_logs, contextlib.ExitStack() as stack:
        from distributed import Client, LocalCluster

        if addr.local:
            stop = _LocalStop()
            stack.enter_context(stop.on_error())        # last out: a cluster stopped while it starts
            cluster = polled(_new_local_cluster, LocalCluster, addr.workers)
            stack.push(lambda kind, exc, tb: cluster.close() if kind is None else None)
            client = stack.enter_context(polled(Client, cluster, timeout=timeout))
            stack.enter_context(stop.on_error())        # first out: workers killed before the client closes
        else:
            try:
                client = stack.enter_context(polled(Client, str(addr), timeout=timeout))
            except (OSError, TimeoutError) as exc:
                raise IOFailure(f"--dask {addr}: no Dask scheduler answered within {timeout:g} s "
                                f"({' '.join(str(exc).split())[:160]})") from None
        try:
            polled(client.wait_for_workers, 1, timeout=timeout)
        except (OSError, TimeoutError):
            raise IOFailure(f"--dask {addr}: the scheduler has no worker (waited {timeout:g} s); start "
                            f"`dask worker {addr}` on the machines that should work") from None
        mine = environment()
        for worker, theirs in sorted(polled(client.run, _worker_environment).items()):
            if theirs != mine:
                raise BTFError(f"--dask {addr}: worker {worker} differs from this process: "
                               f"{_differences(theirs, mine)}; {_advice(theirs, mine)}")
        info = client.scheduler_info()
        n = len(info.get("workers", {}))
        threads = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values())
        link = client.dashboard_link if _has_dashboard(client) else "none (install bokeh for one)"
        log.info(f"dask: {addr}: {n} worker(s), {threads} thread(s); dashboard {link}")
        yield client


def _new_local_cluster(local_cluster, workers: int):
    """A LocalCluster of ``workers`` single-threaded worker processes, each dying with this
    process (usdbtf.lifetime: the nannies give it PARENT_ENV, read by :func:`usdbtf.lifetime.dask_setup`)."""
    with environ_kept():
        return local_cluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                             silence_logs=logging.ERROR, env={PARENT_ENV: str(os.getpid())},
                             preload=["usdbtf.lifetime"])


#: Seconds between the main thread's looks at a signal while it waits for Dask (:func:`polled`).
POLL = 0.1


def polled(fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, called in a helper thread while the main thread waits for it in
    steps of :data:`POLL` seconds.

    Why: CPython runs signal handlers (a command's SIGTERM and SIGINT, :mod:`usdbtf.cli`) in
    the main thread only, when it next runs Python code, while the kernel hands a process's
    signal to any of its threads.  Dask's blocking calls wait 10 s at a time, so a SIGTERM
    that lands on one of Dask's threads would wait up to 10 s; here it waits :data:`POLL`.
    Elsewhere than the main thread ``fn`` is simply called.  Stopped by a signal, the main
    thread goes on (the exception) and leaves the helper thread to end with the process.
    """
    import threading

    if threading.current_thread() is not threading.main_thread():
        return fn(*args, **kwargs)
    box: dict = {}

    def run():
        try:
            box["value"] = fn(*args, **kwargs)
        except BaseException as exc:     # noqa: BLE001 - handed to the caller
            box["error"] = exc

    helper = threading.Thread(target=run, name=f"usdbtf-{getattr(fn, '__name__', 'dask')}", daemon=True)
    helper.start()
    while helper.is_alive():
        helper.join(POLL)
    if "error" in box:
        raise box.pop("error")
    return box["value"]


class _LocalStop:
    """Stops a local cluster at once when its session ends by an exception (SIGTERM and SIGINT
    are exceptions in a command): a farm's stop must be over in seconds, while the cluster's
    own close is graceful (workers finish, nannies wait) and, for a cluster stopped while it
    starts, is left to an ``atexit`` hook of Dask's that waits up to 10 s and then fails.

    So: the processes this one started since the session began (the workers: found by a
    walk of this process's descendants) are killed, nannies
    are told not to restart them, and each cluster started meanwhile is closed with a
    :data:`STOP_TIMEOUT` (its errors ignored: a half-started cluster cannot close cleanly)."""

    def __init__(self):
        import psutil      # a dependency of distributed

        self.me = psutil.Process()
        self.before = {(p.pid, _started(p)) for p in self.me.children(recursive=True)}
        self.clusters_before = set(_cluster_instances())

    @contextlib.contextmanager
    def on_error(self):
        try:
            yield
        except BaseException:
            self.stop()
            # A signal whose exception Python dropped (usdbtf.atomic.interrupt: one that arrives
            # while Dask forks) leaves Dask failing in its stead: the signal is what stopped it.
            raise_if_interrupted()
            raise

    def stop(self) -> None:
        import psutil

        clusters = [c for c in _cluster_instances() if c not in self.clusters_before]
        for cluster in clusters:
            cluster.shutdown_on_close = False       # no graceful close at exit: it is done here
            for nanny in list(getattr(cluster, "workers", {}).values()):
                with contextlib.suppress(Exception):
                    nanny.close_gracefully("usdbtf: stopped")    # a killed worker is not restarted
        self._kill_started()
        for cluster in clusters:
            with contextlib.suppress(Exception):
                cluster.close(timeout=STOP_TIMEOUT)
        # Again: a nanny that was starting its worker (a cluster stopped while it starts) may
        # have spawned it meanwhile.
        self._kill_started()

    def _kill_started(self) -> None:
        import psutil

        # Not Python's resource tracker: shared by all of this process's spawned children, it ends
        # by itself when they and this process have exited (killed, it is started again, and complains).
        procs = [p for p in self.me.children(recursive=True)
                 if (p.pid, _started(p)) not in self.before and not _resource_tracker(p)]
        for proc in procs:
            with contextlib.suppress(psutil.Error):
                proc.kill()
        psutil.wait_procs(procs, timeout=STOP_TIMEOUT)


def _started(proc) -> float:
    try:
        return proc.create_time()
    except Exception:        # noqa: BLE001 - gone already
        return 0.0


def _resource_tracker(proc) -> bool:
    try:
        return any("resource_tracker" in word for word in proc.cmdline())
    except Exception:        # noqa: BLE001 - gone already
        return False


def _cluster_instances() -> list:
    """Dask's live clusters of this process (``SpecCluster._instances``, a weak set: there is
    no public list, and a cluster stopped inside its constructor is reachable only there)."""
    from distributed.deploy.spec import SpecCluster

    return list(getattr(SpecCluster, "_instances", ()))


@contextlib.contextmanager
def environ_kept():
    """Starting a LocalCluster sets ``OMP_NUM_THREADS=1`` and friends in this process's
    environment (for its workers); put it back, so that the processes this one starts later
    (``build``'s steps) get the environment it had."""
    import os

    saved = dict(os.environ)
    try:
        yield
    finally:
        for key in set(os.environ) - set(saved):
            del os.environ[key]
        os.environ.update(saved)


def _has_dashboard(client) -> bool:
    """The scheduler serves Dask's dashboard (it needs Bokeh where the scheduler runs)."""
    if "dashboard" not in client.scheduler_info().get("services", {}):
        return False
    try:
        return bool(client.run_on_scheduler(_bokeh_installed))
    except Exception:          # noqa: BLE001 - a scheduler that refuses run_on_scheduler: say none
        return False


def _bokeh_installed() -> bool:
    import importlib.util

    return importlib.util.find_spec("bokeh") is not None


@contextlib.contextmanager
def _quiet_dask_logs():
    """Dask's own INFO/WARNING lines (workers restarting, connections) stay out of the
    command's stderr; errors still reach it as usdbtf's one line."""
    loggers = [logging.getLogger(name) for name in ("distributed", "tornado", "bokeh")]
    old = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for lg, level in zip(loggers, old):
            lg.setLevel(level)


# -- usdbtf commands as tasks (``usdbtf build --dask``) --------------------------------------------
def command_info(client) -> tuple[dict, int]:
    """(what :func:`run_command` needs, a JSON-able dict; the cluster's thread count) for a
    checked ``client`` of :func:`session`."""
    info = client.scheduler_info()
    threads = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values()) or 1
    return {"scheduler": client.scheduler.address, "environment": environment()}, threads


_CLIENTS: dict = {}


def run_command(info: dict, argv: list, label: str) -> tuple[int, str]:
    """Run ``usdbtf ARGV`` as a task on the cluster of ``info`` (:func:`command_info`) and
    wait: (exit status, stderr).  Called from the build's SConstruct, one thread per job; a
    cluster that cannot be reached is status 74 with one ``usdbtf`` line."""
    import os
    import threading

    lock = _CLIENTS.setdefault("lock", threading.Lock())
    try:
        with lock, _quiet_dask_logs():
            client = _CLIENTS.get(info["scheduler"])
            if client is None:
                import atexit

                from distributed import Client

                client = _CLIENTS[info["scheduler"]] = Client(info["scheduler"], timeout=CONNECT_TIMEOUT)
                atexit.register(client.close)
        key = f"usdbtf-{'-'.join(label.split()[1:2])}-{os.urandom(4).hex()}"
        future = client.submit(_command_task, list(argv), info["environment"], pure=False, key=key)
        return future.result()
    except BTFError as exc:
        return exc.exit_code, f"usdbtf {argv[0]}: error: {' '.join(str(exc).split())}\n"
    except Exception as exc:    # noqa: BLE001 - unreachable scheduler, workers that keep dying: the cluster failed
        return 74, (f"usdbtf {argv[0]}: error: Dask scheduler {info['scheduler']}: {type(exc).__name__}: "
                    f"{' '.join(str(exc).split())[:300]}\n")


def _command_task(argv: list, expected: dict) -> tuple[int, str]:
    """On a worker: ``python -m usdbtf.cli ARGV`` (an argument list, no shell), after checking
    this worker's usdbtf and libraries.  (The worker's ``OMP_NUM_THREADS=1`` reaches the
    command; compress's bytes do not depend on thread counts.)"""
    import os
    import subprocess
    import sys
    import threading

    from .lifetime import child_environment

    try:
        from distributed import get_worker

        where = get_worker().address
    except (ImportError, ValueError):
        where = f"pid {os.getpid()}"
    require_environment(expected, where)
    env = dict(os.environ)
    pipeline = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = pipeline + os.pathsep + env.get("PYTHONPATH", "")
    if _task_cancelled():
        return 130, f"usdbtf {argv[0]}: interrupted\n"
    # The command dies with this worker (usdbtf.lifetime); and it is stopped (SIGTERM: it removes
    # its staging folder and lock, publishes nothing) once its client is gone or cancelled it.
    with subprocess.Popen([sys.executable, "-m", "usdbtf.cli", *argv], stdin=subprocess.DEVNULL,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                          env=child_environment(env)) as proc:
        errors: list = []
        reader = threading.Thread(target=lambda: errors.append(proc.stderr.read()), daemon=True)
        reader.start()
        while True:
            try:
                proc.wait(CANCEL_POLL)
                break
            except subprocess.TimeoutExpired:
                if _task_cancelled():
                    proc.terminate()
        reader.join()
    return proc.returncode, "".join(errors)


#: Seconds between a command task's checks that its client still wants it.
CANCEL_POLL = 0.1


def _task_cancelled() -> bool:
    """In a Dask task: its client cancelled it or is gone (the scheduler then releases the
    client's tasks, and the worker marks the running one cancelled)."""
    try:
        from distributed import get_worker
        from distributed.worker import thread_state

        task = get_worker().state.tasks.get(thread_state.key)
    except (ImportError, ValueError, AttributeError):     # not in a task
        return False
    return task is None or task.state in ("cancelled", "released", "forgotten")
