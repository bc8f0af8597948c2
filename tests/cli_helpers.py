"""Running ``usdbtf`` in-process from tests: status, stdout, stderr, and the error contract
(the documented exit status and exactly one ``usdbtf CMD: error:`` line naming the problem)."""
from __future__ import annotations

from usdbtf.cli import main
from usdbtf.errors import EXIT_CANT_CREATE, EXIT_DATA, EXIT_USAGE


def run(capsys, *argv) -> tuple[int, str, str]:
    """main(argv) in-process; returns (status, stdout, stderr).  Usage errors that argparse
    reports by exiting are returned as their status."""
    capsys.readouterr()
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def ok(capsys, *argv) -> str:
    """Run a command that must succeed; returns its stdout."""
    code, out, err = run(capsys, *argv)
    assert code == 0, err
    return out


def fails(capsys, *argv, code: int, names: str) -> str:
    """The command must exit with ``code`` and print exactly one stderr line,
    ``usdbtf CMD: error: ...``, that contains ``names``; returns the line."""
    status, out, err = run(capsys, *argv)
    assert status == code, (status, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("usdbtf ") and ": error: " in lines[0], lines[0]
    assert "Traceback" not in err
    assert names in lines[0], lines[0]
    return lines[0]


def bad_input(capsys, *argv, names: str, code: int = EXIT_DATA) -> str:
    """Bad input data: exit status 65 (or ``code``) and one line naming ``names``."""
    return fails(capsys, *argv, code=code, names=names)


def bad_usage(capsys, *argv, names: str) -> str:
    """A wrong command line: exit status 2 and one line naming ``names``."""
    return fails(capsys, *argv, code=EXIT_USAGE, names=names)


def refused(capsys, *argv, names: str) -> str:
    """An output that may not be written: exit status 73 and one line naming ``names``."""
    return fails(capsys, *argv, code=EXIT_CANT_CREATE, names=names)
