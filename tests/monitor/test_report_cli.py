"""``dexmon report`` through ``main(argv)``."""

from __future__ import annotations

import base64
import io
import json
import re

import pytest

from monitor.cli import main
from tests.monitor.run_helpers import PATH, record_run


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    path = tmp_path_factory.mktemp("run") / "job.dexrun"
    snaps, _ = record_run(path)
    return path, snaps


def test_report_has_summary_findings_pictures_and_removal(recorded, tmp_path, capsys):
    import imageio.v3 as iio

    path, snaps = recorded
    out = tmp_path / "r.html"
    assert main(["report", str(path), "-o", str(out)]) == 0
    text = out.read_text()
    assert "<h2>Summary</h2>" in text and "programmed cycle time" in text
    assert "0:12.00" in text  # 6 moves x 2 s of row_seconds
    # one sentence per finding, the kind said once (QA 11)
    assert "Gouge at lines 13-14, X15.000 Y16.000 Z6.500: 0.400 mm deep." in text
    # the sentence says it once; the pictures' alt texts name it too
    assert re.sub(r'alt="[^"]*"', "", text).lower().count("gouge") == 1
    imgs = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    # the part in 3-D, end and start from above, removal and feed over time, and per
    # finding a close 3-D view and a section
    assert len(imgs) == 3 + 1 + 2 * 2
    for b in imgs:
        img = iio.imread(io.BytesIO(base64.b64decode(b)))
        assert img.ndim == 3 and img.shape[2] == 3
    # removal per move: one row per move, summing to the volume cut
    rows = re.findall(r"<tr><td>(\d+)</td><td>(\d*)</td><td>([\d.]+)</td></tr>", text)
    assert [int(r[0]) for r in rows] == list(range(1, len(PATH)))
    assert [int(r[1]) for r in rows] == list(range(10, 10 + len(PATH) - 1))
    total = sum(float(r[2]) for r in rows)
    assert total == pytest.approx(snaps[0].volume() - snaps[max(snaps)].volume(), abs=0.01)
    said = capsys.readouterr().out
    assert said == f"wrote {out} (2 findings)\n"  # plain text without --json
    assert main(["report", str(path), "-o", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"event": "report", "path": str(out), "findings": 2}


def test_report_errors(recorded, tmp_path, capsys):
    path, _ = recorded
    assert main(["report", str(path), "-o", str(tmp_path / "r.txt")]) == 2
    assert ".html" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "nope"), "-o", str(tmp_path / "r.html")]) == 2


def test_report_states_every_gap_and_the_missed_and_bad_polls(tmp_path, capsys):
    path = tmp_path / "trouble.dexrun"
    record_run(path, link_trouble=True)
    out = tmp_path / "r.html"
    assert main(["report", str(path), "-o", str(out)]) == 0
    text = out.read_text()
    assert "<h2>Link</h2>" in text
    for label, n in (("missed polls", 3), ("bad polls", 2), ("disconnected polls", 4), ("gaps", 1)):
        assert f"<tr><th>{label}</th><td>{n}</td></tr>" in text, label
    # the gap: when, how long, what was missed, how it came back, where it went on
    row = re.search(r"<tr class='gap'>(.*?)</tr>", text).group(1)
    cells = re.findall(r"<td>(.*?)</td>", row)
    assert cells[:6] == ["0:02.50", "4.5 s", "9", "2", "12.50 mm", "reset: Grbl 1.1h banner"], cells
    assert "off the program" in cells[6]
    assert "grbl:///dev/ttyUSB0: Grbl 1.1h banner" in text  # the reset said


def test_report_of_a_clean_run_says_no_link_trouble(recorded, tmp_path):
    path, _ = recorded
    out = tmp_path / "r.html"
    assert main(["report", str(path), "-o", str(out)]) == 0
    assert "No link trouble" in out.read_text()
