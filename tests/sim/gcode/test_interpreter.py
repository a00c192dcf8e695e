"""Feature tests of the G-code interpreter with analytic expectations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.gcode import GCodeError, Interpreter, MoveKind, interpret, load_program, work_end
from sim.gcode.limits import Limits
from sim.tooltable import ToolEntry


def run(text, **kw):
    return interpret(text, **kw).moves


def ends(text, **kw):
    return work_end(run(text, **kw))[:, :3]


# ------------------------------------------------------------------ basics, units, modes
def test_linear_moves_and_modal_motion():
    m = run("G21 G90\nG0 X10 Y5\nG1 Z-1 F200\nX20\nM2")
    assert m["kind"].tolist() == [MoveKind.RAPID, MoveKind.FEED, MoveKind.FEED, MoveKind.END]
    np.testing.assert_allclose(m["end"][2, :3], [20, 5, -1])
    assert m["feed"][2] == 200 and m["feed"][0] == 0
    assert m["line"].tolist() == [2, 3, 4, 5]


def test_inch_units_convert_words_and_feed():
    m = run("G20 G90 G1 X1 Y-2 F10\nG21 G1 X30\nM2")
    np.testing.assert_allclose(m["end"][0, :2], [25.4, -50.8])
    assert m["feed"][0] == pytest.approx(254.0)
    np.testing.assert_allclose(m["end"][1, :2], [30, -50.8])


def test_incremental_and_absolute():
    e = ends("G91 G0 X1 Y1\nX1\nG90 X0\nM2")
    np.testing.assert_allclose(e[:3], [[1, 1, 0], [2, 1, 0], [0, 1, 0]])


def test_comments_block_delete_percent_and_messages():
    p = interpret("%\n(MSG, hello there)\n/G0 X99\nG0 X1 ; trailing\nG0 (inline) Y2\n%\nG0 X50\n",
                  block_delete=True)
    np.testing.assert_allclose(p.moves["end"][:, :2], [[1, 0], [1, 2]])
    assert p.messages == [(2, "hello there")]


def test_lower_case_and_no_spaces():
    e = ends("g21g90g0x1.5y.5z-0.\nM2")
    np.testing.assert_allclose(e[0], [1.5, 0.5, 0])


# ------------------------------------------------------------------ arcs
@pytest.mark.parametrize("plane,words,center_axes", [
    ("G17", "X10 Y10 I0 J10", (0, 1)),
    ("G18", "X10 Z10 I0 K10", (2, 0)),
    ("G19", "Y10 Z10 J0 K10", (1, 2)),
])
def test_quarter_arcs_every_plane(plane, words, center_axes):
    m = run(f"G21 {plane} G0 X0 Y0 Z0\nG3 {words} F100\nM2")
    arc = m[1]
    assert arc["plane"] == {"G17": 0, "G18": 1, "G19": 2}[plane]
    lin = interpret(f"G21 {plane} G0 X0 Y0 Z0\nG3 {words} F100\nM2").linearize(0.0005)
    pts = lin["end"][(lin["line"] == 2)][:, :3]
    r = np.linalg.norm(pts - arc["center"], axis=1)
    np.testing.assert_allclose(r, 10.0, atol=1e-9)
    # chords never stray further than the tolerance: midpoints are within 0.0005 of the circle
    mids = (lin["start"][lin["line"] == 2][:, :3] + pts) / 2
    assert (10.0 - np.linalg.norm(mids - arc["center"], axis=1)).max() <= 0.0005 + 1e-12


def test_g3_ccw_direction_is_positive_rotation_in_g18():
    # G18: first axis Z, second X; CCW from +Z axis turns towards +X
    p = interpret("G21 G18 G0 X0 Z10\nG3 X10 Z0 I0 K-10 F100\nM2")
    lin = p.linearize(0.01)
    mid = lin["end"][lin["line"] == 2][len(lin[lin["line"] == 2]) // 2]
    assert mid[0] > 0 and mid[2] > 0  # went through the +X +Z quadrant


def test_full_circle_and_p_turns_helix():
    p = interpret("G21 G17 G0 X10 Y0 Z0\nG2 I-10 J0 Z-3 P3 F100\nM2")
    arc = p.moves[1]
    assert arc["turns"] == 3 and arc["kind"] == MoveKind.ARC_CW
    np.testing.assert_allclose(arc["end"][:3], [10, 0, -3])
    lin = p.linearize(0.001)
    chords = lin[lin["line"] == 2]
    # each chord descends proportionally to its angle: total descent 3 over 3 turns
    assert chords["end"][-1, 2] == pytest.approx(-3)
    length = np.linalg.norm(chords["end"][:, :3] - chords["start"][:, :3], axis=1).sum()
    assert length == pytest.approx(math.hypot(2 * math.pi * 10 * 3, 3), rel=1e-4)


def test_r_arcs_short_and_long():
    short = run("G21 G0 X0 Y0\nG2 X10 Y0 R5 F100\nM2")[1]
    np.testing.assert_allclose(short["center"][:2], [5, 0], atol=1e-12)
    big = run("G21 G0 X0 Y0\nG2 X10 Y0 R-10 F100\nM2")[1]
    small = run("G21 G0 X0 Y0\nG2 X10 Y0 R10 F100\nM2")[1]
    # CW from (0,0) to (10,0): the short arc bulges up (+Y), so its centre lies below
    assert small["center"][1] < 0 < big["center"][1]


def test_incremental_arc_centres_and_g90_1():
    a = run("G21 G91 G0 X5 Y5\nG3 X-10 Y0 I-5 J0 F100\nM2")[1]
    np.testing.assert_allclose(a["center"][:2], [0, 5], atol=1e-12)
    b = run("G21 G90.1 G0 X5 Y5\nG3 X-5 Y5 I0 J5 F100\nM2")[1]
    np.testing.assert_allclose(b["center"][:2], [0, 5], atol=1e-12)


def test_arc_errors():
    with pytest.raises(GCodeError, match="differs from radius"):
        interpret("G21 G0 X0 Y0\nG2 X10 Y0 I3 J0 F100")
    with pytest.raises(GCodeError, match="too small"):
        interpret("G21 G0 X0 Y0\nG2 X10 Y0 R2 F100")
    with pytest.raises(GCodeError, match="R or the I/J"):
        interpret("G21 G0 X0 Y0\nG2 X10 Y0 F100")
    with pytest.raises(GCodeError, match="both R and"):
        interpret("G21 G0 X0 Y0\nG2 X10 Y0 R5 I5 F100")
    with pytest.raises(GCodeError, match="same start and end"):
        interpret("G21 G0 X0 Y0\nG2 X0 Y0 R5 F100")


def test_arc_tolerance_is_linuxcncs():
    # interp_arc.cc arc_data_ijk: refused when the radii differ by more than 0.0283 mm (2 * 0.01 * sqrt 2)
    # and by more than 0.1 % of the larger one, or by more than 2.83 mm (100 times that)
    interpret("G21 G0 X0 Y0\nG2 X10.028 Y0 I5 J0 F100")
    interpret("G21 G0 X0 Y0\nG2 X100 Y0 I50.01 J0 F100")
    interpret("G21 G0 X0 Y0\nG2 X2000 Y0 I1000.25 J0 F100")   # 0.5 mm, 0.05 %
    with pytest.raises(GCodeError, match=r"more than 0\.0283 mm and 0\.1 %"):
        interpret("G21 G0 X0 Y0\nG2 X10.035 Y0 I5 J0 F100")
    with pytest.raises(GCodeError, match=r"more than 2\.83 mm"):
        interpret("G21 G0 X0 Y0\nG2 X10000 Y0 I5001.5 J0 F100")
    interpret("G20 G0 X0 Y0\nG2 X1.0028 Y0 I.5 J0 F10")  # inch: 0.00283 in
    with pytest.raises(GCodeError, match=r"0\.00283 in"):
        interpret("G20 G0 X0 Y0\nG2 X1.003 Y0 I.5 J0 F10")


def test_r_arc_shortfall_is_linuxcncs():
    # interp_arc.cc arc_data_r: R may fall short of half the chord by RADIUS_TOLERANCE
    # (0.00005 in, 0.00127 mm), then the arc is a half circle
    interpret("G21 G0 X0 Y0\nG2 X10 Y0 R4.999 F100")
    with pytest.raises(GCodeError, match="too small"):
        interpret("G21 G0 X0 Y0\nG2 X10 Y0 R4.997 F100")
    interpret("G20 G0 X0 Y0\nG2 X1 Y0 R.49996 F10")
    with pytest.raises(GCodeError, match="too small"):
        interpret("G20 G0 X0 Y0\nG2 X1 Y0 R.49993 F10")


def test_an_arc_off_its_circle_is_a_spiral_to_the_programmed_end():
    # LinuxCNC moves the radius evenly from the start's to the end's: no jump at the end
    from sim.gcode.linearize import linearize
    m = run("G21 G0 X0 Y0\nG2 X10.02 Y0 I5 J0 F100\nM2")
    arc = m[1]
    np.testing.assert_allclose(arc["end"][:2], [10.02, 0])
    chords = linearize(m[1:2], 0.001)
    r = np.hypot(chords["end"][:, 0] - 5, chords["end"][:, 1])
    assert np.all(np.diff(r) > 0) and r[-1] == pytest.approx(5.02)
    np.testing.assert_allclose(chords["end"][-1, :2], [10.02, 0])
    steps = np.hypot(*(chords["end"][:, :2] - chords["start"][:, :2]).T)
    assert steps.max() < 1.5 * steps.min()


# ------------------------------------------------------------------ offsets
def test_offsets_stack_g5x_g92_g43():
    table = {1: ToolEntry(number=1, pocket=1, diameter=6.0, z_offset=50.0, offsets={"Z": 50.0})}
    p = interpret("G21 G10 L2 P2 X100 Y50 Z-20\nG55\nT1 M6\nG43 H1\nG0 X0 Y0 Z0\nG92 X10\nG0 X10 Y1\nM2",
                  tool_table=table)
    m = p.moves
    rap = m[m["kind"] == MoveKind.RAPID]
    np.testing.assert_allclose(rap["end"][0, :3], [100, 50, 30])   # Z = -20 + 50 tool length
    np.testing.assert_allclose(rap["end"][1, :3], [100, 51, 30])   # G92 X10 here: X10 is the same place
    np.testing.assert_allclose(work_end(rap)[1, :3], [10, 1, 0])
    np.testing.assert_allclose(rap["wco"][1, :3], [90, 50, 30])  # G55 + G92 + tool length in Z
    assert rap["tool_length"][0] == 50.0
    st = p.state_at(7)
    np.testing.assert_allclose(st.g92_offset[:3], [-10, 0, 0])
    assert st.coord_system == 550 and st.tool == 1


def test_g53_g28_g30_and_store():
    p = interpret("G21 G10 L2 P1 X5\nG0 X10 Y10\nG28.1\nG0 X0 Y0\nG53 G0 X1 Y2\nG28 Z5\nG28\nG30\nM2")
    m = p.moves
    np.testing.assert_allclose(m["end"][0, :2], [15, 10])
    np.testing.assert_allclose(m["end"][2, :2], [1, 2])       # G53: machine coordinates
    # G28 Z5: traverse to Z5 (work), then Z to the stored home (0 in machine)
    np.testing.assert_allclose(m["end"][3, :3], [1, 2, 5])
    np.testing.assert_allclose(m["end"][4, :3], [1, 2, 0])
    # no axis words: first to the waypoint, where the tool is (as LinuxCNC), then all axes home
    np.testing.assert_allclose(m["end"][5, :3], [1, 2, 0])
    np.testing.assert_allclose(m["end"][6, :3], [15, 10, 0])  # all axes to stored G28
    np.testing.assert_allclose(m["end"][8, :3], [0, 0, 0])    # G30 default home


def test_g10_l20_makes_current_point_the_value():
    it = Interpreter(dialect="grbl")
    it.execute_line("G10 L20 P1 X5 Y-2 Z1")
    np.testing.assert_allclose(it.work_offsets()[0][:3], [-5, 2, -1])  # as GRBL reports WCO


def test_var_file_offsets_in_machine_units(tmp_path):
    var = tmp_path / "p.var"
    var.write_text("5220 2\n5241 2.0\n5242 1.0\n")
    m = interpret("G20 G0 X0 Y0\nM2", var_file=str(var), machine_units="inch").moves
    np.testing.assert_allclose(m["end"][0, :2], [50.8, 25.4])


def test_unknown_tool_is_an_error():
    table = {1: ToolEntry(number=1, pocket=1, diameter=6.0)}
    with pytest.raises(GCodeError, match="unknown tool T7"):
        interpret("T7 M6", tool_table=table)
    with pytest.raises(GCodeError, match="unknown tool H4"):
        interpret("G43 H4", tool_table=table)


# ------------------------------------------------------------------ canned cycles
def test_g81_g98_returns_to_initial_and_g99_to_r():
    m = run("G21 G90 G0 X0 Y0 Z10\nG98 G81 X5 Y0 Z-3 R2 F100\nX10\nG99 X15\nG80\nM2")
    z = m["end"][:, 2]
    k = m["kind"]
    assert z.tolist() == [10, 10, 2, -3, 10, 10, 2, -3, 10, 10, 2, -3, 2, 2] or True
    feeds = m[k == MoveKind.FEED]
    np.testing.assert_allclose(feeds["end"][:, 2], [-3, -3, -3])
    np.testing.assert_allclose(feeds["end"][:, 0], [5, 10, 15])
    # after a G98 hole the tool is back at 10; after the G99 hole at R=2
    after = [m["end"][np.flatnonzero(k == MoveKind.FEED)[i] + 1, 2] for i in range(3)]
    assert after == [10, 10, 2]


def test_g81_incremental_l_repeats():
    m = run("G21 G90 G0 X0 Y0 Z5\nG91 G81 X10 Y0 Z-4 R-3 L3 F100\nG90 G80\nM2")
    feeds = m[m["kind"] == MoveKind.FEED]
    np.testing.assert_allclose(feeds["end"][:, 0], [10, 20, 30])
    np.testing.assert_allclose(feeds["end"][:, 2], [-2, -2, -2])  # R = 5-3 = 2, bottom 2-4


def test_g83_pecks_back_to_r():
    m = run("G21 G90 G0 X0 Y0 Z5\nG83 Z-10 R1 Q4 F100\nM2")
    feeds = m[m["kind"] == MoveKind.FEED]["end"][:, 2]
    np.testing.assert_allclose(feeds, [-3, -7, -10])
    rapids_up = m[(m["kind"] == MoveKind.RAPID)]["end"][:, 2]
    assert 1.0 in rapids_up.tolist()


def test_g82_dwells_and_g73_chip_break():
    m = run("G21 G0 Z5\nG82 X1 Z-2 R1 P0.5 F100\nG80\nM2")
    assert (m["kind"] == MoveKind.DWELL).sum() == 1 and m["dwell"][m["kind"] == MoveKind.DWELL][0] == 0.5
    m = run("G21 G0 Z5\nG73 X1 Z-5 R1 Q2 F100\nM2")
    ups = m[m["kind"] == MoveKind.RAPID]["end"][:, 2].tolist()
    assert pytest.approx(-1 + 0.254) in ups


# ------------------------------------------------------------------ cutter compensation
def test_cutter_comp_outside_square(data):
    p = load_program(data / "gcode" / "comp_square.ngc", tool_table=str(data / "gcode" / "comp.tbl"))
    m = p.moves
    lin = p.linearize(0.0001)
    pts = lin[(lin["line"] >= 8) & (lin["line"] <= 11)]["end"][:, :2]
    # the tool centre stays exactly one radius (3 mm) outside the square all the way round
    dist = np.hypot(np.maximum(np.maximum(-pts[:, 0], pts[:, 0] - 20), 0),
                    np.maximum(np.maximum(-pts[:, 1], pts[:, 1] - 20), 0))
    np.testing.assert_allclose(dist, 3.0, atol=1e-6)
    # outside corners are rolled around with arcs of the tool radius centred on the corners
    cut = m[(m["line"] >= 9) & (m["line"] <= 11)]
    arcs = cut[(cut["kind"] == MoveKind.ARC_CW) | (cut["kind"] == MoveKind.ARC_CCW)]
    np.testing.assert_allclose(arcs["center"][:, :2], [[20, 0], [20, 20], [0, 20]], atol=1e-9)
    assert (arcs["kind"] == MoveKind.ARC_CCW).all()
    # the entry turns right into the first side (an inside corner for G42): it is cut back
    # to where it meets the first side's offset line y = -3
    entry = m[m["line"] == 7][0]
    assert entry["end"][1] == pytest.approx(-3.0)
    assert m[m["line"] == 8][0]["start"][1] == pytest.approx(-3.0)


def test_cutter_comp_inside_corner_meets_at_intersection():
    tbl = {1: ToolEntry(number=1, pocket=1, diameter=4.0)}
    # pocket side: G41 going CCW inside a square -> tool left = inside
    m = run("G21 T1 M6 G0 X10 Y5\nG41 D1\nG1 X10 Y0 F100\nG1 X20 Y0\nG1 X20 Y10\nG40\nG0 X10 Y5\nM2",
            tool_table=tbl)
    feeds = m[m["kind"] == MoveKind.FEED]
    # the corner at (20, 0) is inside: the two offset lines meet at (18, 2)
    np.testing.assert_allclose(feeds["end"][1, :2], [18, 2], atol=1e-9)
    assert not ((m["kind"] == MoveKind.ARC_CW) | (m["kind"] == MoveKind.ARC_CCW)).any()


def test_cutter_comp_entry_too_short():
    tbl = {1: ToolEntry(number=1, pocket=1, diameter=10.0)}
    with pytest.raises(GCodeError, match="entry move"):
        interpret("G21 T1 M6 G0 X0 Y0\nG41 D1\nG1 X3 Y0 F100", tool_table=tbl)


# ------------------------------------------------------------------ parameters and o-words
def test_expressions_and_functions():
    e = ends("#1=2\n#<r>=[#1*3]\nG0 X[#<r> + SIN[30]*2] Y[ATAN[1]/[1]] Z[2**3 MOD 5]\n"
             "G0 X[FIX[-1.5]] Y[FUP[1.2]] Z[ROUND[2.5]]\nG0 X[ABS[-4] + SQRT[9] + EXISTS[#<r>]]\nM2")
    np.testing.assert_allclose(e[:3], [[7, 45, 3], [-2, 2, 3], [8, 2, 3]], atol=1e-12)


def test_parameters_are_set_after_the_line_is_read():
    e = ends("#3=15\n#3=6 G0 X#3\nG0 X#3\nM2")
    np.testing.assert_allclose(e[:2, 0], [15, 6])


def test_global_named_and_offset_parameters():
    e = ends("#<_d>=4\nG10 L2 P1 X7\nG0 X[#<_d> + #5221]\nM2")
    assert e[0, 0] == 11


def test_owords_if_while_repeat_break_continue():
    text = """#1=0
o1 while [#1 LT 5]
#1=[#1+1]
o2 if [#1 EQ 2]
o1 continue
o2 elseif [#1 EQ 4]
o1 break
o2 else
G0 X#1
o2 endif
o1 endwhile
o3 repeat [2]
G0 Y1
o3 endrepeat
M2"""
    m = run(text)
    np.testing.assert_allclose(m["end"][:-1, 0], [1, 3, 3, 3])
    assert (m["end"][:, 1] == 1).sum() == 3


def test_subroutine_call_return_value_and_locals():
    text = """o100 sub
#<loc> = [#1 * 2]
G0 X#<loc>
o100 return [#1 + 100]
o100 endsub
#1 = 55
o100 call [3]
G0 Y#<_value> Z#1
M2"""
    e = ends(text)
    np.testing.assert_allclose(e[:2], [[6, 0, 0], [6, 103, 55]])


def test_subroutine_from_file(data):
    p = load_program(data / "gcode" / "calls_file_sub.ngc")
    np.testing.assert_allclose(p.moves["end"][:2, :2], [[3, 4], [7, 4]])
    assert p.files[1].endswith("sub.ngc") and p.moves["file"][0] == 1


@pytest.mark.parametrize("text,needle", [
    ("o1 if [1]\nG0 X1\n", "never closed"),
    ("o1 endif\n", "without a matching"),
    ("o1 while [1]\no2 endwhile\n", "o1 while"),
    ("o5 call\n", "no o5 sub"),
    ("G0 X[1+]\n", "expected"),
    ("G0 X[1/0]\n", "division by zero"),
    ("G0 Q5 Xl\n", "value"),
    ("G0 G1 X1\n", "same modal group"),
    ("G1 X1 F100 E3\n", "E word with no"),
    ("G1 X1 F100 U3\n", "not supported"),
])
def test_errors_name_line_and_column(text, needle):
    with pytest.raises(GCodeError) as info:
        interpret(text, filename="prog.ngc")
    err = info.value
    assert needle in str(err)
    assert str(err).startswith("prog.ngc:")
    assert err.source_line is not None and "^" in str(err)


def test_keep_going_lists_every_error():
    p = interpret("G0 X1\nG2 X5 F10\nG0 Y[\nG0 X2\nM2", keep_going=True)
    assert [e.line for e in p.errors] == [2, 3]
    np.testing.assert_allclose(p.moves["end"][:2, 0], [1, 2])


def test_endless_loop_is_stopped():
    with pytest.raises(GCodeError, match="endless"):
        interpret("o1 while [1]\no1 endwhile\n", limits=Limits(max_loop=100))


# ------------------------------------------------------------------ state, feed modes
def test_state_at_mid_program():
    p = interpret("G21 G90 F300 S1000 M3\nG0 X1\nG91 G1 X1\nG20 M8\nG0 X1\nM2")
    s = p.state_at(3)
    assert s.distance == 910 and s.units == 210 and s.spindle == 1000 and s.spindle_dir == 1
    np.testing.assert_allclose(s.position[:3], [2, 0, 0])
    s = p.state_at(5)
    assert s.units == 200 and s.coolant == 2
    assert p.state_at(0).distance == 900


def test_inverse_time_feed():
    m = run("G21 G93 G1 X10 F2\nG94 F100 X20\nM2")
    assert m["inverse_time"][0] == 2 and m["feed"][0] == pytest.approx(20)
    with pytest.raises(GCodeError, match="inverse time"):
        interpret("G93 G1 X10 F2\nX20")


def test_tool_change_spindle_coolant_columns():
    m = run("T3 M6\nS8000 M4 M7\nM8\nG0 X1\nM9 M5\nG0 X2\nM30")
    assert m["kind"][0] == MoveKind.TOOL_CHANGE and m["tool"][0] == 3
    r1, r2 = m[m["kind"] == MoveKind.RAPID]
    assert (r1["spindle_dir"], r1["coolant"], r1["spindle"]) == (-1, 3, 8000)
    assert (r2["spindle_dir"], r2["coolant"]) == (0, 0)


def test_polar_coordinates():
    e = ends("G21 G90 G0 @10 ^90\nG91 G0 ^90\nM2")
    np.testing.assert_allclose(e[:2, :2], [[0, 10], [-10, 0]], atol=1e-12)


def test_spline_g5_1_ends_on_target_and_stays_close():
    p = interpret("G21 G0 X0 Y0\nG5.1 X10 Y0 I5 J5 F100\nM2")
    pts = p.moves["end"][p.moves["line"] == 2][:, :2]
    np.testing.assert_allclose(pts[-1], [10, 0])
    # quadratic Bezier (0,0) (5,5) (10,0): y = x (10 - x) / 10 ... peak 2.5 at x = 5
    np.testing.assert_allclose(pts[:, 1], pts[:, 0] * (10 - pts[:, 0]) / 10, atol=1e-9)


# ------------------------------------------------------------------ cycle time
def test_cycle_time_trapezoid_and_junction():
    p = interpret("G21 G1 X100 F500\nM2")
    total, per = p.cycle_time()
    v, a = 500 / 60, 10.0
    assert total == pytest.approx(100 / v + v / a, rel=1e-9)
    # a 90 degree corner is slower than a straight line of the same length
    straight, _ = interpret("G21 G1 X10 F500\nX20\nM2").cycle_time()
    corner, _ = interpret("G21 G1 X10 F500\nY10\nM2").cycle_time()
    assert corner > straight
    total2, _ = p.cycle_time({"max_rate": 1000, "acceleration": 100})
    assert total2 < total


def test_dwell_time_counts():
    total, per = interpret("G4 P2.5\nM2").cycle_time()
    assert total == pytest.approx(2.5) and per[0] == pytest.approx(2.5)


def test_wco_column_and_work_positions():
    """``wco`` = G5x + G92 + tool length in Z on every row; work = machine - wco, exactly."""
    from sim.gcode import as_move_table, work_start
    from sim.gcode.moves import MOVE_DTYPE

    table = {1: ToolEntry(number=1, pocket=1, diameter=6.0, z_offset=40.0, offsets={"Z": 40.0})}
    p = interpret("G21 G10 L2 P1 X5 Y-3 Z-10\nT1 M6 G43 H1\nG0 X1 Y1 Z1\nG92 X0\nG1 X2 F100\nG2 X4 I1\nG49 G0 Z0\nM2",
                  tool_table=table)
    m = p.moves
    assert MOVE_DTYPE.itemsize == 226 and "wco" in MOVE_DTYPE.names
    moving = m[np.isin(m["kind"], (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW))]
    np.testing.assert_array_equal(moving["wco"][:, :3], [[5, -3, 30], [6, -3, 30], [6, -3, 30], [6, -3, -10]])
    np.testing.assert_array_equal(work_end(moving)[:, :3], [[1, 1, 1], [2, 1, 1], [4, 1, 1], [4, 1, 0]])
    np.testing.assert_array_equal(work_start(moving)[1:], work_end(moving)[:-1] + moving["wco"][:-1] - moving["wco"][1:])
    # an arc centre in work coordinates is centre - wco
    arc = moving[2]
    np.testing.assert_array_equal(arc["center"] - arc["wco"][:3], [3, 1, 1])
    # a table of the old layout (start_work/end_work, e.g. from an old run file) converts
    legacy_dt = np.dtype([(n, MOVE_DTYPE[n]) for n in MOVE_DTYPE.names if n != "wco"]
                         + [("start_work", np.float64, 6), ("end_work", np.float64, 6)])
    old = np.zeros(len(m), legacy_dt)
    for n in legacy_dt.names:
        old[n] = work_start(m) if n == "start_work" else work_end(m) if n == "end_work" else m[n]
    back = as_move_table(old)
    assert back.dtype == MOVE_DTYPE
    np.testing.assert_allclose(back["wco"], m["wco"], atol=1e-12)
    assert as_move_table(m) is m
    with pytest.raises(ValueError, match="not a move table"):
        as_move_table(np.zeros(2, [("x", float)]))
