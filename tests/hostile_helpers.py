"""The checker of the hostile-input suite: one failing ``usdbtf`` run must

* exit with the expected status (non-zero, below 128: no signal, no crash);
* print exactly one stderr line, ``usdbtf CMD: error: ...``, naming the file, sample, key or
  option at fault; no traceback, nothing else (C++ warnings included: stderr is captured at
  the file-descriptor level);
* leave every watched folder byte for byte as it was: the ``-o`` path and everything beside
  it (no temporary folder, lock file or half-written output), and the inputs;
* leave ``$TMPDIR`` (a fresh folder per case) empty.

Runs are in-process (:func:`in_process`, fast) or real subprocesses (:func:`subprocess_runner`,
for what is process-level: signals, resource limits, dropped privileges).
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Outcome:
    code: int
    stdout: str
    stderr: str


def snapshot(path: Path) -> dict:
    """{relative path: sha256 | "<dir>" | "-> link target"} of everything under ``path``
    (hidden entries included), or {} when it does not exist; ``path`` itself is "."."""
    path = Path(path)
    if not os.path.lexists(path):
        return {}
    out = {}

    def entry(p: Path, rel: str):
        if p.is_symlink():
            out[rel] = "-> " + os.readlink(p)
        elif p.is_dir():
            out[rel] = "<dir>"
        else:
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()

    entry(path, ".")
    if path.is_dir() and not path.is_symlink():
        for d, dirs, files in os.walk(path):
            for name in dirs + files:
                p = Path(d) / name
                entry(p, p.relative_to(path).as_posix())
    return out


def in_process(capfd, env: dict | None = None):
    """A runner calling :func:`usdbtf.cli.main` in this process, stdout/stderr captured at
    the file-descriptor level, ``tempfile``'s folder pointed at the case's ``$TMPDIR``."""
    from usdbtf.cli import main

    def run(argv, tmpdir: Path) -> Outcome:
        capfd.readouterr()
        saved_env = {k: os.environ.get(k) for k in ("TMPDIR", *(env or {}))}
        saved_tempdir = tempfile.tempdir
        os.environ["TMPDIR"] = str(tmpdir)
        os.environ.update(env or {})
        tempfile.tempdir = str(tmpdir)
        try:
            try:
                code = main([str(a) for a in argv])
            except SystemExit as exc:           # argparse
                code = exc.code
        finally:
            tempfile.tempdir = saved_tempdir
            for k, v in saved_env.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        out, err = capfd.readouterr()
        return Outcome(code, out, err)

    return run


def subprocess_runner(*, preexec_fn=None, timeout: float = 120, env: dict | None = None):
    """A runner starting ``python -m usdbtf.cli`` as a real process with ``TMPDIR`` set."""
    def run(argv, tmpdir: Path) -> Outcome:
        e = dict(os.environ, OCIO="ocio://default", TMPDIR=str(tmpdir),
                 PYTHONPATH=str(ROOT / "pipeline") + os.pathsep + os.environ.get("PYTHONPATH", ""))
        e.update(env or {})
        done = subprocess.run([sys.executable, "-m", "usdbtf.cli", *map(str, argv)], capture_output=True, text=True,
                              env=e, timeout=timeout, preexec_fn=preexec_fn, stdin=subprocess.DEVNULL)
        return Outcome(done.returncode, done.stdout, done.stderr)

    return run


def check_failure(run, argv, *, code: int, names, watch, tmpdir: Path) -> str:
    """Run ``argv`` with ``run`` and check the contract in the module docstring; returns the
    error line.  ``names``: a string or strings the line must contain; ``watch``: folders
    (or files) that must be unchanged."""
    names = [names] if isinstance(names, str) else list(names)
    watch = [Path(w) for w in ([watch] if isinstance(watch, (str, Path)) else watch)]
    tmpdir = Path(tmpdir)
    tmpdir.mkdir(parents=True, exist_ok=True)
    assert not any(tmpdir.iterdir()), "the case's TMPDIR must start empty"
    before = {w: snapshot(w) for w in watch}
    got = run(argv, tmpdir)
    command = str(argv[0]) if not str(argv[0]).startswith("-") else next(a for a in map(str, argv)
                                                                        if not a.startswith("-"))
    assert got.code == code, f"exit status {got.code}, expected {code}; stderr: {got.stderr!r}"
    assert 0 < got.code < 128, got.code
    assert "Traceback" not in got.stderr, got.stderr
    lines = got.stderr.strip().splitlines()
    assert len(lines) == 1, f"expected one stderr line, got {len(lines)}: {got.stderr!r}"
    line = lines[0]
    assert line.startswith(f"usdbtf {command}: error: "), line
    for n in names:
        assert str(n) in line, f"{n!r} not in {line!r}"
    for w in watch:
        after = snapshot(w)
        assert after == before[w], _difference(w, before[w], after)
    left = sorted(p.name for p in tmpdir.iterdir())
    assert not left, f"left in $TMPDIR: {left}"
    return line


def _difference(where: Path, before: dict, after: dict) -> str:
    added = sorted(set(after) - set(before))
    removed = sorted(set(before) - set(after))
    changed = sorted(k for k in set(before) & set(after) if before[k] != after[k])
    return f"{where} changed: added {added}, removed {removed}, changed {changed}"
