"""The poll loop: poll a controller, step the session, until the program ends.

:func:`run_controller` is the one loop ``live`` and ``dry-run`` (and the tests and
benchmarks) run. It never lets a driver failure end or freeze monitoring: exceptions
become MISSED states, link events are drained every poll, a controller that gives no
fresh state is said every few seconds (:class:`LinkWatch`) and given up after the job's
give-up time. It ends at the program's end, on an alarm, on ``stop``, or on the caller's
``done()``; ``session.end_reason`` says which.
"""

from __future__ import annotations

import math
import time

import numpy as np

from drivers.state import MachineState, RunState, stale_state
from monitor.job import DEFAULT_GIVE_UP_S
from monitor.session import Session
from monitor.sync import SyncResult

#: how long a controller may give no fresh state before the run ends (s, wall clock);
#: job ``[controller] give_up_s``, ``--give-up``
GIVE_UP_S = DEFAULT_GIVE_UP_S
#: while no fresh state comes, say so this often (s, wall clock)
LOST_NOTICE_S = 5.0
#: "monitor falling behind" is said at most this often (s, wall clock)
BEHIND_NOTICE_S = 5.0
#: a look-ahead backlog (program s its waiting rows reach back from the horizon end)
#: worth saying: predictions there come this much later than they could
BEHIND_BACKLOG_S = 1.0


def run_controller(session: Session, controller, period: float, status=None, stop=None,
                   done=None, max_seconds: float | None = None, notify=None,
                   give_up_s: float | None = GIVE_UP_S, notice_every: float = LOST_NOTICE_S,
                   clock=time.monotonic, resume_after: float | None = None) -> int:
    """Poll ``controller`` every ``period`` s and step ``session`` until the program ends.

    ``done()`` (optional) says the run is over (the virtual controller's ``done``);
    without it the loop ends when the machine stands idle at the end of the program's
    last motion, or in alarm. It also ends on ``stop`` (an Event), ``KeyboardInterrupt``,
    after ``max_seconds``, or when no fresh state came for ``give_up_s`` (wall s; None:
    never). ``session.end_reason`` says which.

    No driver failure ends or freezes the loop: an exception from the controller is
    recorded as a MISSED state (``raw``: the exception) and polling goes on. Every poll
    drains ``controller.link_events()`` (when it has them) into the session. ``notify``
    (callable(dict), optional) gets every link event and gap record as JSON-ready dicts,
    and while no fresh state comes, every ``notice_every`` s, a ``{"event": "lost"}``
    record ("controller lost for 30 s, retrying"). When the monitor cannot keep up (a
    step longer than ``period``, a look-ahead backlog, the spindle overtaking the
    look-ahead) ``notify`` gets, at most every :data:`BEHIND_NOTICE_S`, a ``{"event":
    "behind"}`` record ("monitor falling behind: ..."), also kept in the run file's alerts
    (channel ``behind``). ``clock`` (s) times the steps and the notices (tests pass their
    own). ``resume_after`` (s, dry runs only): resume the controller that long after it
    stood in dexmon's feed hold (a virtual machine has no cycle-start button). Returns the
    number of states processed.
    """
    n = 0
    start = clock()
    watch = LinkWatch(give_up_s, notice_every, notify)
    behind = BehindWatch(period, BEHIND_NOTICE_S, notify, session.run)
    held_since = None  # clock s when the machine was first seen in dexmon's hold
    session.on_gap = notify
    end_at = _program_end(session)
    session.end_reason = "stopped"
    for state in _guarded_states(controller, period, session, stop):
        _drain_link_events(controller, session, notify)
        t_step = clock()
        info = session.step(state)
        now = clock()
        session.alerter.follow_state(state)  # after dexmon's feed hold: held? resumed?
        if resume_after is not None:
            held_since = _resume_dry_run(controller, session.alerter, resume_after, held_since, now)
        n += 1
        behind.see(state.t, now - t_step, session.lookahead.backlog_s, info.overtaken, session, now)
        gave_up = watch.see(state, now)
        if status is not None:
            status.update(state, info.sync, session.path.duration, len(session.findings), info.seconds * 1e3,
                          note=watch.note(now) or _hold_note(session.alerter),
                          upcoming=lambda: _upcoming(session, info.sync, state))
        if gave_up:
            session.end_reason = gave_up
            break
        if stop is not None and stop.is_set():
            break
        if done is not None and done():
            # one more state so the last motion is cut
            last = next(_guarded_states(controller, period, session), None)
            if last is not None:
                session.step(last)
                n += 1
            session.end_reason = "done"
            break
        if done is None and state.fresh and state.state == RunState.IDLE and _at_end(info.sync, end_at):
            session.end_reason = "program end"
            break
        if state.state == RunState.ALARM and done is None:
            session.end_reason = "alarm"
            break
        if max_seconds is not None and now - start > max_seconds:
            session.end_reason = "time limit"
            break
    _drain_link_events(controller, session, notify)
    return n


def _upcoming(session: Session, sync: SyncResult | None, state: MachineState) -> str:
    """The status line's countdown to the next predicted finding ("" when none is ahead)."""
    if sync is None:
        return ""
    from monitor.status import next_finding

    ovr = state.overrides[0] if state.overrides else 100
    return next_finding(session.findings, session.path.row_t0, sync.progress, ovr)


def _resume_dry_run(controller, alerter, after: float, since: float | None, now: float) -> float | None:
    """Resume ``controller`` once it stood ``after`` s (loop clock) in dexmon's feed hold;
    returns when it was first seen held (None: not held). A resume the machine ignores
    (still decelerating) is tried again ``after`` s later."""
    h = alerter.hold
    if h is None or h.get("held_t") is None:
        return None
    if since is None:
        return now
    if now - since < after:
        return since
    try:
        controller.resume()
    except Exception:  # noqa: BLE001 - the loop goes on; the hold note stays on the status line
        pass
    return now


def _hold_note(alerter) -> str:
    """For the status line while the machine stands in dexmon's feed hold."""
    h = getattr(alerter, "hold", None)
    if not h or h.get("held_t") is None:
        return ""
    return f"HELD by dexmon ({h['kind']} line {h['line']}): resume with ~ / cycle start"


def _program_end(session: Session) -> tuple[int, float] | None:
    """``(row, progress s)`` where the program's last motion ends, or None (no motion).

    On a job whose kinematics turns A B C a row turning only a rotary (unwinding A at the
    end) is motion too: the sync follows the angles there (``session.rotary_scale``).
    Elsewhere the rotaries turn nothing the sync sees, so only X Y Z count."""
    mv = session.moves
    if not len(mv):
        return None
    axes = 6 if session.rotary_scale is not None else 3
    moving = np.nonzero(np.any(mv["start"][:, :axes] != mv["end"][:, :axes], axis=1))[0]
    if not moving.size:
        return None
    row = int(moving[-1])
    return row, float(session.path.row_t1[row])


def _at_end(sync: SyncResult | None, end_at: tuple[int, float] | None) -> bool:
    """True when ``sync`` has the machine at the end of the program's last motion (the
    rows after it -- M5, M2 -- move nothing, so the sync never reaches them)."""
    if sync is None or end_at is None or sync.how == "lost":
        return False
    row, progress = end_at
    return sync.row >= row and sync.progress >= progress - 1e-9


class BehindWatch:
    """Says when the monitor cannot keep up with the machine -- steps longer than the poll
    ``period`` (s), a look-ahead backlog of :data:`BEHIND_BACKLOG_S` or more, the spindle
    overtaking the look-ahead -- at once the first time, then at most every
    ``notice_every`` s (``now``'s clock), each notice summing up what happened since the
    last one. Notices go to ``notify`` and to ``run``'s alerts (channel ``behind``)."""

    def __init__(self, period: float, notice_every: float, notify=None, run=None):
        self.period = float(period)
        self.notice_every = float(notice_every)
        self.notify = notify
        self.run = run
        self.notices = 0
        self._next_notice = -math.inf
        self._reset()

    def _reset(self) -> None:
        self.slow_steps, self.longest_s, self.backlog_s = 0, 0.0, 0.0
        self.overtaken: list[tuple[int, int]] = []   # program lines (first, last) not predicted

    def see(self, t: float, step_s: float, backlog_s: float, overtaken, session: Session, now: float) -> dict | None:
        """Take one step: its controller time ``t``, duration ``step_s`` (s), the
        look-ahead's backlog (program s) and the rows it was overtaken on (or None).
        Returns the notice given, if any."""
        if self.period > 0 and step_s > self.period:
            self.slow_steps += 1
            self.longest_s = max(self.longest_s, step_s)
        if backlog_s >= BEHIND_BACKLOG_S:
            self.backlog_s = max(self.backlog_s, backlog_s)
        if overtaken is not None:
            lines = session.moves["line"]
            self.overtaken.append((int(lines[overtaken[0]]), int(lines[overtaken[1]])))
        if not (self.slow_steps or self.backlog_s or self.overtaken) or now < self._next_notice:
            return None
        rec = self._notice(t)
        self._next_notice = now + self.notice_every
        self._reset()
        return rec

    def _notice(self, t: float) -> dict:
        parts = []
        if self.slow_steps:
            parts.append(f"{self.slow_steps} step(s) longer than the poll period of {self.period * 1e3:.0f} ms "
                         f"(longest {self.longest_s * 1e3:.0f} ms)")
        if self.backlog_s:
            parts.append(f"the look-ahead is up to {self.backlog_s:.1f} s behind its horizon")
        for a, b in self.overtaken[:3]:
            parts.append(f"the spindle overtook the look-ahead: {'line ' + str(a) if a == b else f'lines {a}-{b}'} "
                         "not predicted")
        rec = {"event": "behind", "t": t, "slow_steps": self.slow_steps,
               "longest_step_ms": round(self.longest_s * 1e3, 1), "period_ms": round(self.period * 1e3, 1),
               "backlog_s": round(self.backlog_s, 3), "overtaken_lines": [list(x) for x in self.overtaken],
               "message": "monitor falling behind: " + "; ".join(parts)
                          + " (findings there come with less lead time, or only when they happen)"}
        self.notices += 1
        if self.run is not None:
            self.run.append_alert("behind", rec["message"], t=t)
        if self.notify is not None:
            self.notify(rec)
        return rec


class LinkWatch:
    """Watches for a controller that gives no fresh state: says so every ``notice_every``
    s and gives up after ``give_up_s`` (wall clock, s; None: never)."""

    def __init__(self, give_up_s: float | None, notice_every: float, notify=None):
        self.give_up_s = give_up_s
        self.notice_every = float(notice_every)
        self.notify = notify
        self.since: float | None = None   # wall time of the first not-fresh state in a row
        self._next_notice = 0.0
        self.notices = 0

    def see(self, state: MachineState, now: float) -> str | None:
        """Take one state at wall time ``now``; the reason to give up, or None."""
        if state.fresh:
            self.since = None
            return None
        if self.since is None:
            self.since, self._next_notice = now, now + self.notice_every
            return None
        lost = now - self.since
        if self.give_up_s is not None and lost >= self.give_up_s:
            return (f"gave up: no fresh state from the controller for {lost:.1f} s "
                    f"(give-up time {self.give_up_s:g} s; last: {state.state.value}: {state.raw})")
        if now >= self._next_notice:
            self._next_notice = now + self.notice_every
            self.notices += 1
            if self.notify is not None:
                self.notify({"event": "lost", "t": state.t, "seconds": round(lost, 1), "state": state.state.value,
                             "message": f"controller lost for {lost:.0f} s, retrying", "raw": state.raw})
        return None

    def note(self, now: float) -> str:
        """For the status line: "lost 30 s, retrying" while no fresh state comes, else ""."""
        if self.since is None or now - self.since < 1.0:
            return ""
        return f"lost {now - self.since:.0f} s, retrying"


def _guarded_states(controller, period: float, session: Session, stop=None):
    """``controller.states(period)``, where an exception (a driver that broke its
    contract) becomes a MISSED state at the last known position, ``raw`` naming it, and
    polling goes on with a fresh iterator after ``period``. Times never go backwards:
    an exception's state is stamped on the controller's clock, extrapolated from its last
    state by the wall clock."""
    import threading

    pause = stop if stop is not None else threading.Event()
    last_t, offset = None, 0.0
    while True:
        try:
            for state in controller.states(period):
                last_t, offset = state.t, state.t - time.monotonic()
                yield state
            return  # the controller ended its states (closed)
        except Exception as exc:  # noqa: BLE001 - any driver failure is a missed poll
            t = time.monotonic() + offset
            t = t if last_t is None else max(t, last_t)
            last_t = t
            yield stale_state(session.last, RunState.MISSED, t, f"{type(exc).__name__}: {exc}")
            pause.wait(period)  # pacing the retries, as states() paces the polls


def _drain_link_events(controller, session: Session, notify) -> None:
    """Hand the controller's queued link events to the session (and ``notify``)."""
    drain = getattr(controller, "link_events", None)
    if drain is None:
        return
    try:
        events = drain()
    except Exception:  # noqa: BLE001 - a driver's event queue must not end the run
        return
    for ev in events:
        rec = session.link_event(ev)
        if notify is not None:
            notify(rec)
