"""Findings worth reading on the corpus parts (../shared/corpus/parts/README.md) through
``dexmon simulate --json`` at its defaults: the OpenCAMLib finishing paths with their
6 mm ball raise no scallop crest and report only what the ball cannot reach, each region
once (before: 75 findings on the sphere, 74 of them scallop crests); an 8 mm ball on the
carpet path is one gouge region (before: hundreds)."""

from __future__ import annotations

import json

import pytest

from monitor.cli import main

STOCK = {"sphere_on_plate": "box:0,0,-1,76.4923,76.4923,30.8718", "carpet1": "box:0,-82,-10,152,66,5.197857"}


def simulate(capsys, shared, part, tool, *extra):
    parts = shared / "corpus" / "parts"
    rc = main(["simulate", str(parts / f"{part}_ball6_finish.ngc"), "--stock", STOCK[part], "--tool", tool,
               "--resolution", "0.4", "--design", str(parts / f"{part}.stl"), "--json", *extra])
    out, err = capsys.readouterr()
    return rc, json.loads(out)


def test_sphere_ball6_reports_only_the_corner_the_ball_cannot_reach_once(capsys, shared):
    rc, doc = simulate(capsys, shared, "sphere_on_plate", "ball:6")
    (f,) = doc["findings"]
    assert f["kind"] == "undercut" and 0.5 < f["depth"] <= 1.0
    x, y, z = f["contact"]  # in the concave corner where the dome (r 19.1) meets the block
    assert abs(((x - 38.2461) ** 2 + (y - 38.2461) ** 2) ** 0.5 - 19.10) < 3.0 and 14.93 < z < 17.94
    assert f["line_range"] == [f["lines"][0], f["lines"][-1]] and f["line"] == f["lines"][0] or f["lines_total"]
    assert len(f["programmed"]) == 3 and f["time_s"] > 0 and f["worst_line"] >= f["line"]
    # about half of it is out of the ball's reach (the fillet in the corner), the rest
    # crests a finer stepover would cut: not all blamed on the tool (sim/checks/reach.py)
    assert 0.25 <= f["detail"]["unreachable_share"] < 0.9
    # why the crests are not findings, and how to see them
    assert any("0.9934 mm apart" in n and "--undercut-tolerance" in n for n in doc["notes"]), doc["notes"]


def test_sphere_ball6_scallops_are_findings_only_when_asked_for(capsys, shared):
    _, default = simulate(capsys, shared, "sphere_on_plate", "ball:6")
    rc, asked = simulate(capsys, shared, "sphere_on_plate", "ball:6", "--undercut-tolerance", "0.05")
    # the crests on the steep flanks, within a tool radius of the corner: one region with it
    assert rc == 1 and sum(f["area"] for f in asked["findings"]) > sum(f["area"] for f in default["findings"])


def test_carpet_ball6_reports_only_its_unreachable_edges_once_each(capsys, shared):
    rc, doc = simulate(capsys, shared, "carpet1", "ball:6")
    found = doc["findings"]
    assert {f["kind"] for f in found} == {"undercut"}
    # the ball centre never leaves Y -82..66: a strip along each end is out of its reach
    ys = sorted(f["contact"][1] for f in found)
    assert len(found) == 2 and ys[0] < -82 + 3 and ys[1] > 66 - 3
    # a ball standing past the stock's end reaches them: the path's doing, not the tool's
    assert [f["detail"]["unreachable_share"] for f in found] == [0.0, 0.0]


def test_carpet_with_an_8mm_ball_is_one_gouge_region(capsys, shared):
    rc, doc = simulate(capsys, shared, "carpet1", "ball:8")
    gouges = [f for f in doc["findings"] if f["kind"] == "gouge"]
    assert rc == 1 and len(gouges) == 1
    g = gouges[0]
    assert g["depth"] == pytest.approx(0.34, abs=0.03)
    assert g["line"] == g["lines"][0] and g["line_range"][0] == g["line"]
    assert f"lines {g['line_range'][0]}-{g['line_range'][1]}" in g["message"]


def test_dry_run_of_the_carpet_with_an_8mm_ball_finds_simulates_regions_with_small_updates(tmp_path, capsys,
                                                                                           shared):
    """The start of the carpet path (its first passes, as in test_start_and_setup): the
    dry run alerts the gouge regions simulate finds (on these few passes the flanks along
    the part's edge are still apart: 4), one alert each (before: one per look-ahead
    batch), grown by updates that carry what changed, never the whole line list."""
    from tests.monitor.test_start_and_setup import corpus_job

    job = corpus_job(tmp_path, shared, "carpet1", "ball:8")
    main(["simulate", str(job), "--json"])
    sim = [f for f in json.loads(capsys.readouterr().out)["findings"] if f["kind"] == "gouge"]
    rc = main(["dry-run", str(job), "--clock", "sim", "--speed", "50", "--json", "--run", str(tmp_path / "r.sqlite")])
    events = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    found = [e for e in events if e["event"] == "finding"]
    assert rc == 1 and {f["kind"] for f in found} == {"gouge"}
    assert sorted(f["line"] for f in found) == sorted(f["line"] for f in sim), ([f["line"] for f in found], sim)
    g = found[0]
    assert g["line"] == g["lines"][0] and "time_s" in g and len(g["programmed"]) == 3
    updates = [e for e in events if e["event"] == "finding_update" and e["id"] == 1]
    assert updates and all("lines" not in u for u in updates)
    # the lines of the alert and its updates are every line the gouge covers
    seen = set(g["lines"]) | {ln for u in updates for ln in u.get("lines_added", ())}
    last_range = [u["line_range"] for u in updates if "line_range" in u][-1]
    assert min(seen) == last_range[0] and max(seen) == last_range[1]
