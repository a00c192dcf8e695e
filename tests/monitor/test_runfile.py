"""Run file: arrays round-trip without pickle, live reading, crash safety, clear errors."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from drivers.state import MachineState, RunState
from monitor.runfile import RunFileError, RunWriter, default_run_path, pack_arrays, unpack_arrays
from monitor.runreader import RunReader
from sim.gcode.moves import MOVE_DTYPE, empty_moves


def test_arrays_round_trip_plain_and_structured(tmp_path):
    moves = empty_moves(3)
    moves["line"] = [4, 5, 6]
    moves["end"][:, 0] = [1.0, 2.0, 3.0]
    path = tmp_path / "r.sqlite"
    with RunWriter(path) as w:
        w.put_array("moves", moves)
        w.put_array("heights", np.arange(12, dtype=np.float32).reshape(3, 4))
        w.put_array("empty", np.zeros((0, 3), np.int64))
    r = RunReader(path)
    got = r.get_array("moves")
    assert got.dtype == MOVE_DTYPE
    assert got["line"].tolist() == [4, 5, 6]
    assert np.array_equal(got["end"], moves["end"])
    assert np.isnan(got["center"]).all()
    h = r.get_array("heights")
    assert h.dtype == np.float32 and h.shape == (3, 4) and h[2, 3] == 11
    assert r.get_array("empty").shape == (0, 3)
    with pytest.raises(RunFileError, match="no array named 'nope'"):
        r.get_array("nope")


def test_unpack_refuses_object_and_mismatched_sizes():
    header, data = pack_arrays({"a": np.arange(4, dtype=np.int32)})
    bad = json.loads(header)
    bad[0]["shape"] = [5]
    with pytest.raises(RunFileError, match="does not match"):
        unpack_arrays(json.dumps(bad), data, "x")
    bad[0]["shape"] = [4]
    bad[0]["dtype"] = "|O"
    with pytest.raises(RunFileError, match="object"):
        unpack_arrays(json.dumps(bad), data, "x")
    with pytest.raises(TypeError):
        pack_arrays({"o": np.array([object()])})


def test_states_findings_alerts_cuts_trace(tmp_path):
    path = tmp_path / "r.sqlite"
    w = RunWriter(path)
    w.put_meta("job", "[stock]\nbox = [0,0,0,1,1,1]\n")
    w.put_meta("limits", {"x": [0, 100]})
    for k in range(5):
        w.append_state(MachineState(t=k * 0.02, mpos=(k, 2, 3), wco=(1, 1, 1), state=RunState.RUN,
                                    feed=600, spindle=12000, line=10 + k, raw=f"<Run|{k}>"))
    w.append_state(MachineState(t=1.0, mpos=(0, 0, 0)))  # line unknown
    w.append_finding({"kind": "gouge", "line": 12, "position": [1, 2, 3], "lead_time_s": 1.5}, t=0.05)
    w.append_alert("terminal", "gouge at line 12", t=0.05, finding_id=1)
    w.append_cut(1, {"rays": np.array([3, 4], np.int64), "top": np.array([1.5, 2.5], np.float32)},
                 t=0.02, move_id=7, line=12)
    w.append_trace_chunk(0, 9, {"z": np.ones((2, 2), np.float32)})
    w.close()
    w.close()  # twice is fine
    r = RunReader(path)
    meta = r.meta()
    assert meta["job"].startswith("[stock]") and json.loads(meta["limits"]) == {"x": [0, 100]}
    st = r.states()
    assert st.shape == (6,)
    assert st["mpos"][3, 0] == 3 and st["wco"][0, 2] == 1
    assert st["line"].tolist() == [10, 11, 12, 13, 14, -1]
    assert st["state"][0] == "Run"
    f = r.findings()
    assert f == [{"kind": "gouge", "line": 12, "position": [1, 2, 3], "lead_time_s": 1.5}]
    assert r.alerts()[0]["channel"] == "terminal"
    cuts = list(r.cuts())
    assert cuts[0]["stage"] == 1 and cuts[0]["move_id"] == 7
    assert cuts[0]["arrays"]["top"].tolist() == [1.5, 2.5]
    chunks = list(r.trace_chunks())
    assert chunks[0][0] == 0 and chunks[0][1] == 9 and chunks[0][2]["z"].sum() == 4


def test_readable_while_written(tmp_path):
    path = tmp_path / "live.sqlite"
    w = RunWriter(path)
    for k in range(10):
        w.append_state(MachineState(t=float(k), mpos=(k, 0, 0)))
    w.flush()
    r = RunReader(path)
    assert r.state_count() == 10
    w.append_state(MachineState(t=10.0, mpos=(0, 0, 0)))
    w.flush()
    assert r.state_count() == 11
    w.close()


def test_not_a_run_file_names_the_file(tmp_path):
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not sqlite at all" * 100)
    with pytest.raises(RunFileError, match="junk.sqlite.*not a dexmon run file"):
        RunReader(junk)
    with pytest.raises(RunFileError, match="no such run file"):
        RunReader(tmp_path / "missing.sqlite")
    import sqlite3
    other = tmp_path / "other.sqlite"
    con = sqlite3.connect(other)
    con.execute("CREATE TABLE x(a)")
    con.commit()
    con.close()
    with pytest.raises(RunFileError, match="other.sqlite.*not a dexmon run file"):
        RunReader(other)


def test_writer_refuses_to_overwrite(tmp_path):
    path = tmp_path / "r.sqlite"
    RunWriter(path).close()
    with pytest.raises(RunFileError, match="already exists"):
        RunWriter(path)


def test_default_path_is_new_and_timestamped(tmp_path):
    p1 = default_run_path(tmp_path)
    p1.touch()
    p2 = default_run_path(tmp_path)
    assert p1 != p2 and p1.parent == tmp_path and p1.name.startswith("run-")


def test_sigkill_loses_at_most_the_last_second(tmp_path):
    path = tmp_path / "killed.sqlite"
    child = textwrap.dedent(f"""
        import sys, time
        from drivers.state import MachineState
        from monitor.runfile import RunWriter
        w = RunWriter({str(path)!r}, commit_interval=0.25)
        k = 0
        while True:
            t = time.monotonic()
            w.append_state(MachineState(t=t, mpos=(k, 0, 0)))
            k += 1
            if k % 50 == 0:
                print(repr(t), flush=True)
            time.sleep(0.002)  # pace the producer like a 500 Hz poll loop
    """)
    proc = subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True,
                            cwd=os.getcwd())
    try:
        seen = []
        for line in proc.stdout:
            seen.append(float(line))
            if len(seen) >= 12:
                break
        assert len(seen) >= 12, "child died before writing"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    r = RunReader(path)
    st = r.states()
    assert st.size > 0
    assert st["t"].max() >= seen[-1] - 1.0
    assert np.all(np.diff(st["t"]) > 0)


def test_states_with_values_a_controller_made_up_do_not_stop_the_writer(tmp_path):
    """Integers above 2^63 in Ln:, Hold:, ALARM: or Ov: used to end monitoring with
    "cannot write the run file": they are stored as NULL, the raw text kept, and the
    writer goes on."""
    path = tmp_path / "r.sqlite"
    huge = 2**64 + 5
    odd = [MachineState(t=0.1, mpos=(1, 2, 3), state=RunState.HOLD, line=huge, substate=huge,
                        raw="<Hold:18446744073709551621|Ln:18446744073709551621>"),
           MachineState(t=0.2, mpos=(1, 2, 3), state=RunState.ALARM, alarm=-huge, overrides=(huge, 100, 100),
                        raw="ALARM:-huge"),
           MachineState(t=0.3, mpos=(1, 2, 3), state=RunState.RUN, line=np.int64(7), buffer=(15, 128), raw=b"<Run>"),
           MachineState(t=0.4, mpos=(1, 2, 3), state=RunState.RUN, line=12, raw="<Run|Ln:12>")]
    with RunWriter(path) as w:
        for s in odd:
            w.append_state(s)
        w.append_link_event(0.4, "bad", {"event": "link", "kind": "bad", "message": "Ln: too big", "n": huge})
        w.flush()
    r = RunReader(path)
    st = r.states()
    assert len(st) == 4 and st["line"].tolist() == [-1, -1, 7, 12] and st["alarm"].tolist()[:2] == [-1, -1]
    raws = [x[0] for x in r._query("SELECT raw FROM states ORDER BY id")]
    assert raws[0].startswith("<Hold:18446744073709551621") and raws[2] == "b'<Run>'"
    assert r.link_events()[0]["message"] == "Ln: too big"


def test_run_files_without_the_link_events_table_still_open(tmp_path):
    import sqlite3

    path = tmp_path / "old.sqlite"
    with RunWriter(path) as w:
        w.append_state(MachineState(t=0.0, mpos=(0, 0, 0), state=RunState.IDLE))
    con = sqlite3.connect(path)
    con.execute("DROP TABLE link_events")
    con.commit()
    con.close()
    r = RunReader(path)
    assert r.link_events() == [] and r.state_count() == 1


def test_a_row_sqlite_refuses_is_skipped_and_counted_not_fatal(tmp_path):
    path = tmp_path / "r.sqlite"
    with RunWriter(path) as w:
        w._put("INSERT INTO states(t, line) VALUES (?, ?)", (0.0, 2**70))  # past the sanitising appends
        w.append_state(MachineState(t=0.1, mpos=(0, 0, 0), state=RunState.IDLE))
        w.flush()
        assert w.skipped == 1 and "too large" in w.last_skip
    r = RunReader(path)
    assert r.state_count() == 1 and json.loads(r.meta()["skipped_rows"])["rows"] == 1
