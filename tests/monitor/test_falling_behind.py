"""When the monitor cannot keep up it says so ("monitor falling behind") on every output,
at most every few seconds, and a finding with a short or zero lead time says why.

No wall-clock thresholds: slow steps come from a clock the test controls, a backlog from a
throttled look-ahead budget on the virtual controller's simulated clock."""

from __future__ import annotations

import io
import json

import pytest
from rich.console import Console

from monitor.alerts import Alerter
from monitor.commands.dry_run import EXAMPLE_JOB, VIRTUAL_MACHINE, virtual_controller
from monitor.job import load_job
from monitor.loop import BEHIND_NOTICE_S, run_controller
from monitor.runfile import RunWriter
from monitor.runreader import RunReader
from monitor.program_moves import load_moves
from monitor.session import Session

POLL_HZ = 50.0


class StepClock:
    """A clock that moves ``tick`` s each time it is read: every step the loop times
    (read before and after) takes exactly ``tick`` s."""

    def __init__(self, tick: float):
        self.tick, self.now = tick, 0.0

    def __call__(self) -> float:
        self.now += self.tick
        return self.now


class FreeRunning:
    """The virtual controller polled back to back (its simulated clock moves per poll)."""

    def __init__(self, controller):
        self.controller = controller

    def __getattr__(self, name):
        return getattr(self.controller, name)

    def states(self, period):
        while True:
            yield self.controller.poll()


@pytest.fixture(scope="module")
def example():
    job = load_job(EXAMPLE_JOB)
    job.machine = dict(VIRTUAL_MACHINE)
    moves, program = load_moves(job)
    return job, moves, program


def _follow(example, tmp_path, speed=1.0, budget=None, clock=None):
    """Follow the example at ``speed`` simulated s per poll period; returns (session,
    notices, JSON lines, terminal text, run file alerts)."""
    job, moves, program = example
    term, js = io.StringIO(), io.StringIO()
    told = []
    vc = virtual_controller(moves, speed, POLL_HZ, clock="sim")
    with RunWriter(tmp_path / "r.sqlite") as w:
        alerter = Alerter(console=Console(file=term, width=120), json_stream=js, run=w)
        s = Session(job, moves, run=w, alerter=alerter, program=program)
        if budget is not None:
            s.lookahead.budget_rays = budget
        vc.connect()
        run_controller(s, FreeRunning(vc), 1.0 / POLL_HZ, done=lambda: vc.done, notify=told.append,
                       clock=clock or StepClock(0.0))
        vc.close()
        s.finish()
    events = [json.loads(x) for x in js.getvalue().splitlines()]
    return s, told, events, term.getvalue(), RunReader(tmp_path / "r.sqlite").alerts()


def test_keeping_up_says_nothing(example, tmp_path):
    s, told, events, term, alerts = _follow(example, tmp_path)
    assert [r for r in told if r["event"] == "behind"] == []
    assert all(f["lead_time_s"] > 0 and "lead_note" not in f for f in s.findings), s.findings
    assert "falling behind" not in term and all(a["channel"] != "behind" for a in alerts)


def test_steps_longer_than_the_poll_period_are_said_every_few_seconds(example, tmp_path):
    tick = 0.05  # every step 50 ms against a 20 ms poll period
    clock = StepClock(tick)
    s, told, events, term, alerts = _follow(example, tmp_path, clock=clock)
    behind = [r for r in told if r["event"] == "behind"]
    assert behind and behind[0]["slow_steps"] == 1  # said at the first slow step
    for r in behind:
        assert r["message"].startswith("monitor falling behind: ") and "poll period of 20 ms" in r["message"]
        assert r["longest_step_ms"] == pytest.approx(tick * 1e3) and r["period_ms"] == pytest.approx(20.0)
    # at most one notice per BEHIND_NOTICE_S of the loop's clock, each summing up the steps since
    assert len(behind) <= clock.now / BEHIND_NOTICE_S + 1
    assert 1 + sum(r["slow_steps"] for r in behind[1:]) <= len(list(RunReader(tmp_path / "r.sqlite").states()))
    assert [a["text"] for a in alerts if a["channel"] == "behind"] == [r["message"] for r in behind]


def test_a_backlogged_look_ahead_is_said_and_late_findings_say_why(example, tmp_path):
    # one row per step while each poll is 1 s of program: the look-ahead lags its horizon
    s, told, events, term, alerts = _follow(example, tmp_path, speed=POLL_HZ * 1.0, budget=0)
    behind = [r for r in told if r["event"] == "behind"]
    assert behind and "the look-ahead is up to" in behind[0]["message"] and behind[0]["backlog_s"] >= 1.0
    late = [f for f in s.findings if f.get("late_s")]
    assert late, s.findings
    for f in late:
        assert f["predicted"] and f["lead_note"].startswith(f"predicted {f['late_s']:.1f} s late")
        assert "monitor fell behind" in f["lead_note"] and f["lead_note"] in term
        said = next(x for x in events if x["event"] == "finding" and x["line"] == f["line"])
        assert said["late_s"] == f["late_s"] and said["lead_note"] == f["lead_note"]
    assert any(a["channel"] == "behind" for a in alerts)


def test_a_finding_with_lead_time_zero_says_why(example, tmp_path):
    # two program seconds per poll and one row per step: the spindle overtakes the look-ahead
    s, told, events, term, alerts = _follow(example, tmp_path, speed=POLL_HZ * 2.0, budget=0)
    zero = [f for f in s.findings if not f["lead_time_s"]]
    assert zero, s.findings
    for f in zero:
        assert f["lead_note"] == "happened before it could be predicted (the look-ahead had not reached it)"
        assert f"now ({f['lead_note']})" in term
    behind = [r for r in told if r["event"] == "behind"]
    assert behind and all(r["message"].startswith("monitor falling behind") for r in behind)
