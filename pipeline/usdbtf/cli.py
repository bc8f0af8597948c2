"""``usdbtf <stage>``: thin command-line mains over the library.

Every command reads real files and writes its outputs through :mod:`usdbtf.atomic`.
Any failure is one stderr line, ``usdbtf CMD: error: <file/sample/option>: <problem>``,
and an exit status that tells a wrong command line from a bad asset from a full disk
(:data:`EXIT_STATUS`, also printed by ``--help``).  ``--debug`` adds the traceback.
The commands themselves live in :mod:`usdbtf.commands`, one module each; a module that
writes files defines ``outputs(args) -> [(path, kind)]`` and gets ``--force``.

Messages are :mod:`logging` records of the ``usdbtf`` loggers (one per module), written to
stderr as their bare text; ``-q`` (warnings only), ``-v`` (debug too) and ``--progress``
(progress bars also when stderr is not a terminal) work before or after the command name.
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading
from pathlib import Path

from . import __version__
from .numeric import one_blas_thread
from .commands import command_modules
from .argtypes import OUTSIDE_PATHS_HELP
from .errors import EXIT_CANT_CREATE, EXIT_DATA, EXIT_INTERNAL, EXIT_IO, EXIT_OK, EXIT_USAGE, OS_ERROR_WORDS, \
    BTFError, one_line, os_error_message


EXIT_STATUS = f"""\
exit status:
  {EXIT_OK:<3} success
  {EXIT_USAGE:<3} usage: a wrong command line (unknown option, value out of range, options that conflict)
  {EXIT_DATA:<3} bad input data: a damaged, inconsistent or unsupported file (the message names the
      file and the key or sample)
  {EXIT_CANT_CREATE:<3} output refused or cannot be created: it exists (pass --force), it is not a usdbtf
      output of the same kind, it is the input or the working directory, another process writes it
  {EXIT_IO:<3} operating-system error: disk full, permission denied, read-only, out of memory
  {EXIT_INTERNAL:<3} internal error (a bug): rerun with --debug for the traceback

--force replaces only a previous usdbtf output of the same kind, and only once the new one
is complete; anything else at the output path is never touched.  --debug prints the
traceback of any error."""

FORCE_HELP = ("replace an existing output, if it is a previous usdbtf output of the same kind (never "
              "anything else); the old one stays until the new one is complete")
DEBUG_HELP = "also print the traceback of an error (above its one-line message)"
QUIET_HELP = "warnings and errors only: no progress messages or bars"
VERBOSE_HELP = "also debug messages"
PROGRESS_HELP = "draw progress bars of long work even when stderr is not a terminal (e.g. in a log)"


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``usdbtf CMD: error: ...`` and exit status 2."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {' '.join(str(message).split())} (see {self.prog} --help)\n")


def _add_message_flags(p, *, default) -> None:
    """--debug, -q/--quiet, -v/--verbose and --progress on the main parser (``default``
    False) and on each command's (``default`` SUPPRESS: the main parser's value stands
    unless the flag is given after the command name)."""
    p.add_argument("--debug", action="store_true", default=default, help=DEBUG_HELP)
    level = p.add_mutually_exclusive_group()
    level.add_argument("-q", "--quiet", action="store_true", default=default, help=QUIET_HELP)
    level.add_argument("-v", "--verbose", action="store_true", default=default, help=VERBOSE_HELP)
    p.add_argument("--progress", action="store_true", default=default, help=PROGRESS_HELP)


class _Stderr(logging.Handler):
    """Each record's message on its own line of the current ``sys.stderr`` (looked up per
    record, so a caller that swaps stderr, e.g. a test capturing it, gets the lines)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
            sys.stderr.flush()
        except Exception:       # noqa: BLE001 - logging must never end a command
            self.handleError(record)


def configure_logging(*, quiet: bool = False, verbose: bool = False, progress: bool = False) -> None:
    """The ``usdbtf`` loggers' level (``quiet``: warnings; default: info; ``verbose``: debug)
    and one stderr handler printing the bare message; ``progress`` draws bars off a terminal
    too (:func:`usdbtf.progress.show_progress`).  Idempotent: a second call replaces the first."""
    from .progress import show_progress

    root = logging.getLogger("usdbtf")
    for handler in [h for h in root.handlers if isinstance(h, _Stderr)]:
        root.removeHandler(handler)
    root.addHandler(_Stderr())
    root.setLevel(logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO)
    root.propagate = False          # the one handler prints each message once
    show_progress(progress)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="usdbtf", description="Measured BTF materials to USD assets.", epilog=EXIT_STATUS,
               formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"usdbtf {__version__}",
                   help="print the version and exit (with --json: also the libraries and the numeric platform)")
    _add_message_flags(p, default=False)
    p.add_argument("--force", action="store_true", help="the same as the stage's --force: " + FORCE_HELP)
    p.add_argument("--allow-outside-paths", action="store_true", help=OUTSIDE_PATHS_HELP)
    sub = p.add_subparsers(dest="command", required=True, metavar="<stage>", parser_class=Parser)
    for module in command_modules():
        before = set(sub.choices)
        module.add_parser(sub)
        for name in set(sub.choices) - before:
            sp = sub.choices[name]
            sp.epilog = EXIT_STATUS if not sp.epilog else f"{sp.epilog}\n\n{EXIT_STATUS}"
            sp.formatter_class = argparse.RawDescriptionHelpFormatter
            _add_message_flags(sp, default=argparse.SUPPRESS)
            if hasattr(module, "outputs") and "force" not in {a.dest for a in sp._actions}:
                sp.add_argument("--force", action="store_true", default=argparse.SUPPRESS, help=FORCE_HELP)
            sp.set_defaults(_module=module)
    return p


def describe(exc: BaseException) -> tuple[int, str]:
    """(exit status, one-line message) for an exception that ended a command."""
    if isinstance(exc, BTFError):
        return exc.exit_code, one_line(exc)
    if isinstance(exc, OSError):
        return EXIT_IO, one_line(os_error_message(exc))
    if type(exc).__module__.startswith("pxr"):
        # A USD (Tf) error that no reader turned into a BTFError: USD reports a bad layer
        # or a failed write this way.
        from .usdstage import tf_message

        text = tf_message(exc)
        status = EXIT_IO if any(w in text for w in OS_ERROR_WORDS) else EXIT_DATA
        return status, f"USD: {text}"
    if isinstance(exc, MemoryError):
        return EXIT_IO, ("out of memory: the machine cannot hold what this command needs "
                         "(use smaller inputs or options, or a larger machine)")
    return EXIT_INTERNAL, (f"internal error ({type(exc).__name__}: {one_line(exc)[:300]}); "
                           "rerun with --debug for the traceback")


def _paths(value) -> list[Path]:
    if isinstance(value, Path):
        return [value]
    if isinstance(value, (list, tuple)):
        return [v for v in value if isinstance(v, Path)]
    return []


@contextlib.contextmanager
def _outputs_claimed(args):
    """The output policy of this command (``--force``, its inputs) with every output it
    declares claimed: refused outputs fail before any work, and each is locked."""
    from .atomic import claim, output_policy
    from .outputs import FOLDER_KINDS

    module = getattr(args, "_module", None)
    declared = list(module.outputs(args)) if module is not None and hasattr(module, "outputs") else []
    # Every path argument except the outputs (OUTPUT_ARGS: their argument names) is an input.
    output_args = set(getattr(module, "OUTPUT_ARGS", ("output",)))
    inputs = [p for key, v in vars(args).items() if not key.startswith("_") and key not in output_args
              for p in _paths(v)]
    with output_policy(force=getattr(args, "force", False), inputs=inputs), contextlib.ExitStack() as stack:
        if getattr(args, "allow_outside_paths", False):
            from .manifest import outside_paths_allowed

            stack.enter_context(outside_paths_allowed())
        for path, kind in declared:
            stack.enter_context(claim(path, folder=kind in FOLDER_KINDS, kind=kind))
        yield


@contextlib.contextmanager
def _pools_stopped_on_exception():
    """A command that ends by an exception (an error, SIGTERM, Ctrl-C) stops every worker pool
    still open (:func:`usdbtf.lifetime.stop_live_pools`) before its outputs' locks go: a pool
    held by a generator the exception left suspended would otherwise keep its workers running
    and Python's exit waiting for the items still queued."""
    try:
        yield
    except BaseException:
        from .lifetime import stop_live_pools

        stop_live_pools()
        raise


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised so that every ``with`` block cleans up as on Ctrl-C."""


@contextlib.contextmanager
def _signals_raise():
    """SIGTERM and SIGINT become exceptions (Terminated, KeyboardInterrupt), delivered
    through :func:`usdbtf.atomic.interrupt` so that a lock or a commit in progress is
    finished first."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    from .atomic import interrupt, interruption_forgotten

    def on_term(signum, frame):
        interrupt(Terminated())

    def on_int(signum, frame):
        interrupt(KeyboardInterrupt())

    interruption_forgotten()
    old = {signal.SIGTERM: signal.signal(signal.SIGTERM, on_term), signal.SIGINT: signal.signal(signal.SIGINT, on_int)}
    try:
        yield
    except Exception:
        # A signal that lands inside a library's clean-up can surface as that library's error
        # instead (a ProcessPoolExecutor interrupted while starting its manager thread raises
        # "cannot join thread before it is started" from shutdown): the stop is still a stop.
        from .atomic import raise_if_interrupted

        raise_if_interrupted()
        raise
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
        interruption_forgotten()


def version_report() -> dict:
    """What ``usdbtf --version --json`` prints: usdbtf's version and code digest, Python's and
    the computing libraries' versions, and the numeric platform with the variables that pin it
    (``numeric``: the bits of every output depend on it; see :mod:`usdbtf.numeric`)."""
    import os

    from . import numeric
    from .cluster import environment

    env = dict(environment())
    platform = {k: env.pop(k) for k in numeric.platform()}
    pinned = {name: os.environ.get(name, "") for name in numeric.PLATFORM_VARIABLES}
    return {"usdbtf": env.pop("usdbtf"), "code": env.pop("usdbtf code"), "python": env.pop("python"),
            "libraries": env,
            "numeric": {**platform, "reference": numeric.is_reference(platform), "environment": pinned}}


def _version_json_asked(argv) -> bool:
    """``--version --json`` (in either order) before any command name."""
    head = []
    for arg in argv:
        if not arg.startswith("-"):
            break
        head.append(arg)
    return "--version" in head and "--json" in head


def main(argv=None) -> int:
    if argv is None:     # started by usdbtf (build's SCons, a Dask worker): die with that process
        from .lifetime import adopt_parent_from_environment

        adopt_parent_from_environment()
    if _version_json_asked(sys.argv[1:] if argv is None else list(argv)):
        from . import jsontext

        print(jsontext.dumps(version_report()))
        return 0
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:      # reported by the command's own parser, so the line names the command
        sub = next(a for a in parser._actions if a.dest == "command").choices[args.command]
        sub.error(f"unrecognized arguments: {' '.join(extra)}")
    debug = getattr(args, "debug", False)
    configure_logging(quiet=args.quiet, verbose=args.verbose, progress=args.progress)
    # By name: run as ``python -m usdbtf.cli`` this module is __main__, outside the usdbtf loggers.
    logging.getLogger("usdbtf.cli").debug("usdbtf %s: %s", __version__, " ".join(map(str, argv or sys.argv[1:])))
    try:
        # Every command's products on one BLAS thread: no byte depends on thread counts.
        with _signals_raise(), _outputs_claimed(args), _pools_stopped_on_exception(), one_blas_thread():
            status = args.func(args)
            from .atomic import raise_if_interrupted

            raise_if_interrupted()     # a signal Python dropped (usdbtf.atomic.interrupt): still a stop
            return status
    except Terminated:
        print(f"usdbtf {args.command}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print(f"usdbtf {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:      # noqa: BLE001 - every failure becomes one line and a status
        status, message = describe(exc)
        if debug:
            import traceback

            traceback.print_exc()
            message = message.replace("rerun with --debug for the traceback", "traceback above")
        # one_line again: the last line of defence for a message made outside describe().
        print(f"usdbtf {args.command}: error: {one_line(message)}", file=sys.stderr)
        return status


if __name__ == "__main__":
    sys.exit(main())
