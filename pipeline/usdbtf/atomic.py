"""The single place that decides whether an output may be written, and writes it safely.

Every writer in usdbtf goes through :func:`atomic_dir`, :func:`atomic_file` or
:func:`atomic_group`; the CLI additionally :func:`claim`\\ s each ``-o`` before any work
starts, so a refusal costs nothing.

The policy (one set of rules for every command):

* An existing output is replaced only with ``force`` (``--force`` on the command line;
  library calls default to force) and only when it is a previous usdbtf output of the
  same kind, recognised by :func:`usdbtf.outputs.identify`.  An empty folder counts as
  absent.
* Never replaced, even with force: an input of the command, a folder that contains an
  input or lies inside one, the working directory (or a folder containing it), a file
  where a folder goes or a folder where a file goes, a symbolic link, or anything
  :func:`~usdbtf.outputs.identify` does not recognise as the same kind.  (``build``
  protects the scene and its layers itself: :mod:`usdbtf.usd.scenes.build`.)
* Write beside, then swap.  New content is written in a staging folder
  ``.<name>.usdbtf-tmp-<pid>-<random>/new/<name>`` beside the output.  When it is
  complete a ``READY`` file listing the names is written, then each old output is moved
  into ``…/old/`` and the new one into place, and the staging folder is removed.  Until
  ``READY`` exists the previous output is untouched, byte for byte.
* A killed run (kill -9) leaves at most a staging folder and a lock file.  The next run
  for the same output, holding its lock, finishes a ``READY`` staging folder (every
  rename is redone or skipped, so the result is the complete new output) and removes
  any other, so nothing accumulates.
* A lock file ``.<name>.usdbtf-lock`` (``flock``) beside each output: a second process
  writing the same output stops at once with "being written by another process".  The
  lock file is removed when the writer finishes.  The lock belongs to the process that
  took it alone: a forked child closes its copy at once (an ``flock`` lasts as long as any
  process holds its open file; subprocesses never get it, it is opened close-on-exec), and
  only that process removes it, publishes a staging folder or removes one.  A lock whose
  holder is no longer running (a process that kept it open although it is not its holder,
  e.g. the orphan of an older usdbtf) is broken, with a debug line.
* Modes follow the umask (temporary folders are created 0700 by ``mkdtemp``; they are
  opened up to ``0777 & ~umask`` before they become outputs).
* Operating-system errors while writing become :class:`~usdbtf.errors.IOFailure`
  naming the output (not the staging path); folders this call created for the output
  are removed again on failure.
"""
from __future__ import annotations

import contextlib
import contextvars
import errno
import fcntl
import json
import logging
import os
import re
import secrets
import shutil
from dataclasses import dataclass
from pathlib import Path

from . import lifetime, outputs
from .lifetime import interrupt, interruption_forgotten, raise_if_interrupted, signals_deferred
from .errors import BTFError, IOFailure, OutputRefused, os_error_message

__all__ = ["Policy", "output_policy", "current_policy", "check_output", "claim", "atomic_dir", "atomic_file",
           "atomic_group", "scratch_dir", "tidy_owned", "umask", "interrupt", "raise_if_interrupted", "signals_deferred",
           "interruption_forgotten", "related", "TMP_TAG", "LOCK_TAG"]

log = logging.getLogger(__name__)
TMP_TAG = ".usdbtf-tmp-"
LOCK_TAG = ".usdbtf-lock"
SCRATCH_TAG = ".usdbtf-scratch-"
_READY = "READY"
# What older usdbtf versions left beside an output (tempfile.mkdtemp/mkstemp names).
_LEGACY = re.compile(r"\.(tmp|old|staging)-[a-z0-9_]{8}(\.\w+)?")


@dataclass(frozen=True)
class Policy:
    """What the current command may do to existing outputs.

    force : replace a previous usdbtf output of the same kind (library default True; the
        CLI sets it from ``--force``).
    inputs : paths the command reads; an output may not be, contain or lie inside one.
    """

    force: bool = True
    inputs: tuple = ()


_POLICY: contextvars.ContextVar[Policy] = contextvars.ContextVar("usdbtf_output_policy", default=Policy())


@contextlib.contextmanager
def output_policy(*, force: bool = True, inputs=()):
    """Set the :class:`Policy` for the writes inside the ``with`` block."""
    token = _POLICY.set(Policy(bool(force), tuple(Path(p) for p in inputs)))
    try:
        yield
    finally:
        _POLICY.reset(token)


def current_policy() -> Policy:
    return _POLICY.get()


def umask() -> int:
    """The process umask (read without changing it where /proc allows)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _real(path: Path) -> Path:
    """Absolute path with the parent's symbolic links resolved (the last component is kept,
    so a link named as an output is seen as a link)."""
    path = Path(os.path.abspath(path))
    return Path(os.path.realpath(path.parent)) / path.name


def related(a, b) -> str | None:
    """How path ``a`` relates to path ``b`` once symbolic links are resolved: "is", "is
    inside", "contains", or None."""
    a, b = Path(os.path.realpath(a)), Path(os.path.realpath(b))
    if a == b:
        return "is"
    if b in a.parents:
        return "is inside"
    if a in b.parents:
        return "contains"
    return None


def check_output(target, *, folder: bool, kind: str | None = None, what: str = "output") -> str:
    """Decide whether ``target`` may be written under the current policy.

    Returns "absent" (nothing there, or an empty folder), "replace" (a previous usdbtf
    output of ``kind`` that ``force`` allows replacing) or "resume" (an existing output of
    a resumable ``kind``, e.g. a capture folder, that the command continues).  Raises
    :class:`OutputRefused` otherwise, with a message naming the path and the reason.

    kind : the kind this output will be (:mod:`usdbtf.outputs`); None: any usdbtf kind
        (the writer's new content is then checked against it before the swap).
    """
    target = Path(target)
    policy = current_policy()
    real = _real(target if target.name not in ("", ".", "..") else Path(os.path.realpath(target)))
    cwd = Path(os.path.realpath(os.getcwd()))
    if real == cwd or real in cwd.parents:
        inside = "" if real == cwd else " (or a folder containing it)"
        raise OutputRefused(f"{target}: is the working directory{inside}; name a new {what}")
    for p in policy.inputs:
        rel = related(real, p)
        if rel is not None:
            raise OutputRefused(f"{target}: {rel} the input {p}; choose another {what} path")
    for parent in real.parents:
        if os.path.lexists(parent):
            if not parent.is_dir():
                raise OutputRefused(f"{target}: {parent} is not a folder")
            break
    if not os.path.lexists(target):
        return "absent"
    if target.is_symlink():
        if kind == outputs.PTY_LINK and outputs.identify(target) == outputs.PTY_LINK:
            return "replace"
        raise OutputRefused(f"{target}: is a symbolic link; name the real path of the {what}")
    if folder and not target.is_dir():
        raise OutputRefused(f"{target}: is a file, but the {what} is a folder; not replaced, even with --force")
    if not folder and target.is_dir():
        raise OutputRefused(f"{target}: is a folder, but the {what} is a file; not replaced, even with --force")
    if folder and not any(target.iterdir()):
        return "absent"
    if kind == outputs.OWNED:
        found = kind
    else:
        found = outputs.identify(target) if kind is None else (kind if outputs.is_kind(target, kind) else None)
    if kind in outputs.RESUMABLE_KINDS and found == kind:
        return "resume"
    if found is None:
        other = outputs.identify(target) if kind is not None else None
        why = (f"is a {other}, not a {kind}" if other else
               f"is not a usdbtf {kind or 'output'} (not written by usdbtf, or holding other files)")
        raise OutputRefused(f"{target}: exists and {why}; not replaced, even with --force")
    if not policy.force:
        raise OutputRefused(f"{target}: exists; pass --force to replace this previous usdbtf {found}")
    return "replace"


# ----------------------------------------------------------------------------- locks


class _Lock:
    def __init__(self, target: Path):
        self.path = target.parent / f".{target.name}{LOCK_TAG}"
        self.count = 0
        self.fd = None
        self.pid = None

    def acquire(self, shown: Path) -> None:
        for _ in range(20):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                taker = _flock_taker(fd)
                if taker is not None and not lifetime.running(taker):
                    # Held open by processes that outlived the one that took it: broken.
                    log.debug(f"{shown}: lock {self.path.name} taken by pid {taker}, which is no longer "
                              "running: broken")
                    self._unlink_if(fd)
                    os.close(fd)
                    continue
                os.close(fd)
                raise OutputRefused(f"{shown}: being written by another process (pid {holder}; lock "
                                    f"{self.path.name}); try again when it has finished") from None
            except BaseException:
                os.close(fd)
                raise
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:            # not a lock file that its last holder unlinked meanwhile
                left = os.pread(fd, 32, 0).decode(errors="replace").strip()
                if left:        # a killed writer's (the lock was free, so it is not running)
                    log.debug(f"{shown}: lock {self.path.name} left by pid {left}, no longer running: taken over")
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
                self.fd, self.pid = fd, os.getpid()
                return
            os.close(fd)
        raise OutputRefused(f"{shown}: could not take the lock {self.path}")  # pragma: no cover

    def _unlink_if(self, fd: int) -> None:
        """Remove the lock file if it is still the one open as ``fd``."""
        with contextlib.suppress(OSError):
            if os.fstat(fd).st_ino == os.stat(self.path).st_ino:
                os.unlink(self.path)

    def release(self) -> None:
        if self.pid != os.getpid():
            return                   # a forked child's copy: the lock is its parent's
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)     # still holding it: nobody else can be inside
        os.close(self.fd)
        self.fd = None


def _flock_taker(fd: int) -> int | None:
    """The pid that took the ``flock`` on ``fd``'s file, from /proc/locks (None: not known).
    Not who holds it now: every process with the open file (a forked child) holds it."""
    st = os.fstat(fd)
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        with open("/proc/locks") as fh:
            for line in fh:
                f = line.split()
                if len(f) >= 6 and f[1] == "FLOCK" and f[5] == key and f[4].isdigit():
                    return int(f[4]) or None        # 0: a pid outside this pid namespace
    except OSError:
        pass
    return None


def _forget_locks_in_child() -> None:
    """In a forked child: close its copies of the parent's lock files (the parent alone holds
    them; a child that outlived it would keep the output locked)."""
    for lock in _HELD.values():
        if lock.fd is not None:
            with contextlib.suppress(OSError):
                os.close(lock.fd)
            lock.fd = None


_HELD: dict[Path, _Lock] = {}
os.register_at_fork(after_in_child=_forget_locks_in_child)


def _cleanup_stale(target: Path) -> None:
    """Remove (or finish) what killed runs left beside ``target``; called with its lock held."""
    prefix = f".{target.name}"
    with os.scandir(target.parent) as entries:
        names = [e.name for e in entries if e.name.startswith(prefix)]
    for name in names:
        rest = name[len(prefix):]
        path = target.parent / name
        if rest.startswith(TMP_TAG):
            names = _ready_names(path)
            if names is not None:
                _roll_forward(path, target.parent, names)
            shutil.rmtree(path, ignore_errors=True)
        elif rest.startswith(SCRATCH_TAG + f"{os.getpid()}-"):
            continue                                  # this process's own
        elif rest.startswith(SCRATCH_TAG) or _LEGACY.fullmatch(rest):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    path.unlink()


def _make_parents(folder: Path) -> list[Path]:
    """mkdir -p ``folder``; returns the folders created (deepest last)."""
    made = []
    for p in reversed([folder, *folder.parents]):
        if not os.path.lexists(p):
            try:
                p.mkdir()
            except FileExistsError:
                continue
            made.append(p)
    return made


def _remove_made(made: list[Path]) -> None:
    for p in reversed(made):
        with contextlib.suppress(OSError):
            p.rmdir()


@contextlib.contextmanager
def claim(target, *, folder: bool, kind: str | None = None, what: str = "output"):
    """Check ``target`` against the policy and hold its lock for the ``with`` block.

    Yields :func:`check_output`'s state.  Re-entrant within a process (the CLI claims
    every output before a command runs; the writers inside claim again).  Parent folders
    created for the output are removed again if the block fails.
    """
    target = Path(target)
    raise_if_interrupted()
    state = check_output(target, folder=folder, kind=kind, what=what)
    log.debug(f"{target}: output {state} ({kind or 'any usdbtf kind'})")
    real = _real(target if target.name not in ("", ".", "..") else Path(os.path.realpath(target)))
    made, held = [], None
    try:
        # SIGTERM/SIGINT wait while the lock and the registry change, so that every lock
        # file taken is released by the finally below.
        with signals_deferred():
            held = _HELD.get(real)
            if held is None:
                try:
                    made = _make_parents(real.parent)
                    lock = _Lock(real)
                    lock.acquire(target)
                except OSError as exc:
                    where = Path(os.fsdecode(exc.filename)) if exc.filename is not None else real.parent
                    if where.name.endswith(LOCK_TAG):
                        where = where.parent
                    raise IOFailure(f"{target}: cannot write in {where}: {exc.strerror or exc}") from None
                _HELD[real] = held = lock
            held.count += 1
        if held.count == 1:
            try:
                _cleanup_stale(real)
            except OSError as exc:
                raise IOFailure(os_error_message(exc, target)) from None
            # Re-check now that we hold the lock (another writer may have just finished).
            state = check_output(target, folder=folder, kind=kind, what=what)
        yield state
        made = []                      # kept: the output is in them
    finally:
        if held is not None:
            with signals_deferred():
                held.count -= 1
                if held.count == 0:
                    del _HELD[real]
                    held.release()
        _remove_made(made)             # after the lock file is gone, so they can be empty


# ----------------------------------------------------------------------------- staging


def _open_mode(path: Path) -> None:
    os.chmod(path, 0o777 & ~umask())


def _new_staging(out_dir: Path, first: str) -> Path:
    name = f".{first}{TMP_TAG}{os.getpid()}-{secrets.token_hex(4)}"
    staging = out_dir / name
    staging.mkdir(mode=0o700)
    (staging / "new").mkdir()
    return staging


def _move_in(staging: Path, out_dir: Path, name: str) -> None:
    """One step of a commit; safe to repeat after a crash at any point."""
    new, dst = staging / "new" / name, out_dir / name
    if not os.path.lexists(new):
        return                                   # already moved in
    if os.path.lexists(dst):
        (staging / "old").mkdir(exist_ok=True)
        os.rename(dst, staging / "old" / name)
    os.rename(new, dst)


def _ready_names(staging: Path) -> list[str] | None:
    """The output names a staging folder's :data:`_READY` record lists, or None when it has
    none that can be trusted (absent, unreadable, or not a list of plain names in ``new/``): such
    a folder never reached its commit and is only removed."""
    try:
        names = json.loads((staging / _READY).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(names, list) or not all(
            isinstance(n, str) and n not in ("", ".", "..") and "/" not in n and "\0" not in n for n in names):
        return None
    return names


def _roll_forward(staging: Path, out_dir: Path, names: list[str]) -> None:
    for name in names:
        _move_in(staging, out_dir, name)


def _commit(staging: Path, out_dir: Path, names: list[str]) -> None:
    for name in names:
        p = staging / "new" / name
        if p.is_dir() and not p.is_symlink():
            _open_mode(p)
    # The record appears whole or not at all (written beside, then renamed): a kill -9 while
    # it is written must leave a staging folder the next run removes, not an empty READY.
    part = staging / (_READY + ".part")
    with open(part, "w") as fh:
        fh.write(json.dumps(names))
        fh.flush()
        os.fsync(fh.fileno())
    os.rename(part, staging / _READY)
    _fsync_dir(staging)
    _roll_forward(staging, out_dir, names)
    _fsync_dir(out_dir)
    shutil.rmtree(staging, ignore_errors=True)
    log.debug(f"published {', '.join(names)} in {out_dir}")


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _translate(exc: BaseException, staging: Path, shown_dir: Path, main: Path) -> BaseException:
    """The exception to report for a failed write: staging paths replaced by the final
    ones (as the user named them), operating-system errors as :class:`IOFailure`."""
    inner = str(staging / "new")

    def fix(text: str) -> str:
        prefix = "" if str(shown_dir) in ("", ".") else str(shown_dir) + os.sep
        return text.replace(inner + os.sep, prefix).replace(inner, str(shown_dir))

    if isinstance(exc, OSError):
        if exc.errno in (errno.ENOSPC, errno.EFBIG, errno.EDQUOT):
            reason = {errno.ENOSPC: "no space left on the device", errno.EFBIG: "file size limit exceeded",
                      errno.EDQUOT: "disk quota exceeded"}[exc.errno]
            where = os.fsdecode(exc.filename) if exc.filename is not None else str(main)
            return IOFailure(f"{fix(where)}: {reason}")
        return IOFailure(fix(os_error_message(exc, main)))
    if isinstance(exc, BTFError) and inner in str(exc):
        new = type(exc)(fix(str(exc)))
        new.exit_code = exc.exit_code
        return new
    return exc


def _only_in(owner: int) -> None:
    """End this process at once unless it is ``owner``, the process that made the staging
    folder: a forked child that somehow came back into its parent's code (an exception it
    raised, e.g. on a signal, unwinding the ``with`` blocks it inherited) must neither publish
    nor remove the parent's work."""
    if os.getpid() != owner:
        os._exit(1)


@contextlib.contextmanager
def _staged(real_dir: Path, names: list[str], shown_dir: Path, check=None):
    """Yield a staging folder's ``new/`` beside the outputs ``names`` in ``real_dir``;
    commit when the block succeeds (after ``check(new)``), remove it when it fails."""
    main = shown_dir / names[0]
    staging, owner = None, os.getpid()
    try:
        with signals_deferred():
            try:
                staging = _new_staging(real_dir, names[0])
            except OSError as exc:
                raise IOFailure(os_error_message(exc, main)) from None
        yield staging / "new"
        if check is not None:
            check(staging / "new")
        _only_in(owner)
        raise_if_interrupted()           # a stopped command publishes nothing
        with signals_deferred():        # a commit, once started, is finished
            _commit(staging, real_dir, [n for n in names if os.path.lexists(staging / "new" / n)])
    except BaseException as exc:
        if staging is None:
            raise
        _only_in(owner)
        if not (staging / _READY).exists():
            shutil.rmtree(staging, ignore_errors=True)
        # else: the commit itself failed half-way; the next claim of the output finishes it.
        new = _translate(exc, staging, shown_dir, main)
        if new is exc:
            raise
        raise new from None


@contextlib.contextmanager
def atomic_group(out_dir, pieces, *, what: str = "output"):
    """Write several outputs in ``out_dir`` as one: yields a staging folder in which the
    caller creates each piece under its final name; on success they replace the previous
    ones together (see the module docstring), on failure nothing changes.

    pieces : [(name, is_folder, kind)], the first is the main output (it names the
        staging folder; a killed run's is finished or removed when it is claimed again).
        A piece the caller did not create is left as it is.
    """
    out_dir = Path(out_dir)
    pieces = [(str(n), bool(f), k) for n, f, k in pieces]
    with contextlib.ExitStack() as claims:
        states = [claims.enter_context(claim(out_dir / n, folder=f, kind=k, what=what)) for n, f, k in pieces]

        def check(new: Path) -> None:
            for (n, _, k), state in zip(pieces, states):
                if state == "replace" and k is None and os.path.lexists(new / n):
                    _same_kind(out_dir / n, new / n)

        with _staged(_real(out_dir / pieces[0][0]).parent, [n for n, _, _ in pieces], out_dir, check) as new:
            yield new


def _same_kind(old: Path, new: Path) -> None:
    was, now = outputs.identify(old), outputs.identify(new)
    if was is None or was != now:
        raise OutputRefused(f"{old}: is a {was or 'not a usdbtf output'}, the new output a {now or 'unknown kind'}; "
                            "not replaced")


@contextlib.contextmanager
def atomic_dir(target, *, kind: str | None = None, overwrite: bool = True):
    """Yield a fresh empty folder; on success it becomes ``target`` (see the module docstring).

    kind : the output kind (:mod:`usdbtf.outputs`); None: whatever usdbtf kind the new
        content is, which must then match an existing output's.
    overwrite : False refuses an existing ``target`` whatever the policy says.
    """
    target = Path(target)
    if not overwrite and os.path.lexists(target):
        raise OutputRefused(f"{target}: exists")
    with atomic_group(target.parent, [(target.name, True, kind)]) as new:
        folder = new / target.name
        folder.mkdir()
        yield folder


@contextlib.contextmanager
def atomic_file(target, *, kind: str | None = None, owner_checked: bool = False):
    """Yield a path (not yet created, same name and suffix as ``target``) to write; on
    success it replaces ``target``.

    owner_checked : the caller has established that it owns ``target`` (a file inside
        its own output, a generated file of the repository): only the structural rules
        apply, not the kind rules.
    """
    target = Path(target)
    if not owner_checked:
        with atomic_group(target.parent, [(target.name, False, kind)]) as new:
            yield new / target.name
        return
    if target.is_dir() or target.is_symlink():
        raise OutputRefused(f"{target}: is a folder or a link; not replaced")
    with output_policy(force=True, inputs=current_policy().inputs), \
            claim(target, folder=False, kind=outputs.OWNED):
        with _staged(_real(target).parent, [target.name], target.parent) as new:
            yield new / target.name


def tidy_owned(target, *, kind: str | None = None) -> None:
    """Take and release the lock of ``target`` (a file the caller owns, left as it is), so
    that what a killed run left beside it (its lock file, a staging folder) is cleaned even
    when nothing needs writing (``build``'s unchanged SConstruct or built stage after a
    SIGKILL).  ``kind``: the output kind ``target`` is (default: a file inside an output the
    caller owns)."""
    target = Path(target)
    with output_policy(force=True, inputs=current_policy().inputs), \
            claim(target, folder=False, kind=kind or outputs.OWNED):
        pass


@contextlib.contextmanager
def scratch_dir(target):
    """A private scratch folder beside ``target`` for large intermediates (removed at the
    end; a killed run's is removed by the next claim of ``target``)."""
    target = Path(target)
    real = _real(target)
    try:
        made = _make_parents(real.parent)
        path = real.parent / f".{target.name}{SCRATCH_TAG}{os.getpid()}-{secrets.token_hex(4)}"
        path.mkdir(mode=0o700)
    except OSError as exc:
        raise IOFailure(os_error_message(exc, target)) from None
    owner = os.getpid()
    try:
        yield path
    except BaseException:
        _only_in(owner)
        shutil.rmtree(path, ignore_errors=True)
        _remove_made(made)
        raise
    _only_in(owner)
    shutil.rmtree(path, ignore_errors=True)
