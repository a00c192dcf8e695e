"""dexmon's move table equals LinuxCNC's rs274 on real programs (issue 13).

Each program runs through dexmon and is compared, motion end point by motion end point,
with rs274's canonical calls (tests/sim/gcode/rs274_harness.py). rs274's output comes from
``rs274`` itself when it is on the PATH, else from the recording in tests/data/rs274/canon
(written by ``bench/rs274_diff.py --record``). With rs274 present, the recordings are also
checked against it, so they cannot go stale unnoticed.

Sets: tests/data/rs274/programs (always), ../shared/corpus/gcode (when beside the clone),
and the sample programs of Debian's linuxcnc-uspace (when installed).
"""

from __future__ import annotations

import pytest

from tests.sim.gcode import rs274_harness as h

#: programs whose difference from rs274 is known, with its cause; each is a strict xfail,
#: so fixing one fails here until it leaves this list
KNOWN: dict[str, str] = {}


def _params(which: str):
    out = []
    for case in h.cases(which):
        marks = [pytest.mark.xfail(strict=True, reason=KNOWN[case.name])] if case.name in KNOWN else []
        out.append(pytest.param(case, id=case.name, marks=marks))
    return out


def _reference(case: h.Case) -> str:
    if h.RS274 is not None:
        return h.run_rs274(case.path, case.tools, case.params)
    if not case.recording.is_file():
        pytest.skip(f"rs274 is not installed and {case.name} has no recording "
                    f"(apt-get install linuxcnc-uspace; bench/rs274_diff.py --record)")
    return h.read_recording(case.recording)


def _check(case: h.Case) -> None:
    ref = h.parse_canon(_reference(case))
    got = h.dexmon_run(case.path, case.tools, case.params)
    result = h.compare(ref, got)
    assert result.ok, f"{case.name}: {result.status}: {result.detail}"


@pytest.mark.parametrize("case", _params("tests"))
def test_own_programs_equal_rs274(case):
    _check(case)


@pytest.mark.parametrize("case", _params("corpus"))
def test_corpus_equals_rs274(case):
    _check(case)


@pytest.mark.skipif(h.RS274 is None, reason="rs274 is not installed (apt-get install linuxcnc-uspace)")
@pytest.mark.parametrize("case", _params("package"))
def test_linuxcnc_samples_equal_rs274(case):
    _check(case)


@pytest.mark.skipif(h.RS274 is None, reason="rs274 is not installed: the recordings cannot be checked")
@pytest.mark.parametrize("case", [c for c in h.cases("tests") + h.cases("corpus") if c.recording.is_file()],
                         ids=lambda c: c.name)
def test_recordings_are_rs274s_output(case):
    live = h.keep_canon(h.run_rs274(case.path, case.tools, case.params))
    assert h.read_recording(case.recording) == live, \
        f"{case.recording} is stale: re-record with python bench/rs274_diff.py --record"


def test_every_own_program_is_recorded():
    missing = [c.name for c in h.cases("tests") if not c.recording.is_file()]
    assert not missing, f"no recording for {missing}: python bench/rs274_diff.py --set tests --record"


def test_harness_reads_canon_calls():
    text = (" 9 N..... USE_LENGTH_UNITS(CANON_UNITS_INCHES)\n"
            "10 N..... STRAIGHT_TRAVERSE(1.0000, 2.0000, 3.0000, 0.0000, 0.0000, 0.0000)\n"
            "11 N..... SELECT_PLANE(CANON_PLANE_XZ)\n"
            "12 N20    ARC_FEED(2.0000, 6.0000, 1.0000, 5.0000, -1, 0.5000, 0.0000, 0.0000, 0.0000)\n"
            "13 N..... NURBS_FEED(3, ...)\n"
            f"{h.ERROR}Start point too close to probe point\n{h.ERROR}G38.2 Z1\n")
    run = h.parse_canon(text)
    assert [m.kind for m in run.motions] == ["T", "A", "S"]
    assert run.motions[0].end[:3].tolist() == pytest.approx([25.4, 50.8, 76.2])
    # G18: first = Z, second = X, the axis word is Y
    assert run.motions[1].end[:3].tolist() == pytest.approx([6 * 25.4, 0.5 * 25.4, 2 * 25.4])
    assert run.motions[1].center[[0, 2]].tolist() == pytest.approx([5 * 25.4, 25.4])
    assert run.error == "Start point too close to probe point" and run.error_text == "G38.2 Z1"


def test_harness_finds_a_difference():
    ref = h.parse_canon("1 N..... STRAIGHT_FEED(1.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)\n")
    near = h.parse_canon("1 N..... STRAIGHT_FEED(1.0009, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)\n")
    far = h.parse_canon("1 N..... STRAIGHT_FEED(1.0020, 0.0000, 0.0000, 0.0000, 0.0000, 0.0000)\n")
    assert h.compare(ref, near).ok
    assert h.compare(ref, far).status == "differ"
    assert h.compare(ref, h.Run([])).status == "differ"
