"""Alerts: each finding once on every channel; feed hold only when enabled."""

from __future__ import annotations

import io
import json

import numpy as np
from rich.console import Console

from monitor.alerts import Alerter, format_finding
from monitor.runfile import RunWriter
from monitor.runreader import RunReader


def gouge(line=12, pos=(10.0, 5.0, -1.0), lead=2.5, lines=None):
    return {"kind": "gouge", "line": line, "lines": lines or [line], "position": list(pos),
            "depth": 0.5, "lead_time_s": lead}


def test_each_finding_alerted_once_across_polls(tmp_path):
    out, term = io.StringIO(), io.StringIO()
    run = RunWriter(tmp_path / "r.sqlite")
    a = Alerter(console=Console(file=term, width=200), json_stream=out, run=run)
    # the look-ahead reports the same gouge on every poll, drifting a little and growing
    polls = [[gouge(lead=3.0)], [gouge(lead=2.9, pos=(10.4, 5, -1))],
             [gouge(line=13, lines=[12, 13], lead=2.8, pos=(11, 5, -1)),
              {"kind": "rapid_into_stock", "line": 20, "position": [30, 5, 0], "lead_time_s": 6.0}],
             [gouge(lead=2.7)]]
    fresh = [a.offer(p, t=k * 0.02) for k, p in enumerate(polls)]
    assert [len(f) for f in fresh] == [1, 0, 1, 0]
    assert fresh[2][0]["kind"] == "rapid_into_stock"
    events = [json.loads(x) for x in out.getvalue().splitlines()]
    lines = [x for x in events if x["event"] == "finding"]
    assert [x["kind"] for x in lines] == ["gouge", "rapid_into_stock"]
    # the gouge that grew onto line 13 is updated, not alerted again
    updates = [x for x in events if x["event"] == "finding_update"]
    # what changed, not the whole list again
    assert [(u["id"], u["lines_added"], u["line_range"]) for u in updates] == [(1, [13], [12, 13])]
    assert all("lines" not in u for u in updates)
    assert all({"kind", "line", "position", "lead_time_s"} <= set(x) for x in lines)
    assert term.getvalue().count("GOUGE line 12") == 1 and "in 3.0 s" in term.getvalue()
    # same kind and line but far away is a different finding
    assert len(a.offer([gouge(pos=(60, 5, -1))])) == 1
    run.close()
    r = RunReader(tmp_path / "r.sqlite")
    assert [f["kind"] for f in r.findings()] == ["gouge", "rapid_into_stock", "gouge"]
    channels = [x["channel"] for x in r.alerts()]
    assert channels.count("terminal") == 3 and channels.count("json") == 3


def test_feed_hold_only_when_enabled_and_failures_reported():
    calls = []
    a = Alerter(feed_hold=lambda: calls.append(1))
    a.offer([gouge(), {"kind": "undercut", "line": 3, "position": [0, 0, 0]}])
    assert calls == [1]  # the undercut is a quality note, not a reason to stop
    assert Alerter().offer([gouge()])  # no hold callable: nothing to call

    def broken():
        raise RuntimeError("port closed")
    term = io.StringIO()
    b = Alerter(console=Console(file=term, width=200), feed_hold=broken)
    b.offer([gouge()])
    assert "FEED HOLD FAILED: port closed" in term.getvalue()


def test_bell_and_format():
    term = io.StringIO()
    a = Alerter(console=Console(file=term, width=200, force_terminal=True), bell=True)
    a.offer([gouge()])
    assert "\a" in term.getvalue()
    assert format_finding({"kind": "fixture_collision", "line": 7, "position": [1, 2, 3],
                           "lead_time_s": 0}).startswith("FIXTURE COLLISION line 7 at (1.00, 2.00, 3.00)")


def test_predicted_then_happened_is_updated_not_realerted(tmp_path):
    out, term = io.StringIO(), io.StringIO()
    run = RunWriter(tmp_path / "r.sqlite")
    a = Alerter(console=Console(file=term, width=200, force_terminal=True), json_stream=out, run=run, bell=True)
    rapid = {"kind": "rapid_into_stock", "line": 36, "lines": [36], "stage": 30, "stages": [30],
             "position": [68.0, 1.0, -10.0], "lead_time_s": 4.3, "predicted": True, "status": "predicted"}
    assert a.offer([rapid], t=1.0) == [rapid]
    # the real rapid, seen 60 mm before the predicted worst point but on the same move
    live = dict(rapid, position=[8.0, 1.0, -10.0], lead_time_s=0.0, predicted=False, status="happened")
    assert a.offer([live], t=5.0) == []
    assert a.findings[0]["status"] == "happened" and a.findings[0]["happened_t"] == 5.0
    assert a.findings[0]["happened_position"] == [8.0, 1.0, -10.0]
    assert a.offer([live], t=5.1) == []  # seen again: still one record, not updated twice
    events = [json.loads(x) for x in out.getvalue().splitlines()]
    assert [e["event"] for e in events] == ["finding", "finding_update"]
    text = term.getvalue()
    assert text.count("RAPID INTO STOCK line 36 at") == 1 and text.count("happened as predicted") == 1
    assert text.count("\a") == 1  # the note rings no bell
    # a long live gouge followed along one line stays one finding; far along is followed too
    g = [gouge(line=40, pos=(x, 5.0, -1.0), lead=0.0) for x in np.arange(0.0, 80.0, 2.0)]
    for f in g:
        f["predicted"] = False
    assert len(a.offer(g[:1])) == 1 and sum(len(a.offer([f])) for f in g[1:]) == 0
    run.close()
    r = RunReader(tmp_path / "r.sqlite")
    stored = r.findings()
    assert stored[0]["status"] == "happened" and stored[0]["happened_t"] == 5.0
    assert len(stored) == 2


def test_a_gouge_predicted_in_two_batches_is_one_finding_of_full_size(tmp_path):
    """The look-ahead checks row 22 in one batch and row 23 in the next: the second hit
    grows the alerted finding (lines, area, volume) instead of being dropped; a re-check
    of row 22 after re-anchoring and the live cut of the same gouge add no size."""
    out = io.StringIO()
    run = RunWriter(tmp_path / "r.sqlite")
    a = Alerter(json_stream=out, run=run)
    first = {"kind": "gouge", "line": 22, "lines": [22], "stage": 16, "position": [30.0, 19.0, -5.5],
             "depth": 0.5, "area": 50.5625, "volume": 20.1, "lead_time_s": 4.0, "predicted": True,
             "status": "predicted"}
    second = dict(first, line=23, lines=[23], stage=17, position=[29.0, 19.0, -5.4], depth=0.4,
                  area=23.0, volume=6.3, lead_time_s=4.5)
    assert len(a.offer([first])) == 1
    assert a.offer([second]) == []
    assert a.offer([dict(first)]) == []  # row 22 again after a re-anchor
    live = dict(second, predicted=False, status="happened", area=3.0, volume=1.0)
    assert a.offer([live], t=9.0) == []
    rec = a.findings[0]
    assert rec["lines"] == [22, 23] and rec["line"] == 22 and rec["position"] == [30.0, 19.0, -5.5]
    assert abs(rec["area"] - 73.5625) < 1e-9 and abs(rec["volume"] - 26.4) < 1e-9
    assert rec["status"] == "happened" and "lines 22-23" in rec["message"] and "73.562" in rec["message"]
    updates = [json.loads(x) for x in out.getvalue().splitlines()][1:]
    assert [u["event"] for u in updates] == ["finding_update", "finding_update"]
    assert updates[0]["lines_added"] == [23] and updates[0]["line_range"] == [22, 23]
    assert abs(updates[0]["area"] - 73.5625) < 1e-9
    # the live cut only made it happen: its update says that, not the unchanged sizes
    assert updates[1]["status"] == "happened" and "volume" not in updates[1] and "happened_t" in updates[1]
    run.close()
    stored = RunReader(tmp_path / "r.sqlite").findings()
    assert len(stored) == 1 and stored[0]["lines"] == [22, 23] and abs(stored[0]["area"] - 73.5625) < 1e-9
