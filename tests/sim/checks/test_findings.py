import json
import math

import pytest

from sim.checks.findings import KINDS, Finding, merge_findings


def hit(kind, stage, depth=1.0, volume=1.0, line=None, group=None):
    return Finding(kind=kind, line=line or 10 * stage, stage=stage, position=(stage, 0, 0),
                   depth=depth, volume=volume, detail={"group": group} if group else {})


def test_consecutive_hits_of_one_kind_merge_keeping_lines_max_depth_summed_volume():
    out = merge_findings([hit("rapid_into_stock", 3, 0.5, 2.0), hit("rapid_into_stock", 4, 1.5, 3.0),
                          hit("rapid_into_stock", 5, 0.2, 1.0)])
    assert len(out) == 1
    f = out[0]
    assert f.lines == (30, 40, 50) and f.stages == (3, 4, 5)
    assert f.depth == 1.5 and f.volume == 6.0
    assert f.line == 30 and f.worst_line == 40  # where it starts, where it is worst
    assert f.stage == 4 and f.position == (4.0, 0.0, 0.0)  # the worst hit


def test_gaps_kinds_and_groups_keep_hits_apart():
    out = merge_findings([hit("rapid_into_stock", 3), hit("rapid_into_stock", 6),
                          hit("holder_contact", 4), hit("travel_limit", 7, group="X+"),
                          hit("travel_limit", 8, group="Y-")])
    assert [(f.kind, f.stages) for f in out] == [
        ("rapid_into_stock", (3,)), ("holder_contact", (4,)), ("rapid_into_stock", (6,)),
        ("travel_limit", (7,)), ("travel_limit", (8,))]


def test_merge_is_order_independent():
    hits = [hit("gouge", s, depth=s / 10) for s in (5, 2, 3, 4, 9)]
    a = merge_findings(hits)
    b = merge_findings(list(reversed(hits)))
    assert [(f.stages, f.depth) for f in a] == [(f.stages, f.depth) for f in b] == [((2, 3, 4, 5), 0.5), ((9,), 0.9)]


def test_to_json_has_kind_line_position_and_only_measured_sizes():
    f = Finding(kind="gouge", line=12, lines=(12, 14), stage=3, position=(1, 2, 3), depth=0.34, area=2.0)
    j = json.loads(json.dumps(f.to_json()))
    assert j["kind"] == "gouge" and j["line"] == 12 and j["lines"] == [12, 14]
    assert j["position"] == [1.0, 2.0, 3.0] and j["depth"] == 0.34 and j["area"] == 2.0
    assert "volume" not in j and "gouge" in j["message"] and "line" in j["message"]
    assert math.isnan(f.volume)


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="unknown finding kind"):
        Finding(kind="explosion")
    assert "gouge" in KINDS and "travel_limit" in KINDS
