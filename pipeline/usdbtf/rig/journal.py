"""The capture journal: an append-only record that makes captures resumable.

``RAW/journal.jsonl`` holds one JSON object per line:

* line 1, the header: ``{"journal": "usdbtf-capture/1", "plan": <fingerprint>, ...}``;
* ``{"shot": <plan index>, "image": <file>, "frame": <rig frame number>}`` per sample;
* ``{"flat": <file>, "frames": <n>}`` once the flat field is stored;
* ``{"session": {...}}`` at the start of every run that talks to the rig: the rig's
  identity (HELLO) and the camera used, for provenance.

Crash safety (kill -9 at any instant): a frame is written to a temporary name, fsynced
and renamed into place *before* its journal line is appended (and fsynced).  So

* a journal line always points at a complete file;
* a file without a journal line (killed between the rename and the append) is simply
  shot again under the same name on resume -- no duplicate, nothing lost;
* a torn last line (killed mid-append) is cut off on resume; a damaged line anywhere
  else means the file was edited or the disk is failing, and is an error.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from ..errors import BTFError

__all__ = ["FORMAT", "Journal"]

FORMAT = "usdbtf-capture/1"


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class Journal:
    """Open (creating or resuming) the journal at ``path`` for a plan ``fingerprint``.

    Attributes after opening: ``shots`` (dict plan index -> record), ``flat`` (record or
    None), ``header`` (dict), ``resumed`` (bool: it existed before).
    """

    def __init__(self, path, fingerprint: str, header_extra: dict | None = None):
        self.path = Path(path)
        self.shots: dict = {}
        self.flat = None
        self.sessions: list = []
        self.resumed = self.path.exists()
        if self.resumed:
            self._load(fingerprint)
        else:
            self.header = {"journal": FORMAT, "plan": fingerprint, **(header_extra or {})}
            tmp = self.path.with_name(f".{self.path.name}.tmp")
            with open(tmp, "w") as fh:
                fh.write(json.dumps(self.header, sort_keys=True) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
            _fsync_dir(self.path.parent)
        self._fh = open(self.path, "a")

    def _load(self, fingerprint: str) -> None:
        raw = self.path.read_bytes()
        lines = raw.split(b"\n")
        complete, tail = lines[:-1], lines[-1]
        good_bytes = len(raw) - len(tail)
        records = []
        for n, line in enumerate(complete, start=1):
            try:
                records.append(json.loads(line))
            except (UnicodeDecodeError, json.JSONDecodeError):
                if n == len(complete) and not tail:
                    # The last line, newline written but content torn: a crash artifact too.
                    good_bytes -= len(line) + 1
                    break
                raise BTFError(f"{self.path}: line {n} is damaged; the journal cannot be trusted "
                               "(start a new capture folder)") from None
        if good_bytes != len(raw):
            with open(self.path, "r+b") as fh:      # drop the torn tail left by a crash
                fh.truncate(good_bytes)
        if not records or not isinstance(records[0], dict) or records[0].get("journal") != FORMAT:
            raise BTFError(f"{self.path}: not a {FORMAT} journal")
        self.header = records[0]
        if self.header.get("plan") != fingerprint:
            raise BTFError(f"{self.path}: this folder was started with a different capture plan (sampling, "
                           "ordering or obstruction model); use the same options or a new output folder")
        for n, rec in enumerate(records[1:], start=2):
            if isinstance(rec, dict) and isinstance(rec.get("shot"), int):
                if rec["shot"] in self.shots:
                    raise BTFError(f"{self.path}: line {n}: sample {rec['shot']} is recorded twice")
                self.shots[rec["shot"]] = rec
            elif isinstance(rec, dict) and isinstance(rec.get("flat"), str):
                self.flat = rec
            elif isinstance(rec, dict) and isinstance(rec.get("session"), dict):
                self.sessions.append(rec["session"])
            else:
                raise BTFError(f"{self.path}: line {n} is not a journal record: {rec!r}")

    def append(self, record: dict) -> None:
        """Append one record durably (flushed and fsynced before returning)."""
        if isinstance(record.get("shot"), int):
            if record["shot"] in self.shots:
                raise RuntimeError(f"sample {record['shot']} is already in the journal")
            self.shots[record["shot"]] = record
        elif "flat" in record:
            self.flat = record
        elif "session" in record:
            self.sessions.append(record["session"])
        self._fh.write(json.dumps(record, sort_keys=True) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> "Journal":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
