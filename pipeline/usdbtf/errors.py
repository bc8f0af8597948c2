"""The exceptions every stage raises, and the exit status each one means on the command line.

Pipelines must be able to tell a wrong command line from a bad asset from a full disk, so
each kind of failure has its own class and its own documented exit status (the BSD
``sysexits.h`` values that build systems and farm schedulers already know):

======================  ======  ===========================================================
class                   status  meaning
======================  ======  ===========================================================
(argparse)                   2  usage: an unknown option or a value of the wrong form
:class:`UsageError`          2  usage: options that contradict each other or are out of range
:class:`BTFError`           65  bad input data (``EX_DATAERR``): a damaged, inconsistent or
                                unsupported file; the message names the file and sample/key
:class:`OutputRefused`      73  the output cannot be created or may not be replaced
                                (``EX_CANTCREAT``): it exists and is not usdbtf's, it is the
                                input, another process is writing it, ...
:class:`IOFailure`          74  an operating-system error while reading or writing
                                (``EX_IOERR``): disk full, permission denied, read-only ...
(OSError, MemoryError)      74  (the CLI maps them to :class:`IOFailure`)
(anything else)              1  an internal error: a bug; rerun with ``--debug``
======================  ======  ===========================================================

Every message names the file, sample or option at fault; the CLI prints it as one line,
``usdbtf CMD: error: <message>``.
"""
from __future__ import annotations

__all__ = ["BTFError", "UsageError", "OutputRefused", "IOFailure", "error_for_status", "os_error_message",
           "OS_ERROR_WORDS", "link_error", "one_line", "EXIT_OK", "EXIT_USAGE", "EXIT_DATA", "EXIT_CANT_CREATE", "EXIT_IO", "EXIT_INTERNAL"]

#: Words of operating-system errors inside the messages of libraries that do not raise
#: OSError (USD's Tf errors, image writers): such a failure is an I/O error, status 74.
OS_ERROR_WORDS = ("File too large", "No space left", "Permission denied", "Read-only file system", "Is a directory",
                  "Disk quota exceeded")

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2
EXIT_DATA = 65
EXIT_CANT_CREATE = 73
EXIT_IO = 74


class BTFError(Exception):
    """Bad input data or an impossible request.  The message names the file or sample at fault."""

    exit_code = EXIT_DATA


class UsageError(BTFError):
    """Command-line options that are well-formed but out of range or contradictory."""

    exit_code = EXIT_USAGE


class OutputRefused(BTFError):
    """The output path may not be written: it exists and is not a previous usdbtf output of
    the same kind (or ``--force`` was not given), it is or contains the input, another
    process holds its lock, ..."""

    exit_code = EXIT_CANT_CREATE


class IOFailure(BTFError):
    """An operating-system error reading or writing a named path (disk full, permission
    denied, read-only file system, a folder where a file was expected)."""

    exit_code = EXIT_IO


def error_for_status(status: int, message: str) -> BTFError:
    """The exception whose exit status is ``status`` (e.g. the status of a child ``usdbtf``
    process that ``build`` ran), carrying ``message``; statuses without a class of their
    own (1, signals) give a plain :class:`BTFError` with status 65 replaced by ``status``."""
    for cls in (UsageError, OutputRefused, IOFailure, BTFError):
        if cls.exit_code == status:
            return cls(message)
    exc = BTFError(message)
    exc.exit_code = status
    return exc


def one_line(text) -> str:
    """``text`` with every run of whitespace, newlines included, as one space: library
    messages (OIIO, libpng, USD) can span lines, and every usdbtf error is one line."""
    return " ".join(str(text).split())


def os_error_message(exc: OSError, path=None) -> str:
    """One line for an operating-system error: ``PATH: reason`` (the path the error names,
    else ``path``)."""
    import os

    reason = exc.strerror or " ".join(str(exc).split()) or type(exc).__name__
    where = exc.filename if exc.filename is not None else path
    if where is None:
        return reason
    text = f"{os.fsdecode(where)}: {reason}"
    if exc.filename2 is not None:
        text += f" (-> {os.fsdecode(exc.filename2)})"
    return text


#: Links followed before a chain counts as a loop (Linux's own limit is 40).
_MAX_LINK_HOPS = 40


def link_error(path) -> BTFError | None:
    """The error for a symbolic link ``path`` that cannot be followed, its message one line
    naming the link and its chain; None when ``path`` is not a link or leads to something
    that exists.

    A loop (``PATH: symbolic link loop (a -> b -> a)``) is the operating system's ELOOP, an
    :class:`IOFailure` (74); a dangling link (``PATH: dangling symbolic link (-> t: no such
    file)``) is a missing input, a :class:`BTFError` (65).  ``Path.exists`` and ``is_file``
    answer False for both, so a reader that only asks them would call the input "missing" or
    "unrecognised" instead of saying what is wrong.
    """
    import os

    path = os.fspath(path)
    if not os.path.islink(path) or os.path.exists(path):
        return None
    chain, seen, here = [os.path.basename(path)], {os.path.abspath(path)}, path
    for _ in range(_MAX_LINK_HOPS):
        target = os.readlink(here)
        chain.append(target)
        here = os.path.normpath(os.path.join(os.path.dirname(here), target))
        if os.path.abspath(here) in seen:
            return IOFailure(f"{path}: symbolic link loop ({' -> '.join(chain)})")
        if not os.path.islink(here):
            if os.path.lexists(here):
                break           # the chain ends, but a folder on the way is a link that fails
            return BTFError(f"{path}: dangling symbolic link (-> {' -> '.join(chain[1:])}: no such file)")
        seen.add(os.path.abspath(here))
    return IOFailure(f"{path}: symbolic link that cannot be followed ({' -> '.join(chain)} -> ...)")
