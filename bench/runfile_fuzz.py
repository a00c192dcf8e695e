"""Fuzz replay and report with damaged run files: no hang, no crash, no traceback.

A small real run file (a dry run of the bundled example: ``dexmon dry-run --speed 50
--quiet --run F``, or ``--base F``) is copied and damaged in seeded ways: flipped and
zeroed bytes anywhere in the SQLite file, truncation, flipped bytes inside stored BLOBs
and TEXT (SQL updates, as a blob or as text that is no longer UTF-8), wrong types in
cells (text for a number, NULL for NOT NULL, a huge integer, a blob), deleted rows, a
dropped table, meta values that are not JSON, and a few of these at once. A share of the
inputs first drops the ``crc`` columns (a run file of an older dexmon, unchecked).

On each input ``replay --findings``, ``replay --stage end --png``, ``replay --export-stl
end`` and ``report -o`` run through ``monitor.cli.main`` in a forked child under a time
limit (the parent imports and warms everything once, so a child costs milliseconds).
Outcomes per command run: ``error`` (exit 2, one line on stderr), ``ok`` (exit 0/1, no
warning), ``partial`` (exit 0/1 with a one-line warning naming the damage), ``messy``
(exit 2 or a warning over more than one line), ``hang`` (past the limit), ``crash`` (the
child died), ``traceback`` (an exception escaped ``main``). Prints a JSON line every 500
inputs and a final one with the counts and the first examples of each bad outcome::

    python bench/runfile_fuzz.py --n 10000 --seed 1 [--base run.sqlite] [--minutes 30]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import random
import select
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

#: tables and the columns a mutation may touch
TABLES = {
    "meta": ("key", "value"), "arrays": ("name", "header", "data"),
    "states": ("t", "mx", "mz", "state", "line", "feed", "raw", "ovr_feed", "alarm"),
    "findings": ("t", "kind", "line", "lead_time_s", "json"), "alerts": ("t", "channel", "text"),
    "cuts": ("stage", "t", "move_id", "line", "header", "data"),
    "trace": ("stage_from", "stage_to", "header", "data"), "link_events": ("t", "kind", "json"),
}
ODD_VALUES = ["soon", None, 2**63 - 1, -(2**63), 1e308, float("inf"), -1, 0, 2**31, b"\xff\x00\xfe", "", "[]", "{}",
              "null", "1e999", "[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]"]


def make_base(folder: Path) -> Path:
    """A real run file: a fast dry run of the bundled example."""
    path = folder / "base.sqlite"
    subprocess.run([sys.executable, "-m", "monitor.cli", "dry-run", "--speed", "50", "--quiet", "--run", str(path)],
                   cwd=HERE.parent, check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if not path.is_file():
        raise SystemExit("the dry run wrote no run file")
    return path


# --- mutations ------------------------------------------------------------------------

def _flip(raw: bytes, rng: random.Random, n: int = 1) -> bytes:
    b = bytearray(raw)
    for _ in range(n):
        if b:
            b[rng.randrange(len(b))] ^= rng.randrange(1, 256)
    return bytes(b)


def file_flip(path: Path, rng) -> str:
    n = rng.choice([1, 1, 2, 4, 16])
    path.write_bytes(_flip(path.read_bytes(), rng, n))
    return f"flip {n} bytes"


def file_zero(path: Path, rng) -> str:
    b = bytearray(path.read_bytes())
    at, n = rng.randrange(len(b)), rng.choice([1, 8, 100, 4096])
    b[at:at + n] = bytes(len(b[at:at + n]))
    path.write_bytes(bytes(b))
    return f"zero {n} bytes at {at}"


def file_truncate(path: Path, rng) -> str:
    b = path.read_bytes()
    n = rng.randrange(len(b))
    path.write_bytes(b[:n])
    return f"truncate to {n}"


def _random_row(con, table: str, rng):
    ids = [r[0] for r in con.execute(f"SELECT rowid FROM {table}")]
    return rng.choice(ids) if ids else None


def _tables(con) -> list[str]:
    return [r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'") if r[0] in TABLES]


def sql_flip_stored(con, rng) -> str:
    """Flip bytes in a stored blob or text; store it back as a blob or as (maybe not UTF-8) text."""
    table = rng.choice(_tables(con))
    col = rng.choice([c for c in TABLES[table] if c in ("data", "header", "json", "value", "raw", "text", "state")]
                     or list(TABLES[table]))
    rid = _random_row(con, table, rng)
    if rid is None:
        return f"{table} empty"
    value = con.execute(f"SELECT CAST({col} AS BLOB) FROM {table} WHERE rowid = ?", (rid,)).fetchone()[0]
    if not value:
        return f"{table}.{col} row {rid} empty"
    flipped = _flip(value, rng, rng.choice([1, 1, 3]))
    as_text = rng.random() < 0.5
    con.execute(f"UPDATE {table} SET {col} = {'CAST(? AS TEXT)' if as_text else '?'} WHERE rowid = ?", (flipped, rid))
    return f"flip {table}.{col} row {rid} ({'text' if as_text else 'blob'})"


def sql_wrong_type(con, rng) -> str:
    table = rng.choice(_tables(con))
    col = rng.choice(TABLES[table])
    rid = _random_row(con, table, rng)
    value = rng.choice(ODD_VALUES)
    if rid is None:
        return f"{table} empty"
    try:
        con.execute(f"UPDATE {table} SET {col} = ? WHERE rowid = ?", (value, rid))
    except sqlite3.IntegrityError:  # NULL where NOT NULL: take the constraint out of the schema first
        version = con.execute("PRAGMA schema_version").fetchone()[0]
        con.execute("PRAGMA writable_schema = 1")
        con.execute("UPDATE sqlite_master SET sql = replace(sql, 'NOT NULL', '') WHERE name = ?", (table,))
        con.execute(f"PRAGMA schema_version = {version + 1}")  # reload the schema
        con.execute("PRAGMA writable_schema = 0")
        con.execute(f"UPDATE {table} SET {col} = ? WHERE rowid = ?", (value, rid))
    return f"{table}.{col} row {rid} = {value!r:.30}"


def sql_delete(con, rng) -> str:
    table = rng.choice(_tables(con))
    rid = _random_row(con, table, rng)
    if rid is None:
        return f"{table} empty"
    n = rng.choice([1, 1, 2, 1000])
    con.execute(f"DELETE FROM {table} WHERE rowid >= ? AND rowid < ?", (rid, rid + n))
    return f"delete {table} rows {rid}..{rid + n - 1}"


def sql_drop(con, rng) -> str:
    table = rng.choice(_tables(con))
    con.execute(f"DROP TABLE {table}")
    return f"drop {table}"


def sql_meta_not_json(con, rng) -> str:
    key = rng.choice(["frame", "summary", "job", "program", "versions", "format", "version", "tool_spec",
                      "program_path", "created"])
    value = rng.choice(["{not json", "[1, 2", "nul\x00l", "", "{}", "[]", "1e999", "null"])
    con.execute("UPDATE meta SET value = ? WHERE key = ?", (value, key))
    return f"meta {key} = {value!r}"


def drop_checksums(con) -> None:
    """Make the copy a run file of an older dexmon: no crc columns."""
    for table in _tables(con):
        cols = [r[1] for r in con.execute(f"PRAGMA table_info({table})")]
        if "crc" in cols:
            con.execute(f"ALTER TABLE {table} DROP COLUMN crc")


FILE_MUTATIONS = [file_flip, file_zero, file_truncate]
SQL_MUTATIONS = [sql_flip_stored, sql_flip_stored, sql_wrong_type, sql_wrong_type, sql_delete, sql_drop,
                 sql_meta_not_json]


def damage(base: Path, out: Path, rng: random.Random, unchecked_share: float) -> str:
    """A damaged copy of ``base`` at ``out``; returns what was done."""
    shutil.copy(base, out)
    done = []
    if rng.random() < unchecked_share:
        con = sqlite3.connect(out)
        drop_checksums(con)
        con.commit()
        con.close()
        done.append("unchecked")
    n = rng.choice([1, 1, 1, 2, 3])
    for _ in range(n):
        if rng.random() < 0.35:
            done.append(rng.choice(FILE_MUTATIONS)(out, rng))
            continue
        con = sqlite3.connect(out)
        try:
            done.append(rng.choice(SQL_MUTATIONS)(con, rng))
            con.commit()
        except (sqlite3.Error, UnicodeDecodeError, IndexError) as exc:  # damaged beyond SQL already
            done.append(f"sql refused ({str(exc)[:60]})")
        finally:
            con.close()
    return "; ".join(done)


# --- running -----------------------------------------------------------------------------

def commands(run: Path, outdir: Path) -> list[list[str]]:
    return [["replay", str(run), "--findings"],
            ["replay", str(run), "--stage", "end", "--png", str(outdir / "o.png")],
            ["replay", str(run), "--export-stl", "end", str(outdir / "o.stl")],
            ["report", str(run), "-o", str(outdir / "o.html")]]


def _quiet_main(argv) -> dict:
    from monitor.cli import main

    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main(argv)
        return {"rc": rc, "err": err.getvalue()}
    except BaseException as exc:  # noqa: BLE001 - what the fuzz is looking for
        tb = traceback.extract_tb(exc.__traceback__)
        where = f"{tb[-1].filename}:{tb[-1].lineno}" if tb else "?"
        return {"rc": None, "err": err.getvalue(), "exc": f"{type(exc).__name__}: {str(exc)[:200]} at {where}"}


def run_child(argv: list[str], timeout: float) -> dict:
    """``main(argv)`` in a forked child; its result, or a hang/crash."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child
        os.close(r)
        try:
            res = _quiet_main(argv)
            os.write(w, json.dumps(res).encode())
        finally:
            os._exit(0)
    os.close(w)
    chunks, deadline = [], time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        ready, _, _ = select.select([r], [], [], max(left, 0))
        if not ready:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            os.close(r)
            return {"kind": "hang"}
        data = os.read(r, 65536)
        if not data:
            break
        chunks.append(data)
    os.close(r)
    _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status) or not chunks:
        return {"kind": "crash", "what": f"signal {os.WTERMSIG(status)}" if os.WIFSIGNALED(status) else "no result"}
    return json.loads(b"".join(chunks))


def classify(res: dict) -> tuple[str, str]:
    if "kind" in res:
        return res["kind"], res.get("what", "")
    err = res["err"]
    lines = [x for x in err.splitlines() if x.strip()]
    if "exc" in res or "Traceback" in err:
        return "traceback", res.get("exc", err[-300:])
    if res["rc"] == 2:
        return ("error" if len(lines) == 1 else "messy"), err.strip()[:300]
    if res["rc"] in (0, 1):
        if not lines:
            return "ok", ""
        if len(lines) == 1 and "warning:" in lines[0] and "damaged" in lines[0]:
            return "partial", lines[0][:300]
        if len(lines) == 1 and "note:" in lines[0]:
            return "ok", lines[0][:300]
        return "messy", err.strip()[:300]
    return "messy", f"exit {res['rc']}: {err.strip()[:300]}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10000, help="damaged run files (default 10000)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per command run (default 60)")
    ap.add_argument("--base", default=None, help="the run file to damage (default: a fresh dry run)")
    ap.add_argument("--unchecked-share", type=float, default=0.1,
                    help="share of inputs written as an older dexmon would, without checksums (default 0.1)")
    ap.add_argument("--minutes", type=float, default=None, help="stop after this long (the counts say how far)")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="runfile_fuzz-"))
    try:
        base = Path(args.base) if args.base else make_base(work)
        for argv_ in commands(base, work):  # warm every import and kernel once; children fork from here
            assert "exc" not in _quiet_main(argv_), argv_
        rng = random.Random(args.seed)
        kinds = ("error", "ok", "partial", "messy", "hang", "crash", "traceback")
        counts = dict.fromkeys(kinds, 0)
        examples: dict[str, list] = {}
        t0, worst, done = time.perf_counter(), 0.0, 0
        run = work / "damaged.sqlite"
        for i in range(args.n):
            if args.minutes and time.perf_counter() - t0 > 60 * args.minutes:
                break
            for p in work.glob("damaged.sqlite*"):
                p.unlink()
            what = damage(base, run, rng, args.unchecked_share)
            for argv_ in commands(run, work):
                t = time.perf_counter()
                kind, detail = classify(run_child(argv_, args.timeout))
                worst = max(worst, time.perf_counter() - t)
                counts[kind] += 1
                if kind in ("messy", "hang", "crash", "traceback") and len(examples.setdefault(kind, [])) < 8:
                    examples[kind].append({"input": i, "damage": what, "argv": argv_[0:1] + argv_[2:3],
                                           "what": detail})
            done = i + 1
            if done % 500 == 0:
                print(json.dumps({"bench": "runfile_fuzz", "inputs": done, **counts,
                                  "seconds": round(time.perf_counter() - t0, 1)}), flush=True)
        print(json.dumps({"bench": "runfile_fuzz", "inputs": done, "command_runs": sum(counts.values()),
                          "seed": args.seed, "timeout_s": args.timeout, **counts, "slowest_s": round(worst, 2),
                          "seconds": round(time.perf_counter() - t0, 1), "examples": examples}))
        return 0 if not (counts["hang"] or counts["crash"] or counts["traceback"]) else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
