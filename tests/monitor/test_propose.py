"""The monitor may propose, never send: ``dry-run --propose FILE`` writes, for the
bundled example's predicted gouge, the corrected line ``dexmon correct`` would write."""

from __future__ import annotations

import json

from monitor.cli import main


def test_dry_run_proposes_the_corrected_line_for_the_planted_gouge(tmp_path, capsys):
    proposal = tmp_path / "proposed.txt"
    code = main(["dry-run", "--clock", "sim", "--speed", "50", "--json", "--run", str(tmp_path / "r.sqlite"),
                 "--propose", str(proposal)])
    events = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert code == 1
    said = [e for e in events if e["event"] == "proposal"]
    gouge = next(e for e in events if e["event"] == "finding" and e["kind"] == "gouge")
    assert len(said) == 1 and said[0]["id"] is not None and said[0]["file"] == str(proposal)
    assert 22 in said[0]["lines"] and "nothing was sent" in said[0]["message"]
    assert events.index(gouge) < events.index(said[0])
    text = proposal.read_text()
    assert "NOT sent to the machine" in text
    assert "line 22: G1 X30 Z-5.5 (planted gouge" in text
    assert "  -> G1 X30.0000 Y22.0000 Z-5.0000 (planted gouge: dips 0.5 mm into the design) (dexmon: corrected line 22)" in text
    # only a proposal: the virtual machine still ran the program as written
    assert [e for e in events if e["event"] == "finding_update" and e.get("status") == "happened"
            and e["kind"] == "gouge"]


def test_a_gouge_that_cannot_be_corrected_gets_its_reason_written(tmp_path):
    from monitor.job import load_job
    from monitor.propose import Proposer
    from tests.monitor.test_correct_cli import example_job

    text = "G21 G90\nT1 M6\nG0 Z5\nG0 X-8 Y15\nG1 Z-5 F600\nG1 X10\nG2 X20 Y15 Z-5.5 I5 J-2\nG1 X48\nG0 Z5\nM2\n"
    job = load_job(example_job(tmp_path, text))
    out = tmp_path / "proposed.txt"
    p = Proposer(job, out)
    got = p({"kind": "gouge", "line": 7, "lines": [7], "depth": 0.5, "predicted": True})
    assert got["lines"] == [] and "no correction possible" in got["message"]
    assert "face.nc:7: the arc gouges the design by 0.5" in out.read_text()
    assert p({"kind": "gouge", "line": 99, "lines": [99]}) is None


def test_a_gouge_on_turned_lines_gets_no_3axis_proposal(tmp_path):
    """The rotary example's gouge (lines 35-36, at A225): the correction works on 3-axis
    lines only, so nothing is proposed for them; the file and the message say why."""
    from monitor.job import load_job
    from monitor.propose import Proposer
    from tests.monitor.test_correct_cli import TURNED_WHY
    from tests.monitor.test_rotary_job import JOB

    out = tmp_path / "proposed.txt"
    got = Proposer(load_job(JOB), out)({"kind": "gouge", "line": 35, "lines": [35, 36], "depth": 1.0,
                                        "predicted": True})
    text = out.read_text()
    assert got["lines"] == [] and TURNED_WHY in got["message"], got
    assert f"# no proposal: {JOB.parent / 'engrave.nc'}:35: lines 35, 36 left as written, {TURNED_WHY}" in text, text
    assert "->" not in text
