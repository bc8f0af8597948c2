"""Every process usdbtf starts dies with the process that started it.

A farm stops a job with SIGTERM, then SIGKILL, sent to the job's main process.  Nothing the
job started may outlive it: an orphaned worker would keep the output's lock, or go on with
work nobody waits for.  So:

* **Forked children** (decode and encode pools, zip and UBO2014 readers): a fork hook
  (:func:`os.register_at_fork`) asks the kernel to SIGKILL the child when its parent dies
  (Linux ``prctl(PR_SET_PDEATHSIG)``) and exits at once if the parent is already gone (the
  signal only covers deaths after the call).  SIGTERM and SIGINT go back to their default in
  the child: a forked worker has nothing to clean up, so a signal simply ends it, and the
  handler it inherited from the command (which raises an exception to unwind the *parent's*
  ``with`` blocks) could otherwise send it on through the parent's code.
* **A pool that ends by an exception** (SIGTERM and SIGINT are exceptions in a command,
  :mod:`usdbtf.cli`) kills its workers at once (:func:`forked_pool`, :func:`stop_pool`)
  instead of waiting for the items they run: a stopped command stops now.  Its workers are
  forked together when it starts, in a critical section (:func:`signals_deferred`),
  so a signal never lands between a fork and the pool's record of the child.  A pool whose
  ``with`` block never ends -- a generator over it (:func:`usdbtf.compress.parallel.iter_processes`)
  left suspended when the exception was raised outside it, held by a reference cycle through
  the exception's traceback -- is stopped by the command on its way out
  (:func:`stop_live_pools`): else the interpreter's exit waits for every item still queued
  (a quilt's package went on encoding with its CLI and a worker alive 5 s after SIGTERM).
* **Other programs** (a Storm or Cycles frame render in a bpy Python, glslang, a rig's
  camera command, a benchmark's ffmpeg): :func:`dying_with_parent` sets the same kernel
  signal between the fork and the exec.
* **Programs started by usdbtf** (``build``'s SCons and the ``usdbtf`` steps it runs, a Dask
  worker's command): the parent puts its pid in :data:`PARENT_ENV`; the child calls
  :func:`adopt_parent_from_environment` first thing, which sets the same kernel signal (here
  SIGTERM, so that a ``usdbtf`` step still removes its own staging folder and lock) and
  exits if that parent is already gone.  The variable is removed from the child's
  environment, so grandchildren never see a pid that is not their parent's.

The kernel sends the signal when the *thread* that forked the child ends; usdbtf forks from
the thread that also waits for the child (the main thread, a SCons job thread, a Dask task).
Elsewhere than Linux the calls do nothing.
"""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import weakref

__all__ = ["PARENT_ENV", "die_with_parent", "adopt_parent_from_environment", "child_environment",
           "guarded_module_argv", "dying_with_parent", "running", "forked_pool", "stop_pool", "stop_live_pools",
           "dask_setup", "signals_deferred", "interrupt", "raise_if_interrupted", "interruption_forgotten"]

#: The environment variable through which a parent names itself to a program it starts.
PARENT_ENV = "USDBTF_PARENT_PID"
_PR_SET_PDEATHSIG = 1
_STATE: dict = {"prctl": None, "parent": None}


def _prctl():
    """libc's prctl, loaded once (in the parent: a child calls it right after the fork)."""
    if _STATE["prctl"] is None and sys.platform.startswith("linux"):
        import ctypes

        try:
            _STATE["prctl"] = ctypes.CDLL(None, use_errno=True).prctl
        except (OSError, AttributeError):       # pragma: no cover - no libc prctl
            _STATE["prctl"] = False
    return _STATE["prctl"] or None


def die_with_parent(parent: int, sig: int = signal.SIGKILL) -> None:
    """In a child: the kernel sends ``sig`` when the parent (pid ``parent``) dies; if it has
    died already (the child was reparented), ``sig`` now."""
    prctl = _prctl()
    if prctl is not None:
        prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if os.getppid() != parent:
        # Raised in this process as the kernel would have: SIGTERM runs a usdbtf command's cleanup.
        os.kill(os.getpid(), sig)
        if sig == signal.SIGKILL:       # pragma: no cover - not reached
            os._exit(128 + sig)


def _before_fork() -> None:
    _STATE["parent"] = os.getpid()
    _prctl()


def _after_fork_in_child() -> None:
    parent = _STATE["parent"]
    for sig in (signal.SIGTERM, signal.SIGINT):
        with contextlib.suppress(ValueError, OSError):
            if signal.getsignal(sig) not in (signal.SIG_IGN, None):
                signal.signal(sig, signal.SIG_DFL)
    if parent is not None:
        die_with_parent(parent, signal.SIGKILL)


os.register_at_fork(before=_before_fork, after_in_child=_after_fork_in_child)


def dying_with_parent(sig: int = signal.SIGKILL) -> dict:
    """Keyword arguments for :mod:`subprocess` (``preexec_fn``): the program it starts gets
    ``sig`` from the kernel when this process dies, or at once if it died before the exec.

    For programs that are not usdbtf and read no :data:`PARENT_ENV` (a Storm or Cycles frame
    render in a bpy Python, glslang, a rig's camera command, ffmpeg).  The kernel keeps the
    setting across the exec (not for a set-user-ID program).  Call it in the thread that
    waits for the program (``subprocess.run``): the signal comes when that thread ends."""
    parent = os.getpid()
    _prctl()        # loaded here: the child only calls it

    def in_child() -> None:
        die_with_parent(parent, sig)

    return {"preexec_fn": in_child}


def child_environment(env: dict | None = None) -> dict:
    """``env`` (default this process's environment) with :data:`PARENT_ENV` naming this
    process: for a program that calls :func:`adopt_parent_from_environment`."""
    out = dict(os.environ if env is None else env)
    out[PARENT_ENV] = str(os.getpid())
    return out


def adopt_parent_from_environment(sig: int = signal.SIGTERM) -> None:
    """First thing in a program usdbtf started: die with the parent :data:`PARENT_ENV` names
    (removed from the environment: this process's own children are not that parent's)."""
    text = os.environ.pop(PARENT_ENV, None)
    if text is None or not text.isdigit():
        return
    die_with_parent(int(text), sig)


#: Run a module as ``python -m`` does, after what :func:`adopt_parent_from_environment`
#: does (written out: usdbtf itself is not imported there); then :data:`PARENT_ENV` names
#: this process for the programs it starts.
_GUARD = """import ctypes, os, runpy, sys
parent = os.environ.pop({env!r}, "")
try:
    ctypes.CDLL(None).prctl({op}, {sig}, 0, 0, 0)
except (OSError, AttributeError):
    pass
if parent.isdigit() and os.getppid() != int(parent):
    os.kill(os.getpid(), {sig})
os.environ[{env!r}] = str(os.getpid())
sys.argv[0] = {module!r}
runpy.run_module({module!r}, run_name="__main__", alter_sys=True)
"""


def guarded_module_argv(module: str, *args, sig: int = signal.SIGKILL) -> list[str]:
    """``[python, -c, ..., *args]``: ``python -m module *args`` that dies (by ``sig``) with
    this process (start it with :func:`child_environment`), and whose own children are told
    its pid through :data:`PARENT_ENV` (``build`` runs SCons so: SCons has no cleanup of
    ours to run, its ``usdbtf`` steps get SIGTERM when it dies and remove their own)."""
    code = _GUARD.format(module=module, sig=int(sig), env=PARENT_ENV, op=_PR_SET_PDEATHSIG)
    return [sys.executable, "-c", code, *map(str, args)]


def running(pid: int) -> bool:
    """True when process ``pid`` exists and has not exited (a zombie, dead but not yet reaped
    by its parent, holds no file and counts as exited)."""
    if pid <= 0:
        return False
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read()
        return stat[stat.rindex(b")") + 2:][:1] not in (b"Z", b"X")
    except FileNotFoundError:
        return False
    except (OSError, ValueError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            return True
        return True


@contextlib.contextmanager
def forked_pool(workers: int, *, initializer=None, initargs=()):
    """A ``ProcessPoolExecutor`` of ``workers`` forked processes for the ``with`` block:
    shut down normally when the block ends, its workers killed at once (:func:`stop_pool`)
    when it ends by an exception (an error, SIGTERM, Ctrl-C, a generator closed early)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("fork"), initializer=initializer,
                               initargs=initargs)
    _LIVE_POOLS.add(pool)
    try:
        # Every worker forked now (a forking pool starts them all at its first item), in a
        # critical section: a SIGTERM raised between a fork and the pool's record of the child
        # left a worker that no stop_pool kills and that multiprocessing's exit then joins for
        # ever (compress of a zip, SIGTERM at its first child: the command and one worker alive
        # 5 s later, once in a full test run on a busy machine).  The signal is raised when the
        # section ends, with every worker recorded.
        with signals_deferred():
            pool.submit(int)
        yield pool
    except BaseException:
        stop_pool(pool)
        raise
    finally:
        _LIVE_POOLS.discard(pool)
    pool.shutdown(wait=True)


#: The :func:`forked_pool` pools whose ``with`` block has not ended (weak: a pool nothing holds
#: any more has no block left to end).
_LIVE_POOLS: "weakref.WeakSet" = weakref.WeakSet()


def stop_live_pools() -> int:
    """Stop every :func:`forked_pool` pool whose block has not ended (:func:`stop_pool`: workers
    killed, queued items dropped); returns how many.  A command calls it when it ends by an
    exception: a pool's block can outlive the exception when a generator holding it is left
    suspended in a reference cycle, and Python's exit then waits for the pool's queued items."""
    pools = list(_LIVE_POOLS)
    for pool in pools:
        _LIVE_POOLS.discard(pool)
        stop_pool(pool)
    return len(pools)


def stop_pool(pool) -> None:
    """Kill a ``ProcessPoolExecutor``'s workers and shut it down without running what is
    queued (the workers' current items are abandoned: nothing waits for them)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for proc in processes:
        with contextlib.suppress(Exception):
            proc.kill()
    pool.shutdown(wait=True, cancel_futures=True)
    for proc in processes:
        with contextlib.suppress(Exception):
            proc.join(1.0)


# ----------------------------------------------------------------------------- interruptions
# A command's signals as exceptions, held back through short critical sections (usdbtf.atomic
# takes and releases locks and commits outputs in them; forked_pool forks its workers in one).

_CRITICAL = {"depth": 0, "pending": None, "signalled": None}


@contextlib.contextmanager
def signals_deferred():
    """A short critical section (taking or releasing a lock, committing an output, forking a
    pool's workers): an interruption that :func:`interrupt` is asked to deliver meanwhile is
    raised when the outermost section ends, so no lock, half-moved output or unrecorded
    worker is left behind."""
    _CRITICAL["depth"] += 1
    try:
        yield
    finally:
        _CRITICAL["depth"] -= 1
        pending = _CRITICAL["pending"]
        if _CRITICAL["depth"] == 0 and pending is not None:
            _CRITICAL["pending"] = None
            raise pending


def interrupt(exc: BaseException) -> None:
    """Raise ``exc`` now, or when the current critical section ends (for signal handlers:
    the CLI turns SIGTERM and SIGINT into exceptions through this).

    ``exc`` is also kept until :func:`interruption_forgotten`: Python drops an exception
    raised where it cannot propagate (a signal that arrives while an ``os.fork`` hook of
    ``logging`` or ``concurrent.futures`` runs is printed and ignored), so
    :func:`raise_if_interrupted` raises it again where the work can stop: before an output
    is published, between a pool's results, when a command returns."""
    _CRITICAL["signalled"] = _CRITICAL.get("signalled") or exc
    if _CRITICAL["depth"]:
        _CRITICAL["pending"] = _CRITICAL["pending"] or exc
        return
    raise exc


def raise_if_interrupted() -> None:
    """Raise the interruption :func:`interrupt` was given, if any (outside a critical section)."""
    exc = _CRITICAL.get("signalled")
    if exc is not None and not _CRITICAL["depth"]:
        raise exc


def interruption_forgotten() -> None:
    """Start afresh (a command's start and end: :func:`usdbtf.cli.main` runs in tests many times)."""
    _CRITICAL["signalled"] = None


def dask_setup(worker) -> None:
    """A Dask preload hook (``preload=["usdbtf.lifetime"]``): a worker of a local cluster
    (:func:`usdbtf.cluster.session`) dies by SIGKILL with the process that started it, named
    by :data:`PARENT_ENV` (the nanny's ``env``).  Dask's own pipe to the parent ends it too,
    but only when its watching thread gets the GIL."""
    adopt_parent_from_environment(signal.SIGKILL)
