"""Job file: every table parsed, errors name file/key/expected, flags override the file."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from monitor.job import Job, JobError, add_job_arguments, job_from_args, load_job, parse_job_text, require

FULL = """
work_offset = [-200, -100, -50]
resolution = 0.2

[controller]
url = "grbl+socket://127.0.0.1:2000"
poll_hz = 25

[program]
path = "part.nc"
dialect = "grbl"

[stock]
box = [0, 0, 0, 60, 40, 20]

[[fixtures]]
name = "clamp"
box = [-5, 15, 20, 15, 25, 28]

[[fixtures]]
stl = "vise.stl"
offset = [1, 2, 3]

[tools]
table = "tools.tbl"
1 = "flat:6:L=20"
[tools.2]
spec = "ball:6:L=20"
shank = [6, 30]
holder = [25, 40]

[design]
stl = "design.stl"

[tolerance]
gouge = 0.05
interest = 2

[limits]
x = [-300, 0]
z = [-100, 0]

[lookahead]
seconds = 3
mm = 80

[alerts]
actions = ["log", "bell", "feed_hold"]
"""


@pytest.fixture
def job_dir(tmp_path):
    for name in ("part.nc", "vise.stl", "tools.tbl", "design.stl", "stock.stl"):
        (tmp_path / name).write_text("x")
    (tmp_path / "job.toml").write_text(FULL)
    return tmp_path


def test_full_job(job_dir):
    job = load_job(job_dir / "job.toml")
    assert job.controller == "grbl+socket://127.0.0.1:2000" and job.poll_hz == 25
    assert job.program == job_dir / "part.nc" and job.dialect == "grbl"
    assert job.work_offset == (-200, -100, -50)
    assert job.stock.kind == "box" and job.stock.bounds() == ((0, 0, 0), (60, 40, 20))
    assert [f.kind for f in job.fixtures] == ["box", "stl"]
    assert job.fixtures[0].name == "clamp" and job.fixtures[1].offset == (1, 2, 3)
    assert job.fixtures[1].stl == job_dir / "vise.stl"
    assert job.tool_table == job_dir / "tools.tbl"
    assert job.tool(1).spec == "flat:6:L=20" and job.tool(2).shank == (6, 30) and job.tool(2).holder == (25, 40)
    assert job.tool(3) is None
    assert job.design.stl == job_dir / "design.stl"
    assert job.resolution == 0.2
    assert job.tolerance.gouge == 0.05 and job.tolerance.interest == 2
    assert job.limits == {"x": (-300, 0), "z": (-100, 0)}
    assert job.horizon_s == 3 and job.horizon_mm == 80
    assert job.feed_hold and job.text == FULL


@pytest.mark.parametrize("text, message", [
    ('[stock]\nbox = "abc"', r'job.toml: \[stock\] box: expected 6 numbers \(mm.*got "abc"'),
    ('[stock]\nbox = [0, 0, 0, 1, 1]', r"\[stock\] box: expected 6 numbers"),
    ('[stock]\nbox = [0, 0, 5, 1, 1, 1]', r"\[stock\] box: expected x0 < x1"),
    ('[stock]\nbox = [0,0,0,1,1,1]\ncylinder = [0,0,1,0,1]', r"\[stock\]: expected exactly one of"),
    ('[stock]\nsphere = 3', r"\[stock\]: unknown key 'sphere'"),
    ('resolution = -1', r"resolution: expected a positive number \(mm\), got -1"),
    ('resolution = true', r"resolution: expected a positive number"),
    ('[controller]\nurl = "ttyUSB0"', r"\[controller\] url: expected a controller URL"),
    ('[program]\npath = "missing.nc"', r"\[program\] path: file .*missing.nc.* not found"),
    ('[program]\ndialect = "fanuc"', r"\[program\] dialect: expected linuxcnc or grbl"),
    ('[tools]\n1 = "ball"', r'\[tools\] 1: expected a tool spec'),
    ('[tools]\n[tools.2]\nspec = "ball:6"\nshank = [6]', r"\[tools\] 2 shank: expected 2 numbers"),
    ('[tools]\nfoo = 1', r"\[tools\]: unknown key 'foo'"),
    ('[limits]\nx = [5, 1]', r"\[limits\] x: expected min < max"),
    ('[limits]\nw = [0, 1]', r"\[limits\]: unknown key 'w'"),
    ('[alerts]\nactions = ["siren"]', r"\[alerts\] actions: expected a list of log, bell, feed_hold"),
    ('[lookahead]\nseconds = 0', r"\[lookahead\] seconds: expected a positive number \(s\)"),
    ('[controller]\ngive_up_s = -5', r"\[controller\] give_up_s: expected a positive number \(s\), got -5"),
    ('work_offset = "here"', r'work_offset: expected 3 numbers \(mm, or "controller"\), got "here"'),
    ('stock = [', r"job.toml: not valid TOML"),
    ('colour = 1', r"top level: unknown key 'colour'"),
])
def test_errors_name_key_and_expectation(tmp_path, text, message):
    with pytest.raises(JobError, match=message):
        parse_job_text(text, "job.toml", tmp_path)


def test_give_up_time_from_job_and_flag(tmp_path):
    assert parse_job_text("", "j", tmp_path).give_up_s == 600.0
    job = parse_job_text("[controller]\ngive_up_s = 30", "j", tmp_path)
    assert job.give_up_s == 30.0
    assert job_from_args(_args(["--give-up", "2.5"])).give_up_s == 2.5
    with pytest.raises(JobError, match=r"--give-up: expected a positive number \(s\), got 0"):
        job_from_args(_args(["--give-up", "0"]))


def test_work_offset_from_controller_and_cylinder(tmp_path):
    job = parse_job_text('work_offset = "controller"\n[stock]\ncylinder = [10, 10, 5, 0, 20]', "j", tmp_path)
    assert job.work_offset is None
    assert job.stock.bounds() == ((5, 5, 0), (15, 15, 20))


def _args(argv):
    p = argparse.ArgumentParser()
    add_job_arguments(p)
    return p.parse_args(argv)


def test_flags_override_file(job_dir):
    args = _args(["--stock", "box:0,0,0,10,10,10", "--tool", "bull:8:1", "--resolution", "0.5",
                  "--horizon", "7", "--gouge-tol", "0.1", "--work-offset", "controller"])
    job = job_from_args(args, job_dir / "job.toml")
    assert job.stock.box == (0, 0, 0, 10, 10, 10)
    assert job.tool(1).spec == "bull:8:1" and job.tool(99).spec == "bull:8:1"
    assert job.resolution == 0.5 and job.horizon_s == 7 and job.tolerance.gouge == 0.1
    assert job.work_offset is None
    assert job.program == job_dir / "part.nc"  # kept from the file


def test_job_from_flags_alone(job_dir):
    args = _args(["--program", str(job_dir / "part.nc"), "--stock", "cylinder:0,0,10,0,5",
                  "--tool", "flat:6", "--design", str(job_dir / "design.stl"), "--feed-hold"])
    job = job_from_args(args)
    assert job.source is None and job.program == job_dir / "part.nc"
    assert job.stock.kind == "cylinder" and job.design.kind == "stl" and job.feed_hold
    require(job, "program", "stock", "tools")
    with pytest.raises(JobError, match="no controller: give \\[controller\\] in the job file or --controller"):
        require(job, "controller")


def test_bad_flag_names_flag():
    with pytest.raises(JobError, match=r'--stock: box: expected 6 numbers .*got "1,2"'):
        job_from_args(_args(["--stock", "box:1,2"]))
    with pytest.raises(JobError, match=r"--stock: expected box:"):
        job_from_args(_args(["--stock", "sphere:3"]))
    with pytest.raises(JobError, match="job file not found"):
        job_from_args(_args([]), "nope.toml")
    assert isinstance(job_from_args(_args([])), Job)


def test_machine_limits_for_timing_and_their_errors():
    job = parse_job_text('[machine]\nmax_rate = [6000, 6000, 2500]\nacceleration = 400\n'
                         'junction_deviation = 0.02\n')
    assert job.machine == {"max_rate": (6000.0, 6000.0, 2500.0), "acceleration": (400.0, 400.0, 400.0),
                           "junction_deviation": 0.02}
    assert parse_job_text("").machine is None
    with pytest.raises(JobError, match=r"\[machine\] max_rate: expected 3 numbers \(mm/min, one, three \(X Y Z\) or six \(\+ A B C\)\)"):
        parse_job_text('[machine]\nmax_rate = [1, 2]\n')
    with pytest.raises(JobError, match=r"\[machine\] acceleration: expected positive numbers"):
        parse_job_text('[machine]\nacceleration = [1, 0, 2]\n')
    with pytest.raises(JobError, match=r"\[machine\]: unknown key 'rapid'"):
        parse_job_text('[machine]\nrapid = 5\n')


def test_machine_start_and_its_errors():
    job = parse_job_text('[machine]\nstart = [0, 0, -2.5]\n')
    assert job.start == (0.0, 0.0, -2.5) and job.machine is None  # a start alone keeps the default timing
    job = parse_job_text('[machine]\nstart = [1, 2, 3]\nmax_rate = 1000\n')
    assert job.start == (1.0, 2.0, 3.0) and job.machine["max_rate"] == (1000.0, 1000.0, 1000.0)
    assert parse_job_text("").start is None
    with pytest.raises(JobError, match=r"job.toml: \[machine\] start: expected 3 numbers \(mm, machine coords"):
        parse_job_text('[machine]\nstart = [1, 2]\n')


def test_lead_times_come_from_the_planned_cycle_time():
    """Session program time is Program.cycle_time with the job's machine: slower
    acceleration makes the same program take longer (the length/feed estimate would not)."""
    from pathlib import Path

    from monitor.commands.dry_run import EXAMPLE_JOB
    from monitor.work_coords import work_moves
    from monitor.program_moves import load_moves, program_seconds
    from monitor.sync import row_seconds

    job = load_job(Path(EXAMPLE_JOB))
    moves, program = load_moves(job)
    fast = program_seconds(program, moves, {"max_rate": (5000,) * 3, "acceleration": (2000,) * 3})
    slow = program_seconds(program, moves, {"max_rate": (5000,) * 3, "acceleration": (50,) * 3})
    naive = row_seconds(work_moves(moves))
    assert fast.shape == slow.shape == naive.shape == (len(moves),)
    assert slow.sum() > fast.sum() * 1.2 and fast.sum() >= naive.sum() * 0.99

    class NoTiming:
        def cycle_time(self, machine=None):
            raise RuntimeError("no planner")
    assert np.array_equal(program_seconds(NoTiming(), moves), naive)


def test_machine_kinematics_default_is_plain_three_axis():
    from sim.kinematics import Trivial

    assert parse_job_text("").kinematics == Trivial()
    job = parse_job_text('[machine]\nmax_rate = 1000\n')
    assert job.kinematics == Trivial() and job.machine == {"max_rate": (1000.0, 1000.0, 1000.0)}


def test_machine_kinematics_and_their_parameters():
    from sim.kinematics import FourthAxis, HeadHead, TableTable

    job = parse_job_text('[machine]\nkinematics = "xyzac-trt"\nrot_point = [10, 20, 30]\n'
                         'rot_offset = "0, 5, -8"\nconventional_directions = true\n')
    assert job.kinematics == TableTable("A", rot_point=(10, 20, 30), rot_offset=(0, 5, -8),
                                        conventional_directions=True)
    # the build alone keeps the default timing, as start does
    assert job.machine is None
    job = parse_job_text('[machine]\nkinematics = "xyza"\nrot_point = [0, 0, -40]\nstart = [0, 0, 0]\n'
                         'acceleration = 300\n')
    assert job.kinematics == FourthAxis("A", rot_point=(0, 0, -40)) and job.start == (0.0, 0.0, 0.0)
    assert job.machine == {"acceleration": (300.0, 300.0, 300.0)}
    assert parse_job_text('[machine]\nkinematics = "5axiskins"\npivot_length = 250\n').kinematics == \
        HeadHead("B", pivot_length=250)


@pytest.mark.parametrize("machine, message", [
    ('kinematics = "xyzq"', r'job.toml: \[machine\] kinematics: expected one of xyz, xyza, xyzb, xyzac-trt, '
                            r'xyzbc-trt, .*, got "xyzq"'),
    ('kinematics = 5', r'\[machine\] kinematics: expected one of xyz, .*, got 5'),
    ('kinematics = "xyza"\nrot_point = [1, 2]', r'\[machine\] rot_point: expected 3 numbers \(mm, machine coords: '
                                                r'a point of the rotary axis\), got \[1, 2\]'),
    ('kinematics = "xyzac-trt"\nrot_offset = "a, b"', r'\[machine\] rot_offset: expected 3 numbers'),
    ('kinematics = "xyzbc-head"\npivot_length = -3', r'\[machine\] pivot_length: expected a number >= 0 \(mm, '
                                                     r'gauge point to the head.s pivot\), got -3'),
    ('kinematics = "xyzbc-head"\nconventional_directions = "yes"',
     r'\[machine\] conventional_directions: expected true or false, got "yes"'),
    ('kinematics = "xyzac-trt"\npivot_length = 100', r"\[machine\] pivot_length: not used by kinematics "
                                                     r"'xyzac-trt' \(it takes rot_point, rot_offset, "
                                                     r"conventional_directions\)"),
    ('rot_point = [0, 0, 0]', r"\[machine\] rot_point: not used by kinematics 'xyz' \(plain 3-axis: "
                              r"give kinematics\)"),
    ('kinematic = "xyza"', r"\[machine\]: unknown key 'kinematic'; expected one of acceleration, "
                           r"conventional_directions, junction_deviation, kinematics, max_rate, pivot_length, "
                           r"rot_offset, rot_point, start"),
])
def test_machine_kinematics_errors_name_key_and_expected(machine, message):
    with pytest.raises(JobError, match=message):
        parse_job_text(f"[machine]\n{machine}\n")
