"""Rules of LinuxCNC's rs274 outside cycles, probing and tool lengths: the feed rate (G94/G95 reset it,
a G93 F is the move's), and blocks it refuses (G53 with no motion, G10/G28/G30/G92 with a motion code,
absolute-centre arcs missing a centre word)."""

from __future__ import annotations

import pytest

from sim.gcode import GCodeError, MoveKind, interpret


@pytest.mark.parametrize("text", ["G21 F100\nG94\nG1 X1\nM2", "G21 F100\nG95 S100 G1 X1\nM2",
                                  "G21 F100\nG93 G1 X1 F2\nG94 G1 X2\nM2"])
def test_g94_and_g95_reset_the_feed_rate(text):
    with pytest.raises(GCodeError, match="zero feed rate"):
        interpret(text)


def test_g94_with_its_f_word_on_the_line_keeps_it():
    m = interpret("G21 G94 F100\nG1 X1\nM2").moves
    assert m["feed"][0] == 100.0


def test_a_g93_f_word_leaves_the_feed_rate_for_probing():
    # the probe in G93 feeds at the last units-per-minute F (rs274 accepts it)
    m = interpret("G21 G94 F100\nG93 G1 X1 F2\nG38.2 Z-1\nM2").moves
    probe = m[m["kind"] == MoveKind.PROBE][0]
    assert probe["feed"] == 100.0


def test_two_codes_that_use_axis_words_are_refused_even_without_axes():
    with pytest.raises(GCodeError, match="both use axis words"):
        interpret("G21\nG0 G28\nM2")


def test_g53_without_a_motion_on_its_line_is_refused():
    with pytest.raises(GCodeError, match="G53 needs G0 or G1") as info:
        interpret("G21 G0 X1\nG53 M8\nM2")
    assert info.value.line == 2
    interpret("G21 G0 X1\nG53 G0\nG53 Z0\nM2")   # an explicit G0, or axis words with G0 in force


def test_an_absolute_centre_arc_needs_both_centre_words():
    with pytest.raises(GCodeError, match="J word missing in absolute center arc") as info:
        interpret("G21 G90.1 G0 X0 Y0\nG2 X10 I5 F100\nM2")
    assert info.value.line == 2
