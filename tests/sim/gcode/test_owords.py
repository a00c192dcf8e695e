"""o-word subroutines as LinuxCNC runs them (issue 13).

rs274 reads a program line by line: ``o<x> sub`` skips to the first ``o<x> endsub``; a
sub being run returns at the first ``return`` or ``endsub`` it executes, whatever its
label (LinuxCNC's own probe and remap macros return with another label). The whole-program
comparisons are tests/data/rs274/programs/owords_*.ngc in test_rs274.py; these tests name
the behaviour and the messages.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim.gcode import GCodeError, interpret, load_program, work_end


def ends(text, **kw):
    return work_end(interpret(text, **kw).moves)[:, :3]


def test_return_with_another_label_returns_from_the_sub():
    text = "o<probe> sub\nG0 X1\no100 if [1]\no<other> return [5]\no100 endif\nG0 X9\no<probe> endsub\n" \
           "o<probe> call\nG0 Y#<_value>\nM2"
    np.testing.assert_allclose(ends(text)[:2], [[1, 0, 0], [1, 5, 0]])


def test_endsub_with_another_label_returns_when_run():
    text = "o<a> sub\nG0 X1\no<b> endsub\nG0 X2\no<a> endsub\no<a> call\nG0 Y5\nM2"
    np.testing.assert_allclose(ends(text)[:2], [[1, 0, 0], [1, 5, 0]])


def test_bare_return_sets_value_to_zero():
    text = "o1 sub\no1 endsub [7]\no2 sub\no2 return\no2 endsub\no1 call\nG0 X#<_value>\no2 call\n" \
           "G0 Y#<_value> Z#<_value_returned>\nM2"
    np.testing.assert_allclose(ends(text)[:2], [[7, 0, 0], [7, 0, 0]])


def test_sub_never_closed_runs_to_the_end_of_the_file():
    p = interpret("G0 X1\no<m106> sub\nG0 X5\no<m103> endsub\nG0 Y3\nM2\n")
    np.testing.assert_allclose(work_end(p.moves)[:, :3], [[1, 0, 0]])
    assert any("o<m106> sub" in w and "never closed" in w for w in p.warnings), p.warnings


def test_return_outside_any_sub_is_refused_where_it_runs():
    with pytest.raises(GCodeError) as info:
        interpret("G0 X1\no<x> return\nM2\n", filename="p.ngc")
    assert info.value.line == 2 and "o<x> return" in info.value.message


@pytest.mark.parametrize("text,needle", [
    ("o<probe_rect_pocket> call\nM2\n", "o<probe_rect_pocket> call: no o<probe_rect_pocket> sub"),
    ("o<a> sub\nG0 X1\n", "o<a> sub is never closed"),
    ("o<a> endif\nM2\n", "o<a> endif without a matching o<a> if"),
    ("o100 endif\nM2\n", "o100 endif without a matching o100 if"),
    ("o<g20sub> callsub\nM2\n", "unknown o-word command 'callsub'"),
])
def test_messages_keep_the_angle_brackets(text, needle):
    p = interpret(text, keep_going=True)
    said = [e.message for e in p.errors] + p.warnings
    assert any(needle in m for m in said), said


def test_a_call_runs_a_sub_defined_further_on():
    np.testing.assert_allclose(ends("G21\no<b> call [2]\nG0 Z1\nM2\no<b> sub\nG0 X#1\no<b> endsub\n")[:2],
                               [[2, 0, 0], [2, 0, 1]])


def test_reading_a_definition_after_its_call_is_refused():
    with pytest.raises(GCodeError) as info:
        interpret("G21\no<b> call [2]\nG0 Z1\no<b> sub\nG0 X#1\no<b> endsub\nM2\n")
    assert info.value.line == 4 and "after a call already ran it" in info.value.message


def _files(tmp_path, **files):
    for name, text in files.items():
        (tmp_path / f"{name}.ngc").write_text(text)
    return tmp_path / "main.ngc"


def test_a_sub_file_knows_only_the_sub_called_and_those_after_the_call(tmp_path):
    lib = "o<h1> sub\nG0 Z#1\no<h1> endsub\no<lib> sub\nG0 X#1\no<h2> call [7]\no<lib> endsub\n" \
          "o<h2> sub\nG0 Y#1\no<h2> endsub\n"
    main = _files(tmp_path, lib=lib, main="G21\no<lib> call [3]\nM2\n")
    np.testing.assert_allclose(work_end(load_program(main).moves)[:2, :3], [[3, 0, 0], [3, 7, 0]])
    main = _files(tmp_path, main="G21\no<lib> call [3]\no<h1> call [5]\nM2\n")
    with pytest.raises(GCodeError, match="no o<h1> sub") as info:
        load_program(main)
    assert info.value.line == 3


def test_a_sub_line_met_while_running_a_sub_runs_on(tmp_path):
    # LinuxCNC's craftsman m106.ngc: a sub file without its endsub, another sub line in it
    main = _files(tmp_path, m106="o<m106> sub\nG0 X1\no<next> sub\nG0 Y2\no<m103> endsub\nG0 X5\n",
                  main="G21\no<m106> call\nG0 Z7\nM2\n")
    np.testing.assert_allclose(work_end(load_program(main).moves)[:3, :3], [[1, 0, 0], [1, 2, 0], [1, 2, 7]])


@pytest.mark.parametrize("text,line", [
    ("G21\no1 if [1]\nG0 X1\no1 endif\no1 if [1]\nG0 X2\no1 endif\nM2\n", 5),
    ("G21\n#1=0\no1 while [#1 LT 2]\n#1=[#1+1]\no1 endwhile\no1 while [#1 LT 4]\n#1=[#1+1]\no1 endwhile\nM2\n", 6),
])
def test_a_label_run_from_two_lines_is_refused_at_the_second(text, line):
    # rs274: "duplicate O-word label"
    with pytest.raises(GCodeError, match="already used on line") as info:
        interpret(text)
    assert info.value.line == line


def test_labels_are_per_program_and_per_called_sub():
    # the same o1 in a sub (called twice) and in the program is no duplicate
    text = "G21\no2 sub\no1 if [#1]\nG0 X#1\no1 endif\no2 endsub\no2 call [1]\no2 call [2]\n" \
           "o1 if [1]\nG0 Y3\no1 endif\nM2\n"
    np.testing.assert_allclose(ends(text)[:3], [[1, 0, 0], [2, 0, 0], [2, 3, 0]])
