"""Bad programs never hang, never crash: every runaway is refused at its line.

Each case was seen in a fuzz of mutated programs (issue 12): loops and repeat counts that
never end, cycles and arcs with absurd counts, coordinates no machine has, expressions that
blew the stack, numbers that are not ASCII digits. Each must give a GCodeError naming the
line, quickly, with bounded memory; the limits are configurable.
"""

from __future__ import annotations

import json

import pytest

from sim.gcode.errors import GCodeError
from sim.gcode.limits import Limits
from sim.gcode.program import interpret


def refused(text: str, line: int, match: str, **kw) -> GCodeError:
    with pytest.raises(GCodeError, match=match or None) as exc:
        interpret(text, filename="bad.ngc", **kw)
    assert exc.value.line == line, str(exc.value)
    return exc.value


@pytest.mark.timeout(60)
def test_endless_while_stops_at_the_loop_limit():
    err = refused("#1=1\no101 while [#1 GT 0]\nG1 X1 F100\no101 endwhile\nM2\n", 2, "o101 while.*1000 times",
                  limits=Limits(max_loop=1000))
    assert "max-loop" in str(err) or "limit" in str(err)


@pytest.mark.timeout(60)
def test_empty_endless_while_and_do_while_stop():
    refused("#1=1\no1 while [#1 GT 0]\no1 endwhile\nM2\n", 2, "o1 while", limits=Limits(max_loop=500))
    refused("#1=1\no2 do\no2 while [#1 GT 0]\nM2\n", 2, "o2 do", limits=Limits(max_loop=500))


@pytest.mark.timeout(60)
def test_nested_endless_loops_stop():
    depth = 300
    text = "#1=1\n" + "".join(f"o{k} while [#1 GT 0]\n" for k in range(1, depth + 1)) + "G1 X1 F10\n" \
        + "".join(f"o{k} endwhile\n" for k in range(depth, 0, -1)) + "M2\n"
    refused(text, depth + 1, f"o{depth} while", limits=Limits(max_loop=50))


@pytest.mark.timeout(60)
def test_huge_repeat_count_is_refused_at_its_line():
    refused("o100 repeat [1000000000]\nG1 X1 F100\no100 endrepeat\nM2\n", 1, "repeat count 1000000000",
            limits=Limits(max_loop=100000))


def test_loops_within_the_limit_run():
    p = interpret("#1=0\no1 while [#1 LT 50]\nG1 X[#1] F100\n#1=[#1+1]\no1 endwhile\nM2\n",
                  limits=Limits(max_loop=50))
    assert len(p.moves) == 51


@pytest.mark.timeout(60)
def test_cycle_repeats_and_pecks_are_bounded():
    refused("G90 G0 Z5\nG81 X1 Y1 Z-1 R1 L1000000000 F100\nM2\n", 2, "L1000000000")
    refused("G91 G0 Z5\nG81 X1 Y1 Z-1 R1 L1000000000 F100\nM2\n", 2, "L1000000000")
    refused("G0 Z5\nG73 X1 Y1 Z-100 R1 Q0.000001 F100\nM2\n", 2, "peck")
    refused("G0 Z5\nG83 X1 Y1 Z-100 R1 Q0.000001 F100\nM2\n", 2, "peck")


@pytest.mark.timeout(60)
def test_arc_turns_are_bounded():
    refused("G0 X0 Y0\nG2 X0 Y0 I5 J0 P100000 F100\nM2\n", 2, "P100000")


@pytest.mark.parametrize("word", ["X[-10**300]", "X" + "9" * 400, "Y[10**6]", "Z-1000000"])
def test_coordinates_beyond_any_machine_are_refused(word):
    err = refused(f"G0 Z5\nG1 {word} F100\nM2\n", 2, "")
    assert "machine" in str(err) or "number" in str(err), str(err)


def test_exponent_is_an_e_word():
    # no exponents in G-code: rs274 reads X1e300 as X1 E300, an E word nothing uses
    refused("G0 Z5\nG1 X1e300 F100\nM2\n", 2, "E word with no")


def test_fast_path_refuses_coordinates_beyond_any_machine():
    lines = [f"G1 X{k} Y1 F100" for k in range(20)] + ["G1 X9999999 Y1", "M2"]
    refused("\n".join(lines) + "\n", 21, "beyond")


def test_long_flat_expression_is_no_recursion_error():
    # 2,000 terms: deeper than Python's stack, within the line length
    p = interpret("#1=[" + "+".join(["1"] * 2000) + "]\nG1 X[#1/1000] F100\nM2\n")
    assert p.moves["end"][0][0] == pytest.approx(2.0)
    refused("#1=[" + "+".join(["1"] * 5000) + "]\nM2\n", 1, "characters long")


def test_deeply_nested_brackets_are_refused():
    refused("#1=" + "[" * 1000 + "1" + "]" * 1000 + "\nM2\n", 1, "nested")


def test_unclosed_if_with_keep_going_reports_not_crashes():
    p = interpret("#1=1\no1 if [#1 GT 0]\nG1 X1 F100\no1 else\nG1 X2\nM2\n", keep_going=True)
    assert any("never closed" in str(e) for e in p.errors)


def test_huge_tool_number_is_refused():
    refused("T10000000000 M6\nM2\n", 1, "tool number")


def test_full_width_digits_are_not_numbers():
    refused("G1 X\uff11\uff12 F100\nM2\n", 1, "")


@pytest.mark.timeout(60)
def test_overlong_lines_are_refused():
    refused("G0 X1\nG1 X1 F100" + " " * 100_000 + "\nM2\n", 2, "characters")


def test_moves_json_is_valid_json(tmp_path, capsys):
    from monitor.cli import main

    prog = tmp_path / "p.ngc"
    prog.write_text("G0 X1 Y2 Z3\nG1 X4 F100\nM2\n")
    assert main(["moves", str(prog), "--format", "jsonl"]) == 0
    for line in capsys.readouterr().out.splitlines():
        json.loads(line, parse_constant=lambda c: pytest.fail(f"{c} in JSON output"))


@pytest.mark.timeout(120)
def test_loop_across_a_chunk_boundary_is_not_rescanned_per_pass():
    from sim.gcode import fastpath

    body = "\n".join(f"G1 X{k % 7} Y{k % 5} F100" for k in range(40))
    pad = "\n".join(f"G1 X{k % 3} F100" for k in range(fastpath.CHUNK - 30))
    text = pad + "\n#1=0\no1 while [#1 LT 200]\n" + body + "\n#1=[#1+1]\no1 endwhile\nM2\n"
    scans = []
    real = fastpath.scan

    def counting(lines, a, b):
        scans.append(a)
        return real(lines, a, b)

    fastpath.scan = counting
    try:
        interpret(text)
    finally:
        fastpath.scan = real
    assert len(scans) <= 4, scans[:10]


def test_max_loop_flag_and_job_key(tmp_path, capsys):
    from monitor.cli import main
    from monitor.job import load_job

    prog = tmp_path / "loop.ngc"
    prog.write_text("#1=0\no1 while [#1 LT 300]\nG1 X[#1/100] F100\n#1=[#1+1]\no1 endwhile\nM2\n")
    assert main(["moves", str(prog), "--max-loop", "100"]) == 2
    assert "loop.ngc:2" in capsys.readouterr().err
    assert main(["moves", str(prog), "--max-loop", "300"]) == 0
    job = tmp_path / "job.toml"
    job.write_text(f'[program]\npath = "{prog.name}"\nmax_loop = 100\n')
    assert load_job(job).max_loop == 100
    job.write_text(f'[program]\npath = "{prog.name}"\nmax_loop = 0\n')
    with pytest.raises(Exception, match="max_loop"):
        load_job(job)
