"""The rig service's run history: one row per run the service made, in an SQLite file in its output folder.

The service writes a row as a run begins (RUNNING) and completes it as the run ends, whether it passed,
failed, was stopped or raised; a row still RUNNING whose service process is gone was cut short by that
process's end (INTERRUPTED). At the end the row also takes from the run's own summary.json whether the robot
fell and how, the faults that acted and when, and the operators' actions (e-stops, resets, cuts: who and
when), where the summary records them. The file stays across restarts (an older file gains the new columns,
empty for its old rows); consoles read it through the service's `PREFIX/rig/history` queryable, with ISO
8601 times, and fetch a run's files through `PREFIX/rig/file` (`History.file` decides what may be read: a
plain file directly inside a run folder that resolves inside the output folder).
"""

from __future__ import annotations

import json
import os
import re
import sqlite3
import threading
import time
from datetime import datetime
from pathlib import Path

from hil.bench.rigs import alive
from hil.faults import parse_fault

FILE_NAME = "history.sqlite"
SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    folder TEXT NOT NULL,           -- the run folder, relative to the output folder
    scenario TEXT NOT NULL,
    bench TEXT NOT NULL,
    controller TEXT NOT NULL,       -- where it ran and its law, e.g. "embedded reference ihacs"
    clock TEXT NOT NULL,
    verdict TEXT NOT NULL,    -- RUNNING, then PASSED FAILED INCONCLUSIVE ESTOPPED STOPPED ERROR INTERRUPTED
    first_cause TEXT,               -- the supervisor's first transition's cause, e.g. OPERATOR_ESTOP
    error TEXT,
    started REAL NOT NULL,          -- wall clock, s since the epoch
    ended REAL,
    files TEXT NOT NULL DEFAULT '', -- the run folder's files at its end, '/'-separated
    pid INTEGER NOT NULL            -- the service process that made it
)
"""
ADDED = {
    "fallen": "INTEGER",  # summary.json: 1 fell, 0 did not; NULL: no summary
    "fall_cause": "TEXT",
    "faults": "TEXT",  # JSON: each fault as described, with the window it acted in
    "operator_actions": "TEXT",  # JSON: summary.json's operator_actions, as recorded
}
"""Columns taken from the run's summary.json at its end; a file made before them gains them, empty."""
COLUMNS = (
    "id",
    "folder",
    "scenario",
    "bench",
    "controller",
    "clock",
    "verdict",
    "first_cause",
    "error",
    "started",
    "ended",
    "files",
    *ADDED,
)
PLAIN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]{0,127}")
"""A file name a console may ask for: no separator, no leading dot (so neither '..' nor hidden files)."""
MAX_LIMIT = 500


class NotServed(LookupError):
    """The file asked for is not one the history serves: why, in one line."""


class NoHistory:
    """Where nothing is kept (a campaign written outside the bench's folder): the same calls, no file."""

    def begin(self, folder: Path, scenario: str, bench: str, controller: str, clock: str) -> int:
        return 0

    def end(
        self, run_id: int, verdict: str, first_cause: str | None = None, error: str | None = None
    ) -> None:
        pass

    def close(self) -> None:
        pass


class History:
    def __init__(self, folder: Path | str):
        """The history of the runs under `folder` (the service's output folder), made if missing."""
        self.folder = Path(folder).resolve()
        self.folder.mkdir(parents=True, exist_ok=True)
        # One connection for the service's threads (the run's worker writes, zenoh's threads read), behind a
        # lock; autocommit, and a busy timeout for a second service sharing the folder.
        self._db = sqlite3.connect(
            self.folder / FILE_NAME, timeout=10.0, check_same_thread=False, isolation_level=None
        )
        self._lock = threading.Lock()
        with self._lock:
            self._db.execute(SCHEMA)
            present = {row[1] for row in self._db.execute("PRAGMA table_info(runs)")}
            for column, kind in ADDED.items():
                if column not in present:
                    self._db.execute(f"ALTER TABLE runs ADD COLUMN {column} {kind}")
            running = self._db.execute("SELECT id, pid FROM runs WHERE verdict = 'RUNNING'").fetchall()
            for run_id, pid in running:
                if pid == os.getpid() or not alive(pid):
                    self._db.execute(
                        "UPDATE runs SET verdict = 'INTERRUPTED', error = ? WHERE id = ?",
                        ("the service ended during the run", run_id),
                    )

    def begin(self, folder: Path, scenario: str, bench: str, controller: str, clock: str) -> int:
        """A new run's row (RUNNING); its id."""
        with self._lock:
            cursor = self._db.execute(
                "INSERT INTO runs (folder, scenario, bench, controller, clock, verdict, started, pid) "
                "VALUES (?, ?, ?, ?, ?, 'RUNNING', ?, ?)",
                (self._relative(folder), scenario, bench, controller, clock, time.time(), os.getpid()),
            )
            run_id = cursor.lastrowid
            assert run_id is not None  # None only before any INSERT on the cursor
            return run_id

    def end(
        self, run_id: int, verdict: str, first_cause: str | None = None, error: str | None = None
    ) -> None:
        """The run's end: its verdict, the supervisor's first cause, the files its folder holds now, and
        what its summary.json says of a fall, the faults and the operators' actions."""
        with self._lock:
            row = self._db.execute("SELECT folder FROM runs WHERE id = ?", (run_id,)).fetchone()
            if row is None:
                return
            folder = self.folder / row[0]
            files = sorted(p.name for p in folder.iterdir() if p.is_file()) if folder.is_dir() else []
            recorded = _from_summary(folder / "summary.json")
            self._db.execute(
                "UPDATE runs SET verdict = ?, first_cause = ?, error = ?, ended = ?, files = ?, fallen = ?, "
                "fall_cause = ?, faults = ?, operator_actions = ? WHERE id = ?",
                (verdict, first_cause, error, time.time(), "/".join(files), *recorded, run_id),
            )

    def interrupt(self, run_id: int, why: str) -> None:
        """A run cut short as its process leaves at once (a second Ctrl-C): its row INTERRUPTED now, not
        at the service's next start; a row already ended keeps its verdict. Safe from a signal handler: its
        own connection, never the lock a thread of the service may hold."""
        folder_of = "SELECT folder FROM runs WHERE id = ?"
        db = sqlite3.connect(self.folder / FILE_NAME, timeout=10.0, isolation_level=None)
        try:
            row = db.execute(folder_of, (run_id,)).fetchone()
            folder = self.folder / row[0] if row is not None else None
            files = (
                sorted(p.name for p in folder.iterdir() if p.is_file()) if folder and folder.is_dir() else []
            )
            db.execute(
                "UPDATE runs SET verdict = 'INTERRUPTED', error = ?, ended = ?, files = ? "
                "WHERE id = ? AND verdict = 'RUNNING'",
                (why, time.time(), "/".join(files), run_id),
            )
        finally:
            db.close()

    def runs(self, limit: int = 50, before: int | None = None) -> list[dict]:
        """The newest `limit` runs (older than run `before`), newest first."""
        limit = max(1, min(int(limit), MAX_LIMIT))
        query = f"SELECT {', '.join(COLUMNS)} FROM runs"
        args: tuple = ()
        if before is not None:
            query, args = query + " WHERE id < ?", (int(before),)
        with self._lock:
            rows = self._db.execute(query + " ORDER BY id DESC LIMIT ?", (*args, limit)).fetchall()
        return [self._record(row) for row in rows]

    def count(self) -> int:
        with self._lock:
            return int(self._db.execute("SELECT COUNT(*) FROM runs").fetchone()[0])

    def file(self, run_id: int, name: str) -> Path:
        """The path of file `name` of run `run_id`, if the history serves it: a plain name (no separator, no
        leading dot), a regular file whose real path (symbolic links followed) is directly inside that run's
        folder, inside the output folder. NotServed says why not."""
        if not isinstance(name, str) or not PLAIN_NAME.fullmatch(name):
            raise NotServed(f"{name!r} is not a plain file name")
        with self._lock:
            row = self._db.execute("SELECT folder FROM runs WHERE id = ?", (int(run_id),)).fetchone()
        if row is None:
            raise NotServed(f"no run {run_id} in the history")
        folder = (self.folder / row[0]).resolve()
        path = (folder / name).resolve()
        if not folder.is_relative_to(self.folder) or path.parent != folder:
            raise NotServed(f"{name} of run {run_id} is outside the output folder")
        if not path.is_file():
            raise NotServed(f"run {run_id} has no file {name}")
        return path

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # ------------------------------------------------------------------------------------------- rows
    def _relative(self, folder: Path) -> str:
        resolved = Path(folder).resolve()
        # A folder outside the output folder is kept absolute, and never served (see `file`).
        return str(resolved.relative_to(self.folder) if resolved.is_relative_to(self.folder) else resolved)

    @staticmethod
    def _record(row: tuple) -> dict:
        record = dict(zip(COLUMNS, row, strict=True))
        record["files"] = [f for f in record["files"].split("/") if f]
        for stamp in ("started", "ended"):
            record[stamp] = iso(record[stamp])
        record["fallen"] = None if record["fallen"] is None else bool(record["fallen"])
        for listed in ("faults", "operator_actions"):
            record[listed] = None if record[listed] is None else json.loads(record[listed])
        return record


def iso(stamp: float | None) -> str | None:
    """A wall-clock stamp as ISO 8601 with the machine's UTC offset, to the second."""
    if stamp is None:
        return None
    return datetime.fromtimestamp(stamp).astimezone().isoformat(timespec="seconds")


def _from_summary(path: Path) -> tuple[int | None, str | None, str | None, str | None]:
    """(fallen, fall_cause, faults, operator_actions) of a run's summary.json for its row (NULL where the
    run wrote none, or did not record that): the faults as described, each with the window it acted in;
    the operators' actions as the summary records them."""
    try:
        summary = json.loads(path.read_text())
    except (OSError, ValueError):
        return None, None, None, None
    if not isinstance(summary, dict):
        return None, None, None, None
    fallen = summary.get("fallen")
    faults = summary.get("faults")
    actions = summary.get("operator_actions")
    return (
        None if not isinstance(fallen, bool) else int(fallen),
        summary.get("fall_cause") if isinstance(summary.get("fall_cause"), str) else None,
        None if not isinstance(faults, list) else json.dumps([_fault(f) for f in faults]),
        None if not isinstance(actions, list) else json.dumps(actions),
    )


def _fault(entry: object) -> str:
    """'sensor.stuck imu.pitch ... acted 1.0-3.0 s' (or 'never acted') from a summary's fault entry."""
    if not isinstance(entry, dict) or not isinstance(entry.get("fault"), dict):
        return str(entry)
    fault = entry["fault"]
    try:
        described = parse_fault(fault, "summary.json faults").describe()
    except ValueError:  # a fault of another version's catalog: its kind at least
        described = str(fault.get("kind", "?"))
    acted = entry.get("acted")
    if isinstance(acted, list) and len(acted) == 2:
        return f"{described}, acted {acted[0]:g}-{acted[1]:g} s"
    return f"{described}, never acted"
