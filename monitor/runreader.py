"""Reading a run file (the format is :mod:`monitor.runfile`'s), also while it is written.

Every row's checksum and cell types are checked as it is read: a damaged, mistyped or
missing row is skipped and named in :attr:`RunReader.damage`, so ``replay`` and ``report``
use what is intact and say in one line what they skipped; trace chunks are used up to the
first damaged one. A file damaged beyond opening is one :class:`RunFileError` line.
Nothing stored is ever executed (arrays through ``np.frombuffer``, JSON through ``json``).
"""

from __future__ import annotations

import json
import math
import sqlite3
from pathlib import Path
from typing import Iterator

import numpy as np

from monitor.runfile import (FORMAT, STATE_DTYPE, TABLES, VERSION, RunFileError, parse_json, row_crc,
                             unpack_arrays)

#: what reading a damaged SQLite file raises (a schema whose names are not UTF-8: UnicodeDecodeError)
_SQL_ERRORS = (sqlite3.Error, UnicodeDecodeError)
#: tables a run file has had from the start (link_events came later)
_FIRST_TABLES = ("meta", "arrays", "states", "findings", "alerts", "cuts", "trace")
#: at most this many damaged places are named in one warning line
_NAMED = 4


class RunReader:
    """Read a run file, also while it is being written (WAL readers see the last commit).

    Rows whose checksum or types do not hold are skipped; ``damage`` names each (table and
    row, what was wrong) for the one-line warning of the commands (:meth:`damage_line`).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        where = str(self.path)
        #: damaged places found so far, in the order found (a dict: each named once)
        self._damage: dict[str, None] = {}
        self._row_counts: dict[str, int] = {}
        #: rows read per table, kept once the writer has closed the file (it changes no more)
        self._read: dict[str, list] = {}
        if not self.path.is_file():
            raise RunFileError("no such run file", where)
        try:
            self._con = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
            self._columns = {name: {r[1] for r in self._con.execute(f"PRAGMA table_info({name})")}
                             for name in TABLES}
        except _SQL_ERRORS as exc:
            raise RunFileError(f"not a dexmon run file, or damaged beyond opening ({_said(exc)}); nothing readable",
                               where) from exc
        try:
            self._check_format()
        except RunFileError:
            self._con.close()
            raise

    def _check_format(self) -> None:
        """RunFileError unless the meta table says this is a run file this dexmon reads."""
        where = str(self.path)
        if not self._columns["meta"]:
            if self._columns["trace"] and self._columns["states"]:
                self.checked = True
                raise self.damaged("table meta (missing)")
            raise RunFileError("not a dexmon run file (no meta table)", where)
        #: False for run files written before rows carried checksums: damage may go unseen
        self.checked = all("crc" in self._columns[t] for t in _FIRST_TABLES if self._columns[t])
        rows = self.meta()
        #: rows appended per table as the writer counted them when it closed ({} if it did not)
        self._row_counts = _counts(rows.get("rows"))
        if self._damage and (rows.get("format") != FORMAT or rows.get("version") is None):
            raise self.damaged(f"meta format or version unreadable ({self.damage[0]})")
        if rows.get("format") != FORMAT:
            raise RunFileError(f"not a dexmon run file (meta format is {rows.get('format')!r})", where)
        try:
            version = int(rows.get("version", "0"))
        except ValueError:
            version = -1
        if version != VERSION:
            raise RunFileError(f"run file version {rows.get('version')!r}, this dexmon reads {VERSION}", where)

    # -- damage
    @property
    def damage(self) -> list[str]:
        """What was found damaged and skipped so far, e.g. ``"trace row 2 (checksum mismatch)"``."""
        return list(self._damage)

    def note(self, what: str) -> None:
        """Name one damaged place (once)."""
        self._damage.setdefault(what, None)

    def damage_line(self) -> str | None:
        """One line naming what was damaged and skipped, or None for an intact file."""
        if not self._damage:
            return None
        named = self.damage[:_NAMED]
        more = len(self._damage) - len(named)
        return (f"{self.path} is damaged; skipped {', '.join(named)}"
                f"{f' and {more} more' if more else ''}; used what is intact")

    def damaged(self, what: str) -> RunFileError:
        """The error for damage that leaves nothing to show: names it and what is still readable."""
        try:
            readable = f"{len(self.states())} states, {len(self.findings())} findings readable"
        except (RunFileError, *_SQL_ERRORS):
            readable = "no states or findings readable"
        return RunFileError(f"run file is damaged: {what}; {readable}", str(self.path))

    # -- rows
    def _query(self, sql: str, params: tuple = ()) -> list:
        """Raw SQL rows (unchecked)."""
        try:
            return self._con.execute(sql, params).fetchall()
        except _SQL_ERRORS as exc:
            raise self.damaged(_said(exc)) from exc

    def _rows(self, table: str, contiguous: bool = True) -> list[tuple]:
        """``(rowid, values)`` of the rows of ``table`` whose checksum and types hold, in
        rowid order; values as :data:`TABLES` lists them (text as str, blobs as bytes,
        numbers as int/float). Damaged rows, rows missing between others (``contiguous``:
        the writer never deletes) and a table that is gone are noted and skipped."""
        if table in self._read:
            return self._read[table]
        cols = TABLES[table]
        have = self._columns[table]
        if not have:
            if table in _FIRST_TABLES or self.checked:
                self.note(f"table {table} (missing)")
            return []
        checked = "crc" in have
        sql = f"SELECT rowid, {', '.join(cols)}{', crc' if checked else ''} FROM {table} ORDER BY rowid"
        out, last = [], 0 if contiguous else None
        texts = [i for i, kind in enumerate(cols.values()) if kind in "Tt"]
        self._con.text_factory = bytes  # text that is not UTF-8 is one damaged row, not an error
        try:
            for row in self._con.execute(sql):
                rid, values = row[0], list(row[1:1 + len(cols)])
                if contiguous and last is not None and rid != last + 1:
                    self.note(f"{table} rows {last + 1}..{rid - 1} (missing)" if rid > last + 2
                               else f"{table} row {last + 1} (missing)")
                last = rid
                problem = _decode_texts(values, texts, cols)
                if problem is None and checked:
                    problem = None if _crc_matches(values, row[-1]) else "checksum mismatch"
                elif problem is None:  # unchecked: only the types guard what follows
                    problem = _type_problem(values, cols)
                    values = [_as_read(v, kind) for v, kind in zip(values, cols.values())]
                if problem:
                    self.note(f"{table} row {rid} ({problem})")
                    continue
                out.append((rid, tuple(values)))
        except _SQL_ERRORS as exc:
            self.note(f"{table} after row {last or 0} ({_said(exc)})")
        finally:
            self._con.text_factory = str
        written = self._row_counts.get(table, 0) if contiguous else 0
        if last is not None and written > last:
            self.note(f"{table} rows {last + 1}..{written} (missing)" if written > last + 1
                      else f"{table} row {written} (missing)")
        if self._row_counts:  # closed by its writer: nothing changes any more
            self._read[table] = out
        return out

    def meta(self) -> dict[str, str]:
        return dict(v for _, v in self._rows("meta", contiguous=False))

    def _arrays(self) -> dict[str, tuple[int, str, bytes]]:
        return {name: (rid, header, data) for rid, (name, header, data) in self._rows("arrays", contiguous=False)}

    def array_names(self) -> list[str]:
        return sorted(self._arrays())

    def get_array(self, name: str) -> np.ndarray:
        arrays = self._arrays()
        if name not in arrays:
            damaged = [d for d in self._damage if d.startswith("arrays") or d.startswith("table arrays")]
            if damaged:
                raise self.damaged(f"array {name!r} unreadable ({damaged[0]})")
            raise RunFileError(f"no array named {name!r} (has {sorted(arrays)})", str(self.path))
        rid, header, data = arrays[name]
        try:
            out = unpack_arrays(header, data, f"{self.path} arrays row {rid} ({name})")
        except RunFileError as exc:
            self.note(f"arrays row {rid} ({name}: {_reason(exc)})")
            raise
        if name not in out:
            raise RunFileError(f"array {name!r} header names {sorted(out)}", str(self.path))
        return out[name]

    def states(self) -> np.ndarray:
        """All readable machine states, a structured array of :data:`STATE_DTYPE` in time order."""
        rows = [v for _, v in self._rows("states")]
        out = np.zeros(len(rows), STATE_DTYPE)
        if rows:
            cols = list(zip(*rows))
            f = lambda c, default=0: np.array([default if v is None else v for v in c], np.float64)  # noqa: E731
            i32 = lambda c, default: np.array([v if isinstance(v, int) and -2**31 <= v < 2**31 else default  # noqa: E731
                                               for v in c], np.int32)
            out["t"] = f(cols[0])
            out["mpos"] = np.stack([f(c) for c in cols[1:7]], axis=1)
            out["wco"] = np.stack([f(c) for c in cols[7:13]], axis=1)
            out["state"] = [(c or "")[:12] for c in cols[13]]
            out["substate"] = i32(cols[14], -1)
            out["feed"] = f(cols[15])
            out["spindle"] = f(cols[16])
            out["line"] = i32(cols[17], -1)
            out["overrides"] = np.stack([i32(c, 100) for c in cols[18:21]], axis=1)
            out["alarm"] = i32(cols[21], -1)
        return out

    def state_count(self) -> int:
        """How many states are readable."""
        return len(self._rows("states"))

    def _json_rows(self, table: str, fields: dict) -> Iterator[tuple[int, tuple, dict]]:
        """``(rowid, values, object)`` of the rows whose ``json`` column holds a JSON object
        whose ``fields`` (key -> test) are None or pass their test (what the commands rely on;
        an unchecked file may hold anything)."""
        for rid, values in self._rows(table):
            try:
                obj = parse_json(values[-1], "json", "")
            except RunFileError:
                obj = None
            if not isinstance(obj, dict):
                self.note(f"{table} row {rid} (json is not a JSON object)")
                continue
            bad = next((k for k, test in fields.items() if obj.get(k) is not None and not test(obj[k])), None)
            if bad:
                self.note(f"{table} row {rid} ({bad} is {repr(obj[bad])[:20]}, expected {fields[bad].__doc__})")
                continue
            yield rid, values, obj

    def findings(self) -> list[dict]:
        return [obj for _, _, obj in self._json_rows("findings", _FINDING_FIELDS)]

    def alerts(self) -> list[dict]:
        return [{"t": t, "finding_id": fid, "channel": ch, "text": text}
                for _, (t, fid, ch, text) in self._rows("alerts")]

    def cuts(self, stage_from: int = 0, stage_to: int | None = None) -> Iterator[dict]:
        """Readable cut deltas in stage order: dicts with ``stage, t, move_id, line, arrays``."""
        hi = math.inf if stage_to is None else int(stage_to)
        rows = sorted(self._rows("cuts"), key=lambda r: (r[1][0], r[0]))
        for cid, (stage, t, mid, line, header, data) in rows:
            if not stage_from <= stage <= hi:
                continue
            try:
                arrays = unpack_arrays(header, data, f"{self.path} cuts row {cid}")
            except RunFileError as exc:
                self.note(f"cuts row {cid} ({_reason(exc)})")
                continue
            yield {"stage": stage, "t": t, "move_id": mid, "line": line, "arrays": arrays}

    def link_events(self) -> list[dict]:
        """Link events and gap records in the order written (each its JSON object plus
        ``kind`` and ``t``); [] for a run file written before the table existed."""
        return [{**obj, "kind": kind, "t": t} for _, (t, kind, _js), obj in self._json_rows("link_events", _GAP_FIELDS)]

    def trace_chunks(self) -> list[tuple[int, int, dict[str, np.ndarray]]]:
        """``(stage_from, stage_to, arrays)`` in the order written, up to the first damaged
        or missing chunk (each chunk builds on the ones before it)."""
        out = []
        rows = self._rows("trace")
        for k, (cid, (a, b, header, data)) in enumerate(rows):
            if cid != k + 1:  # row k + 1 was damaged or missing (noted): the rest builds on it
                self.note(f"trace rows {cid}.. (they build on trace row {k + 1})")
                break
            try:
                arrays = unpack_arrays(header, data, f"{self.path} trace row {cid}")
            except RunFileError as exc:
                self.note(f"trace row {cid} ({_reason(exc)})")
                if k + 1 < len(rows):
                    self.note(f"trace rows {cid + 1}.. (they build on trace row {cid})")
                break
            out.append((a, b, arrays))
        return out

    def close(self) -> None:
        self._con.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _text(v) -> bool:
    """text"""
    return isinstance(v, str)


def _number(v) -> bool:
    """a number"""
    return isinstance(v, (int, float))


def _integer(v) -> bool:
    """an integer"""
    return isinstance(v, int)


def _integers(v) -> bool:
    """a list of integers"""
    return isinstance(v, list) and all(isinstance(x, int) for x in v)


def _numbers(v) -> bool:
    """a list of numbers"""
    return isinstance(v, list) and all(isinstance(x, (int, float)) for x in v)


#: the fields of a finding the commands read, and what each must be when present
_FINDING_FIELDS = {"kind": _text, "line": _integer, "lines": _integers, "stage": _integer, "position": _numbers,
                   "depth": _number, "area": _number, "volume": _number, "lead_time_s": _number,
                   "status": _text, "message": _text}
#: the same for link events and gap records
_GAP_FIELDS = {"run_s": _number, "seconds": _number, "jump_mm": _number, "message": _text}


def _said(exc: BaseException) -> str:
    """What SQLite said, on one printable line (it quotes damaged bytes)."""
    return "".join(c if c.isprintable() else f"\\x{ord(c):02x}" for c in str(exc))[:200]


def _counts(text) -> dict[str, int]:
    """The meta ``rows`` entry ({table: rows written}), {} when absent or not that."""
    try:
        counts = json.loads(text) if text else {}
    except ValueError:
        return {}
    return {k: v for k, v in counts.items() if isinstance(v, int)} if isinstance(counts, dict) else {}


def _reason(exc: RunFileError) -> str:
    """The message of a RunFileError without its ``where:`` prefix."""
    text = str(exc)
    return text[len(exc.where) + 2:] if exc.where and text.startswith(f"{exc.where}: ") else text


def _decode_texts(values: list, texts: list[int], cols: dict[str, str]) -> str | None:
    """Decode the text columns (read as bytes) of one row in place; what is not UTF-8, or None."""
    for i in texts:
        if isinstance(values[i], bytes):
            try:
                values[i] = values[i].decode()
            except UnicodeDecodeError:
                return f"{list(cols)[i]} is not UTF-8 text"
    return None


def _crc_matches(values: list, crc) -> bool:
    try:
        return isinstance(crc, int) and row_crc(values) == crc
    except (TypeError, ValueError, OverflowError):
        return False


def _type_problem(values: list, cols: dict[str, str]) -> str | None:
    """What does not fit its column in one row of an unchecked file (text decoded), or None."""
    for v, (name, kind) in zip(values, cols.items()):
        k = kind.lower()
        if v is None:
            if kind.isupper():
                return f"{name} is NULL, expected {_EXPECTED[k]}"
        elif k == "t" and not isinstance(v, str) or k == "b" and not isinstance(v, (bytes, str)) \
                or k in "fi" and not isinstance(v, (int, float)) \
                or k == "i" and isinstance(v, float) and not (v.is_integer() and abs(v) < 2**63):
            return f"{name} holds {_held(v)}, expected {_EXPECTED[k]}"
    return None


def _as_read(v, kind: str):
    """A value of an unchecked row that passed :func:`_type_problem` as its column holds it."""
    if kind in "Ii" and isinstance(v, float) and v.is_integer() and abs(v) < 2**63:
        return int(v)
    if kind in "Bb" and isinstance(v, str):
        return v.encode()
    return v


_EXPECTED = {"t": "text", "b": "bytes", "f": "a number", "i": "an integer"}


def _held(v) -> str:
    return "text" if isinstance(v, (bytes, str)) else repr(v)[:24]
