"""The live loop's fast paths change no result.

With a design, the checkers of the live model and the look-ahead keep an error map for
gouges only (``Checker.exact_excess_while_cutting`` off: the material left keeps Huang's
estimate while cutting). The example job run through the virtual machine 0.5 mm low
(the program's planted gouge predicted, the machine's found on the live model) gives the same findings
(every record: kind, lines, depth, position, volume, lead time), the same live model and
the same trace in the run file as with the exact map (the session's trace keeps no
history: what it wrote replays the live model).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import monitor.predict as predict
from monitor.commands.dry_run import EXAMPLE_JOB, virtual_controller
from monitor.job import load_job
from monitor.loop import run_controller
from monitor.runfile import RunWriter
from monitor.runreader import RunReader
from monitor.program_moves import load_moves
from monitor.session import Session
from monitor.trace_io import load_trace


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    moves, program = load_moves(job)
    return dataclasses.replace(job, work_offset=(0.0, 0.0, 0.0)), moves, program


def _run(job, moves, program, dz, path):
    machine = moves.copy()
    for col in ("start", "end"):
        machine[col][:, 2] += dz
    machine["center"][:, 2] += dz
    vc = virtual_controller(machine, speed=1.0, rate=50, clock="sim")
    writer = RunWriter(path)
    s = Session(job, moves, program=program, run=writer)
    vc.connect()
    run_controller(s, vc, 0.0, done=lambda: vc.done)
    vc.close()
    s.finish()
    writer.close()
    trace = load_trace(RunReader(path))
    return s, trace


def test_findings_model_and_trace_are_those_of_the_exact_error_map(example, tmp_path, monkeypatch):
    job, moves, program = example
    dz = -0.5
    fast, fast_trace = _run(job, moves, program, dz, tmp_path / "fast.sqlite")
    make = predict.make_checker

    def exact_checker(*a, **kw):
        checker = make(*a, **kw)
        checker.exact_excess_while_cutting = True
        return checker

    monkeypatch.setattr(predict, "make_checker", exact_checker)
    exact, exact_trace = _run(job, moves, program, dz, tmp_path / "exact.sqlite")
    assert exact.live_checks.checker.exact_excess_while_cutting
    assert not fast.live_checks.checker.exact_excess_while_cutting
    gouges = [f for f in exact.findings if f["kind"] == "gouge"]
    assert any(not f["predicted"] for f in gouges), exact.findings
    assert fast.findings == exact.findings
    assert fast.stage == exact.stage
    a, b = fast.live.top(), exact.live.top()
    assert np.array_equal(a, b, equal_nan=True)
    last = exact_trace.z.last_stage  # the last stage that removed material
    assert fast_trace.z.last_stage == last and last > 100
    for stage in (last // 3, last):
        assert np.array_equal(fast_trace.grid_at(stage).top(), exact_trace.grid_at(stage).top(), equal_nan=True)
    assert np.array_equal(exact_trace.grid_at(last).top(), b, equal_nan=True)
    # the session's trace handed every chunk on to the run file and kept none of it
    assert fast._live_trace.trace.z.n_changes == 0 and fast._live_trace.trace.z._keyframes == []
    # the gouge side of both error maps is the same (the look-ahead's found the planted
    # dip on line 22 too)
    for checks in ("live_checks", "lookahead"):
        fm, em = getattr(fast, checks).checker.error_map, getattr(exact, checks).checker.error_map
        assert np.array_equal(fm.gouge, em.gouge, equal_nan=True)
        assert np.nanmin(em.gouge) < -0.4
