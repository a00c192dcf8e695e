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

Every table has a ``crc`` column: the CRC-32 of the row's other values as SQLite gives
them back (:func:`normal_row`, :func:`row_crc`; the writer thread adds it), checked on
reading, so damage (a flipped byte in a trace chunk, a cell of the wrong type) is detected,
not drawn. A damaged or missing row (the writer never deletes; on closing it writes each
table's row count to meta ``rows``) is skipped and named in ``RunReader.damage`` (:mod:`monitor.runreader`); trace
chunks are used up to the first damaged one. Run files written before checksums open as
*unchecked* (``RunReader.checked`` False): only the types of their cells are checked.

Old run files without the ``link_events`` table open as having none. State values a
controller made up (an integer beyond SQLite's 64 bits, a type it cannot store) are stored
as NULL; the ``raw`` column keeps the text they came from.

Numpy data is stored as raw bytes plus a JSON header naming dtype (``dtype.descr``) and
shape; reading validates the header (no object fields, sizes that add up) and uses
``np.frombuffer`` -- nothing stored is ever executed (no pickle).

Durability: WAL journal, ``synchronous=NORMAL``. Appends go through a queue to one writer
thread that owns the connection and commits at least every ``commit_interval`` seconds,
so a ``kill -9`` loses at most that much and the file still opens; the session's hot loop
never waits on the disk. The session hands its trace chunks on at least as often
(``monitor.live_trace.TRACE_CHUNK_S``), and each chunk's ``stage_to`` says up to which stage
the model is rebuilt: a reader ends a run whose cuts go further (cut short) there
(``monitor.trace_io.RunView.cut_short``).
"""

from __future__ import annotations

import json
import math
import queue
import sqlite3
import threading
import time
import zlib
from datetime import datetime
from pathlib import Path

import numpy as np

from monitor.jsonable import json_default
from sim.errors import InputError

FORMAT = "dexmon-run"
VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value TEXT NOT NULL, crc INTEGER);
CREATE TABLE IF NOT EXISTS arrays(name TEXT PRIMARY KEY, header TEXT NOT NULL, data BLOB NOT NULL, crc INTEGER);
CREATE TABLE IF NOT EXISTS states(
    id INTEGER PRIMARY KEY, t REAL NOT NULL,
    mx REAL, my REAL, mz REAL, ma REAL, mb REAL, mc REAL,
    wx REAL, wy REAL, wz REAL, wa REAL, wb REAL, wc REAL,
    state TEXT, substate INTEGER, feed REAL, spindle REAL, line INTEGER,
    ovr_feed INTEGER, ovr_rapid INTEGER, ovr_spindle INTEGER, alarm INTEGER, raw TEXT, crc INTEGER);
CREATE TABLE IF NOT EXISTS findings(
    id INTEGER PRIMARY KEY, t REAL, kind TEXT NOT NULL, line INTEGER, lead_time_s REAL,
    json TEXT NOT NULL, crc INTEGER);
CREATE TABLE IF NOT EXISTS alerts(
    id INTEGER PRIMARY KEY, t REAL, finding_id INTEGER, channel TEXT NOT NULL, text TEXT NOT NULL,
    crc INTEGER);
CREATE TABLE IF NOT EXISTS cuts(
    id INTEGER PRIMARY KEY, stage INTEGER NOT NULL, t REAL, move_id INTEGER, line INTEGER,
    header TEXT NOT NULL, data BLOB NOT NULL, crc INTEGER);
CREATE TABLE IF NOT EXISTS trace(
    id INTEGER PRIMARY KEY, stage_from INTEGER NOT NULL, stage_to INTEGER NOT NULL,
    header TEXT NOT NULL, data BLOB NOT NULL, crc INTEGER);
CREATE TABLE IF NOT EXISTS link_events(
    id INTEGER PRIMARY KEY, t REAL, kind TEXT NOT NULL, json TEXT NOT NULL, crc INTEGER);
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


#: per table, the columns its ``crc`` covers and what each holds: T/t text, B blob, F/f a
#: number, I/i an integer (upper case: never NULL)
TABLES = {
    "meta": {"key": "T", "value": "T"},
    "arrays": {"name": "T", "header": "T", "data": "B"},
    "states": {"t": "F", **{c: "f" for c in STATE_COLUMNS[1:13]}, "state": "t", "substate": "i", "feed": "f",
               "spindle": "f", "line": "i", "ovr_feed": "i", "ovr_rapid": "i", "ovr_spindle": "i",
               "alarm": "i", "raw": "t"},
    "findings": {"t": "f", "kind": "T", "line": "i", "lead_time_s": "f", "json": "T"},
    "alerts": {"t": "f", "finding_id": "i", "channel": "T", "text": "T"},
    "cuts": {"stage": "I", "t": "f", "move_id": "i", "line": "i", "header": "T", "data": "B"},
    "trace": {"stage_from": "I", "stage_to": "I", "header": "T", "data": "B"},
    "link_events": {"t": "f", "kind": "T", "json": "T"},
}


def normal_row(table: str, values) -> tuple:
    """A row's values as SQLite will give them back (what :func:`row_crc` is taken of):
    numbers in REAL columns as floats, integral ones in INTEGER columns as ints, NaN as
    NULL, -0.0 as 0.0; numbers a column cannot hold (not a number, beyond 64 bits) NULL."""
    return tuple(_normal(v, kind) for v, kind in zip(values, TABLES[table].values()))


def _normal(v, kind: str):
    if v is None:
        return None
    if kind in "TtBb":
        return (v if isinstance(v, str) else str(v)) if kind in "Tt" else bytes(v)
    if not isinstance(v, (int, float, np.integer, np.floating)):
        return None
    try:
        f = float(v)
    except OverflowError:
        return None
    if f != f:
        return None
    if kind in "Ii" and (isinstance(v, (int, np.integer)) or f.is_integer()) and abs(f) < 2**63:
        return int(v)
    return f + 0.0  # + 0.0: no -0.0


def row_crc(values) -> int:
    """CRC-32 of one row's values (as :func:`normal_row` makes them): of their ``repr``,
    so a number that became text or a float that became an integer does not match."""
    return zlib.crc32(repr(tuple(values)).encode("utf-8", "surrogatepass"))


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
                raise RunFileError(f"bad dtype field {str(field)[:80]}", where)
            name, sub = field[0], tuples(field[1])
            out.append((name, sub) if len(field) == 2 else (name, sub, tuple(int(x) for x in field[2])))
        return out
    try:
        dtype = np.lib.format.descr_to_dtype(tuples(descr))
    except (TypeError, ValueError, KeyError, OverflowError, RecursionError) as exc:
        raise RunFileError(f"bad dtype {descr!r} ({exc})", where) from exc
    if dtype.hasobject:
        raise RunFileError("object arrays are not allowed in a run file", where)
    return dtype


def parse_json(text, what: str, where: str):
    """``text`` parsed as JSON, else RunFileError naming ``what``."""
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, UnicodeDecodeError
        raise RunFileError(f"{what} is not JSON ({str(exc)[:80]})", where) from exc


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
    entries = parse_json(header, "array header", where)
    if not isinstance(entries, list):
        raise RunFileError("array header must be a list", where)
    out = {}
    buf = memoryview(data)
    for e in entries:
        try:
            name, descr, shape = e["name"], e["dtype"], [int(s) for s in e["shape"]]
            offset, nbytes = int(e["offset"]), int(e["nbytes"])
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise RunFileError(f"bad array header entry {str(e)[:80]}", where) from exc
        dtype = _descr_to_dtype(descr, f"{where} [{name}]")
        count = math.prod(shape)
        if min(shape, default=0) < 0 or count * dtype.itemsize != nbytes or offset < 0 \
                or offset + nbytes > len(data) or count > 2**40:
            raise RunFileError(f"array {name!r}: shape {shape} of {dtype} does not match "
                               f"{nbytes} bytes at offset {offset} of {len(data)}", where)
        out[name] = np.frombuffer(buf[offset:offset + nbytes], dtype=dtype, count=count).reshape(shape)
    return out


# --- writer ----------------------------------------------------------------------------

_STOP = object()
#: what one row's values can make SQLite raise: that row is skipped, not the run file
_ROW_ERRORS = (OverflowError, sqlite3.InterfaceError, sqlite3.IntegrityError, ValueError, TypeError)


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
        #: (t, kind, line) of each finding appended, for the checksum of its updates
        self._finding_keys: list[tuple] = []
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
        self._row("meta", (key, text), "INSERT OR REPLACE")

    def put_array(self, name: str, arr: np.ndarray) -> None:
        """Store (or replace) one named array, e.g. the move table (``"moves"``)."""
        header, data = pack_arrays({name: arr})
        self._row("arrays", (name, header, data), "INSERT OR REPLACE")

    def append_state(self, s) -> None:
        """Append one :class:`drivers.state.MachineState` (odd values stored as NULL,
        see :func:`sql_value`; ``raw`` always kept as text)."""
        ovr = tuple(s.overrides or ()) + (100,) * (3 - len(s.overrides or ()))
        row = (s.t, *s.mpos, *s.wco, getattr(s.state, "value", str(s.state)), s.substate,
               s.feed, s.spindle, s.line, ovr[0], ovr[1], ovr[2], s.alarm)
        raw = s.raw if isinstance(s.raw, str) else repr(s.raw)
        self._row("states", tuple(sql_value(v) for v in row) + (raw,))

    def append_link_event(self, t: float | None, kind: str, record: dict) -> None:
        """Append one link event or gap record (``kind``: lost, back, reset, bad, note, gap)
        as its JSON object."""
        self._row("link_events", (t, str(kind), json.dumps(record, default=json_default)))

    def append_finding(self, finding: dict, t: float | None = None) -> None:
        """Append one finding as its JSON object (keys ``kind``, ``line``, ``lead_time_s`` indexed)."""
        key = (t, str(finding.get("kind", "")), _int_or_none(finding.get("line")))
        self._finding_keys.append(key)
        self._row("findings", key + (finding.get("lead_time_s"), json.dumps(finding, default=json_default)))

    def update_finding(self, finding_id: int, finding: dict) -> None:
        """Replace the JSON of finding ``finding_id`` (1-based, in append order), e.g. when a
        predicted finding really happened."""
        lead, text = _normal(finding.get("lead_time_s"), "f"), json.dumps(finding, default=json_default)
        key = self._finding_keys[int(finding_id) - 1] if 0 < int(finding_id) <= len(self._finding_keys) else None
        crc = _crc_or_none(normal_row("findings", key + (lead, text))) if key else None
        self._put("UPDATE findings SET lead_time_s = ?, json = ?, crc = ? WHERE id = ?",
                  (lead, text, crc, int(finding_id)))

    def append_alert(self, channel: str, text: str, t: float | None = None, finding_id: int | None = None) -> None:
        self._row("alerts", (t, finding_id, channel, text))

    def append_cut(self, stage: int, arrays: dict[str, np.ndarray], t: float | None = None,
                   move_id: int | None = None, line: int | None = None) -> None:
        """Append the cut delta of one stage (e.g. path points, changed rays and their new segments)."""
        header, data = pack_arrays(arrays)
        self._row("cuts", (int(stage), t, move_id, line, header, data))

    def append_trace_chunk(self, stage_from: int, stage_to: int, arrays: dict[str, np.ndarray]) -> None:
        """Append a z-trace / time-trace chunk covering stages ``stage_from..stage_to``."""
        header, data = pack_arrays(arrays)
        self._row("trace", (int(stage_from), int(stage_to), header, data))

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
    def _row(self, table: str, values: tuple, verb: str = "INSERT") -> None:
        """Queue one row of ``table`` (values of :data:`TABLES` ``[table]``, in order) with its checksum."""
        cols = tuple(TABLES[table]) + ("crc",)
        # the writer thread adds the checksum: the caller's loop does not wait for it
        self._put(f"{verb} INTO {table}({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})",
                  tuple(values), table)

    def _put(self, sql: str, params: tuple, table: str | None = None) -> None:
        """Queue one statement; with ``table``, ``params`` are that table's checked columns
        and the writer thread appends their checksum."""
        self._check()
        if self._closed:
            raise RunFileError("run file is closed", str(self.path))
        self._q.put((sql, params, table))

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
            for key, value in (("format", FORMAT), ("version", str(VERSION)),
                               ("created", datetime.now().isoformat(timespec="seconds"))):
                con.execute("INSERT INTO meta(key, value, crc) VALUES (?, ?, ?)", (key, value, row_crc((key, value))))
        except BaseException as exc:  # reported to the caller by _check
            self._error = exc
            self._closed = True
            self._ready.set()
            return
        self._ready.set()
        in_tx = False
        last_commit = time.monotonic()
        rows: dict[str, int] = {}  # rows appended per table, written as meta "rows" on closing
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
                    sql, params, table = item
                    try:
                        if table:
                            params = normal_row(table, params)
                            params += (row_crc(params),)
                        con.execute(sql, params)
                        if sql.startswith("INSERT INTO "):
                            table = sql[12:].split("(", 1)[0]
                            rows[table] = rows.get(table, 0) + 1
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
                    row = ("rows", json.dumps(rows))
                    con.execute("INSERT OR REPLACE INTO meta(key, value, crc) VALUES (?, ?, ?)", row + (row_crc(row),))
                    if self.skipped:
                        row = ("skipped_rows", json.dumps({"rows": self.skipped, "last": self.last_skip}))
                        con.execute("INSERT OR REPLACE INTO meta(key, value, crc) VALUES (?, ?, ?)",
                                    row + (row_crc(row),))
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


def _crc_or_none(values):
    """:func:`row_crc`, or None for values SQLite will refuse anyway (the row is then skipped)."""
    try:
        return row_crc(values)
    except (TypeError, ValueError, OverflowError):
        return None


def _int_or_none(v):
    try:
        return None if v is None else int(v)
    except (TypeError, ValueError):
        return None
