"""The run file: one SQLite file per run, written as the run goes, readable while written.

Layout (all times are ``MachineState.t`` seconds unless said otherwise)::

    meta(key TEXT PRIMARY KEY, value TEXT)          format, version, job TOML, program text ...
    arrays(name TEXT PRIMARY KEY, header, data)     named numpy arrays (the move table ...)
    states(id, t, mx..mc, wx..wc, state, substate, feed, spindle, line,
           ovr_feed, ovr_rapid, ovr_spindle, alarm, raw)
    findings(id, t, kind, line, lead_time_s, json)
    alerts(id, t, finding_id, channel, text)
    cuts(id, stage, t, move_id, line, header, data)  cut deltas: named arrays per stage
    trace(id, stage_from, stage_to, header, data)    z-trace / time-trace chunks
    link_events(id, t, kind, json)                   link trouble: lost, back, reset, bad,
                                                     note (as the driver told it) and gap
                                                     (the session's record of each gap)

Old run files without the ``link_events`` table open as having none. State values a
controller made up (an integer beyond SQLite's 64 bits, a type it cannot store) are stored
as NULL; the ``raw`` column keeps the text they came from.

Numpy data is stored as raw bytes plus a JSON header naming dtype (``dtype.descr``) and
shape; reading validates the header (no object fields, sizes that add up) and uses
``np.frombuffer`` -- nothing stored is ever executed (no pickle).

Durability: WAL journal, ``synchronous=NORMAL``. Appends go through a queue to one writer
thread that owns the connection and commits at least every ``commit_interval`` seconds,
so a ``kill -9`` loses at most that much and the file still opens; the session's hot loop
never waits on the disk.
"""

from __future__ import annotations

import json
import queue
import sqlite3
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Iterator

import numpy as np

from monitor.jsonable import json_default
from sim.errors import InputError

FORMAT = "dexmon-run"
VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS arrays(name TEXT PRIMARY KEY, header TEXT NOT NULL, data BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS states(
    id INTEGER PRIMARY KEY, t REAL NOT NULL,
    mx REAL, my REAL, mz REAL, ma REAL, mb REAL, mc REAL,
    wx REAL, wy REAL, wz REAL, wa REAL, wb REAL, wc REAL,
    state TEXT, substate INTEGER, feed REAL, spindle REAL, line INTEGER,
    ovr_feed INTEGER, ovr_rapid INTEGER, ovr_spindle INTEGER, alarm INTEGER, raw TEXT);
CREATE TABLE IF NOT EXISTS findings(
    id INTEGER PRIMARY KEY, t REAL, kind TEXT NOT NULL, line INTEGER, lead_time_s REAL,
    json TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS alerts(
    id INTEGER PRIMARY KEY, t REAL, finding_id INTEGER, channel TEXT NOT NULL, text TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS cuts(
    id INTEGER PRIMARY KEY, stage INTEGER NOT NULL, t REAL, move_id INTEGER, line INTEGER,
    header TEXT NOT NULL, data BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS trace(
    id INTEGER PRIMARY KEY, stage_from INTEGER NOT NULL, stage_to INTEGER NOT NULL,
    header TEXT NOT NULL, data BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS link_events(
    id INTEGER PRIMARY KEY, t REAL, kind TEXT NOT NULL, json TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS cuts_stage ON cuts(stage);
CREATE INDEX IF NOT EXISTS trace_stage ON trace(stage_from);
"""

STATE_COLUMNS = ("t", "mx", "my", "mz", "ma", "mb", "mc", "wx", "wy", "wz", "wa", "wb", "wc",
                 "state", "substate", "feed", "spindle", "line",
                 "ovr_feed", "ovr_rapid", "ovr_spindle", "alarm", "raw")

#: the states table as numpy: ``RunReader.states()`` returns this dtype
STATE_DTYPE = np.dtype([
    ("t", np.float64), ("mpos", np.float64, 6), ("wco", np.float64, 6),
    ("state", "U12"), ("substate", np.int32), ("feed", np.float64), ("spindle", np.float64),
    ("line", np.int32), ("overrides", np.int32, 3), ("alarm", np.int32),
])


class RunFileError(InputError):
    """A file that is not a dexmon run file, is corrupt, or cannot be written."""


def default_run_path(folder: str | Path = "runs", now: datetime | None = None) -> Path:
    """A new time-stamped path ``folder/run-YYYYmmdd-HHMMSS[-n].sqlite`` that does not exist yet."""
    folder = Path(folder)
    stamp = (now or datetime.now()).strftime("%Y%m%d-%H%M%S")
    path = folder / f"run-{stamp}.sqlite"
    n = 1
    while path.exists():
        path = folder / f"run-{stamp}-{n}.sqlite"
        n += 1
    return path


# --- numpy <-> bytes, never pickle -------------------------------------------------------

def _descr_to_dtype(descr, where: str) -> np.dtype:
    """Rebuild a dtype from its JSON-decoded ``descr``; refuse object and malformed types."""
    def tuples(d):
        if isinstance(d, str):
            return d
        out = []
        for field in d:
            if not isinstance(field, list) or len(field) not in (2, 3) or not isinstance(field[0], str):
                raise RunFileError(f"bad dtype field {field!r}", where)
            name, sub = field[0], tuples(field[1])
            out.append((name, sub) if len(field) == 2 else (name, sub, tuple(int(x) for x in field[2])))
        return out
    try:
        dtype = np.lib.format.descr_to_dtype(tuples(descr))
    except (TypeError, ValueError) as exc:
        raise RunFileError(f"bad dtype {descr!r} ({exc})", where) from exc
    if dtype.hasobject:
        raise RunFileError("object arrays are not allowed in a run file", where)
    return dtype


def pack_arrays(arrays: dict[str, np.ndarray]) -> tuple[str, bytes]:
    """Named arrays -> (JSON header, one blob of their raw C-order bytes)."""
    header, parts, offset = [], [], 0
    for name, arr in arrays.items():
        arr = np.ascontiguousarray(arr)
        if arr.dtype.hasobject:
            raise TypeError(f"array {name!r}: object dtype cannot be stored")
        raw = arr.tobytes()
        header.append({"name": str(name), "dtype": arr.dtype.descr if arr.dtype.names else arr.dtype.str,
                       "shape": list(arr.shape), "offset": offset, "nbytes": len(raw)})
        parts.append(raw)
        offset += len(raw)
    return json.dumps(header), b"".join(parts)


def unpack_arrays(header: str, data: bytes, where: str) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack_arrays`; validates every entry. Arrays are read-only views."""
    try:
        entries = json.loads(header)
    except json.JSONDecodeError as exc:
        raise RunFileError(f"array header is not JSON ({exc})", where) from exc
    if not isinstance(entries, list):
        raise RunFileError("array header must be a list", where)
    out = {}
    buf = memoryview(data)
    for e in entries:
        try:
            name, descr, shape = e["name"], e["dtype"], [int(s) for s in e["shape"]]
            offset, nbytes = int(e["offset"]), int(e["nbytes"])
        except (KeyError, TypeError, ValueError) as exc:
            raise RunFileError(f"bad array header entry {e!r}", where) from exc
        dtype = _descr_to_dtype(descr, f"{where} [{name}]")
        count = int(np.prod(shape)) if shape else 1
        if min(shape, default=0) < 0 or count * dtype.itemsize != nbytes or offset < 0 \
                or offset + nbytes > len(data):
            raise RunFileError(f"array {name!r}: shape {shape} of {dtype} does not match "
                               f"{nbytes} bytes at offset {offset} of {len(data)}", where)
        out[name] = np.frombuffer(buf[offset:offset + nbytes], dtype=dtype, count=count).reshape(shape)
    return out


# --- writer ----------------------------------------------------------------------------

_STOP = object()
#: what one row's values can make SQLite raise: that row is skipped, not the run file
_ROW_ERRORS = (OverflowError, sqlite3.InterfaceError, ValueError, TypeError)


class RunWriter:
    """Append-only writer of one run file. Thread-safe appends; one writer thread does SQL.

    ``path`` must not exist yet (a run file is never overwritten). Calls return at once;
    :meth:`flush` waits until everything appended so far is committed. An error in the
    writer thread is raised by the next call.
    """

    def __init__(self, path: str | Path, commit_interval: float = 0.25):
        self.path = Path(path)
        if self.path.exists():
            raise RunFileError("run file already exists; give a new name with --run", str(self.path))
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RunFileError(f"cannot create the folder ({exc.strerror})", str(self.path)) from exc
        self.commit_interval = float(commit_interval)
        self._q: queue.Queue = queue.Queue()
        self._error: BaseException | None = None
        self._ready = threading.Event()
        self._closed = False
        self._stage = 0
        #: rows SQLite refused (a value it cannot store): skipped, counted, the run goes on
        self.skipped = 0
        self.last_skip = ""
        self._thread = threading.Thread(target=self._loop, name=f"runfile:{self.path.name}", daemon=True)
        self._thread.start()
        self._ready.wait()
        self._check()

    # -- public appends
    def put_meta(self, key: str, value) -> None:
        """Set a meta entry; non-strings are stored as JSON."""
        text = value if isinstance(value, str) else json.dumps(value)
        self._put("INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)", (key, text))

    def put_array(self, name: str, arr: np.ndarray) -> None:
        """Store (or replace) one named array, e.g. the move table (``"moves"``)."""
        header, data = pack_arrays({name: arr})
        self._put("INSERT OR REPLACE INTO arrays(name, header, data) VALUES (?, ?, ?)", (name, header, data))

    def append_state(self, s) -> None:
        """Append one :class:`drivers.state.MachineState` (odd values stored as NULL,
        see :func:`sql_value`; ``raw`` always kept as text)."""
        ovr = tuple(s.overrides or ()) + (100,) * (3 - len(s.overrides or ()))
        row = (s.t, *s.mpos, *s.wco, getattr(s.state, "value", str(s.state)), s.substate,
               s.feed, s.spindle, s.line, ovr[0], ovr[1], ovr[2], s.alarm)
        raw = s.raw if isinstance(s.raw, str) else repr(s.raw)
        self._put(f"INSERT INTO states({', '.join(STATE_COLUMNS)}) VALUES "
                  f"({', '.join('?' * len(STATE_COLUMNS))})", tuple(sql_value(v) for v in row) + (raw,))

    def append_link_event(self, t: float | None, kind: str, record: dict) -> None:
        """Append one link event or gap record (``kind``: lost, back, reset, bad, note, gap)
        as its JSON object."""
        self._put("INSERT INTO link_events(t, kind, json) VALUES (?, ?, ?)",
                  (sql_value(t), str(kind), json.dumps(record, default=json_default)))

    def append_finding(self, finding: dict, t: float | None = None) -> None:
        """Append one finding as its JSON object (keys ``kind``, ``line``, ``lead_time_s`` indexed)."""
        self._put("INSERT INTO findings(t, kind, line, lead_time_s, json) VALUES (?, ?, ?, ?, ?)",
                  (t, str(finding.get("kind", "")), _int_or_none(finding.get("line")),
                   _float_or_none(finding.get("lead_time_s")), json.dumps(finding, default=json_default)))

    def update_finding(self, finding_id: int, finding: dict) -> None:
        """Replace the JSON of finding ``finding_id`` (1-based, in append order), e.g. when a
        predicted finding really happened."""
        self._put("UPDATE findings SET lead_time_s = ?, json = ? WHERE id = ?",
                  (_float_or_none(finding.get("lead_time_s")), json.dumps(finding, default=json_default),
                   int(finding_id)))

    def append_alert(self, channel: str, text: str, t: float | None = None, finding_id: int | None = None) -> None:
        self._put("INSERT INTO alerts(t, finding_id, channel, text) VALUES (?, ?, ?, ?)",
                  (t, finding_id, channel, text))

    def append_cut(self, stage: int, arrays: dict[str, np.ndarray], t: float | None = None,
                   move_id: int | None = None, line: int | None = None) -> None:
        """Append the cut delta of one stage (e.g. path points, changed rays and their new segments)."""
        header, data = pack_arrays(arrays)
        self._put("INSERT INTO cuts(stage, t, move_id, line, header, data) VALUES (?, ?, ?, ?, ?, ?)",
                  (int(stage), t, move_id, line, header, data))

    def append_trace_chunk(self, stage_from: int, stage_to: int, arrays: dict[str, np.ndarray]) -> None:
        """Append a z-trace / time-trace chunk covering stages ``stage_from..stage_to``."""
        header, data = pack_arrays(arrays)
        self._put("INSERT INTO trace(stage_from, stage_to, header, data) VALUES (?, ?, ?, ?)",
                  (int(stage_from), int(stage_to), header, data))

    def flush(self, timeout: float = 30.0) -> None:
        """Block until everything appended so far is committed."""
        self._check()
        done = threading.Event()
        self._q.put(done)
        if not done.wait(timeout):
            raise RunFileError(f"writer did not commit within {timeout} s", str(self.path))
        self._check()

    def close(self) -> None:
        """Commit everything and close the file. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._q.put(_STOP)
        self._thread.join()
        self._check()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    # -- internals
    def _put(self, sql: str, params: tuple) -> None:
        self._check()
        if self._closed:
            raise RunFileError("run file is closed", str(self.path))
        self._q.put((sql, params))

    def _check(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            if isinstance(err, RunFileError):
                raise err
            raise RunFileError(f"cannot write the run file ({err})", str(self.path)) from err

    def _loop(self) -> None:
        try:
            con = sqlite3.connect(str(self.path), isolation_level=None)
            con.execute("PRAGMA journal_mode=WAL")
            con.execute("PRAGMA synchronous=NORMAL")
            con.executescript(_SCHEMA)
            con.execute("INSERT INTO meta(key, value) VALUES ('format', ?), ('version', ?), ('created', ?)",
                        (FORMAT, str(VERSION), datetime.now().isoformat(timespec="seconds")))
        except BaseException as exc:  # reported to the caller by _check
            self._error = exc
            self._closed = True
            self._ready.set()
            return
        self._ready.set()
        in_tx = False
        last_commit = time.monotonic()
        try:
            while True:
                wait = max(self.commit_interval - (time.monotonic() - last_commit), 0.0) if in_tx else None
                try:
                    item = self._q.get(timeout=wait)
                except queue.Empty:
                    item = None  # time to commit
                if isinstance(item, tuple):
                    if not in_tx:
                        con.execute("BEGIN")
                        in_tx = True
                    try:
                        con.execute(*item)
                    except _ROW_ERRORS as exc:  # one row SQLite cannot take: skip it, go on
                        self.skipped += 1
                        self.last_skip = f"{type(exc).__name__}: {exc}"
                    if time.monotonic() - last_commit < self.commit_interval:
                        continue
                if in_tx:
                    con.execute("COMMIT")
                    in_tx = False
                last_commit = time.monotonic()
                if isinstance(item, threading.Event):
                    item.set()
                elif item is _STOP:
                    if self.skipped:
                        con.execute("INSERT OR REPLACE INTO meta(key, value) VALUES ('skipped_rows', ?)",
                                    (json.dumps({"rows": self.skipped, "last": self.last_skip}),))
                    break
        except BaseException as exc:
            self._error = exc
            # keep draining so flush() callers are released
            while True:
                try:
                    item = self._q.get_nowait()
                except queue.Empty:
                    break
                if isinstance(item, threading.Event):
                    item.set()
        finally:
            try:
                if in_tx:
                    con.execute("COMMIT")
            except sqlite3.Error:
                pass
            con.close()


#: SQLite's INTEGER range
_SQL_INT = (-(2**63), 2**63 - 1)


def sql_value(v):
    """``v`` as SQLite stores it: ints within 64 bits, floats, text; anything else (an
    integer beyond 64 bits, an object) None -- a state a controller made up must not stop
    the run file."""
    if v is None or isinstance(v, str):
        return v
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (int, np.integer)):
        v = int(v)
        return v if _SQL_INT[0] <= v <= _SQL_INT[1] else None
    if isinstance(v, (float, np.floating)):
        return float(v)
    return None


def _int_or_none(v):
    try:
        return None if v is None else int(v)
    except (TypeError, ValueError):
        return None


def _float_or_none(v):
    try:
        return None if v is None else float(v)
    except (TypeError, ValueError):
        return None


# --- reader ------------------------------------------------------------------------------

class RunReader:
    """Read a run file, also while it is being written (WAL readers see the last commit)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        where = str(self.path)
        if not self.path.is_file():
            raise RunFileError("no such run file", where)
        try:
            self._con = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
            rows = dict(self._con.execute("SELECT key, value FROM meta").fetchall())
        except sqlite3.DatabaseError as exc:
            raise RunFileError(f"not a dexmon run file ({exc})", where) from exc
        if rows.get("format") != FORMAT:
            raise RunFileError(f"not a dexmon run file (meta format is {rows.get('format')!r})", where)
        try:
            version = int(rows.get("version", "0"))
        except ValueError:
            version = -1
        if version != VERSION:
            raise RunFileError(f"run file version {rows.get('version')!r}, this dexmon reads {VERSION}", where)

    def _query(self, sql: str, params: tuple = ()) -> list:
        try:
            return self._con.execute(sql, params).fetchall()
        except sqlite3.DatabaseError as exc:
            raise RunFileError(f"corrupt run file ({exc})", str(self.path)) from exc

    def meta(self) -> dict[str, str]:
        return dict(self._query("SELECT key, value FROM meta"))

    def array_names(self) -> list[str]:
        return [r[0] for r in self._query("SELECT name FROM arrays ORDER BY name")]

    def get_array(self, name: str) -> np.ndarray:
        rows = self._query("SELECT header, data FROM arrays WHERE name = ?", (name,))
        if not rows:
            raise RunFileError(f"no array named {name!r} (has {self.array_names()})", str(self.path))
        arrays = unpack_arrays(rows[0][0], rows[0][1], f"{self.path} arrays[{name}]")
        if name not in arrays:
            raise RunFileError(f"array {name!r} header names {sorted(arrays)}", str(self.path))
        return arrays[name]

    def states(self) -> np.ndarray:
        """All machine states, a structured array of :data:`STATE_DTYPE` in time order."""
        rows = self._query(f"SELECT {', '.join(STATE_COLUMNS[:-1])} FROM states ORDER BY id")
        out = np.zeros(len(rows), STATE_DTYPE)
        if rows:
            cols = list(zip(*rows))
            f = lambda c, default=0: np.array([default if v is None else v for v in c])  # noqa: E731
            out["t"] = f(cols[0])
            out["mpos"] = np.stack([f(c) for c in cols[1:7]], axis=1)
            out["wco"] = np.stack([f(c) for c in cols[7:13]], axis=1)
            out["state"] = [c or "" for c in cols[13]]
            out["substate"] = f(cols[14], -1)
            out["feed"] = f(cols[15])
            out["spindle"] = f(cols[16])
            out["line"] = f(cols[17], -1)
            out["overrides"] = np.stack([f(c, 100) for c in cols[18:21]], axis=1)
            out["alarm"] = f(cols[21], -1)
        return out

    def state_count(self) -> int:
        return int(self._query("SELECT COUNT(*) FROM states")[0][0])

    def findings(self) -> list[dict]:
        out = []
        for fid, t, js in self._query("SELECT id, t, json FROM findings ORDER BY id"):
            try:
                d = json.loads(js)
            except json.JSONDecodeError as exc:
                raise RunFileError(f"finding {fid} is not JSON ({exc})", str(self.path)) from exc
            out.append(d)
        return out

    def alerts(self) -> list[dict]:
        return [{"t": t, "finding_id": fid, "channel": ch, "text": text}
                for t, fid, ch, text in self._query("SELECT t, finding_id, channel, text FROM alerts ORDER BY id")]

    def cuts(self, stage_from: int = 0, stage_to: int | None = None) -> Iterator[dict]:
        """Cut deltas in stage order: dicts with ``stage, t, move_id, line, arrays``."""
        hi = 2**62 if stage_to is None else int(stage_to)
        for cid, stage, t, mid, line, header, data in self._query(
                "SELECT id, stage, t, move_id, line, header, data FROM cuts "
                "WHERE stage >= ? AND stage <= ? ORDER BY stage, id", (int(stage_from), hi)):
            yield {"stage": stage, "t": t, "move_id": mid, "line": line,
                   "arrays": unpack_arrays(header, data, f"{self.path} cuts[{cid}]")}

    def link_events(self) -> list[dict]:
        """Link events and gap records in the order written (each its JSON object plus
        ``kind`` and ``t``); [] for a run file written before the table existed."""
        try:
            rows = self._con.execute("SELECT id, t, kind, json FROM link_events ORDER BY id").fetchall()
        except sqlite3.OperationalError as exc:
            if "no such table" in str(exc):
                return []
            raise RunFileError(f"corrupt run file ({exc})", str(self.path)) from exc
        except sqlite3.DatabaseError as exc:
            raise RunFileError(f"corrupt run file ({exc})", str(self.path)) from exc
        out = []
        for eid, t, kind, js in rows:
            try:
                rec = json.loads(js)
            except json.JSONDecodeError as exc:
                raise RunFileError(f"link event {eid} is not JSON ({exc})", str(self.path)) from exc
            out.append({**rec, "kind": kind, "t": t})
        return out

    def trace_chunks(self) -> Iterator[tuple[int, int, dict[str, np.ndarray]]]:
        """``(stage_from, stage_to, arrays)`` in the order written."""
        for cid, a, b, header, data in self._query(
                "SELECT id, stage_from, stage_to, header, data FROM trace ORDER BY id"):
            yield a, b, unpack_arrays(header, data, f"{self.path} trace[{cid}]")

    def close(self) -> None:
        self._con.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
