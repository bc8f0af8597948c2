"""Running ``usdbtf`` in-process from tests: status, stdout, stderr, and the bad-input contract."""
from __future__ import annotations

from usdbtf.cli import main


def run(capsys, *argv) -> tuple[int, str, str]:
    """main(argv) in-process; returns (status, stdout, stderr)."""
    capsys.readouterr()
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def ok(capsys, *argv) -> str:
    """Run a command that must succeed; returns its stdout."""
    code, out, err = run(capsys, *argv)
    assert code == 0, err
    return out


def bad_input(capsys, *argv, names: str) -> str:
    """The command must exit 2 with exactly one stderr line that names ``names``."""
    code, out, err = run(capsys, *argv)
    assert code == 2, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("usdbtf ") and ": error: " in lines[0]
    assert names in lines[0], lines[0]
    return lines[0]
