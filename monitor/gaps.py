"""The ledger of link trouble in a live run: not-fresh polls counted, gaps opened and closed.

A state that is not fresh (``drivers.state.NOT_FRESH``: missed, bad, disconnected) is
counted by kind. A gap opens on a disconnect, on a LOST or RESET link event, or after
:data:`GAP_POLLS` not-fresh polls in a row: from then on the path the machine took is
unknown. The session closes the gap at the next fresh state (it re-syncs, and says where
and what it cut meanwhile); the ledger turns each gap into one record -- when, how long,
what was missed, how the controller came back -- written to the run file's
``link_events``, handed to ``on_gap`` and listed in the summary.
"""

from __future__ import annotations

from drivers.state import LinkEvent, LinkKind, MachineState, RunState

#: not-fresh polls in a row (missed, bad) after which the path since the last fresh state
#: counts as unknown: a gap, as a disconnect is at once
GAP_POLLS = 5
#: what a not-fresh run state is counted as
COUNTED = {RunState.MISSED: "missed", RunState.BAD: "bad", RunState.DISCONNECTED: "disconnected"}


class GapLedger:
    """Counts, the open gap and the closed gap records of one run.

    Parameters
    ----------
    run : monitor.runfile.RunWriter or None, where link events and gap records go.
    """

    def __init__(self, run=None):
        self.run = run
        #: not-fresh states seen, by kind (missed, bad, disconnected)
        self.counts = {"missed": 0, "bad": 0, "disconnected": 0}
        #: closed gap records, oldest first (JSON-ready dicts, see :func:`gap_message`)
        self.gaps: list[dict] = []
        #: called with every gap record when it closes, or None
        self.on_gap = None
        self.open: dict | None = None       # the open gap, while the path is unknown
        self._unfresh: list[MachineState] = []  # not-fresh states since the last fresh one
        self._t0: float | None = None       # t of the first state: gaps say when, from there
        self._last_fresh_t: float | None = None

    def started(self, t: float) -> None:
        """The run's first state came at ``t`` (gap records count their time from it)."""
        if self._t0 is None:
            self._t0 = t

    def not_fresh(self, state: MachineState) -> None:
        """Count a not-fresh state; a disconnect, or GAP_POLLS of them in a row, opens a gap."""
        self.counts[COUNTED[state.state]] += 1
        self._unfresh.append(state)
        if self.open is not None:
            self.open["polls_missed"] += 1
            self.open[COUNTED[state.state]] += 1
        elif state.state == RunState.DISCONNECTED or len(self._unfresh) >= GAP_POLLS:
            self.open_gap()

    def fresh(self, t: float) -> dict | None:
        """A fresh state came at ``t``: the gap it ends (to close with :meth:`close`), or
        None. Trouble before the run's first fresh state is no gap (there is no path to
        join yet): the counts keep what was missed."""
        gap = self.open if self.open is not None or len(self._unfresh) < GAP_POLLS else self.open_gap()
        self._unfresh = []
        if gap is not None and self._last_fresh_t is None:
            gap = self.open = None
        self._last_fresh_t = t
        return gap

    def open_gap(self, reason: str = "", t: float | None = None) -> dict:
        """Start a gap record at the first not-fresh state since the last fresh one (or
        at ``t``, for a controller that says it lost the link or reset between two fresh
        states); the open one if there is one."""
        if self.open is not None:
            return self.open
        first = self._unfresh[0] if self._unfresh else None
        counted = {k: sum(COUNTED[u.state] == k for u in self._unfresh) for k in self.counts}
        t_lost = first.t if first is not None else t
        self.open = {"event": "gap", "t_lost": t_lost,
                     "run_s": None if t_lost is None or self._t0 is None else round(t_lost - self._t0, 3),
                     "last_fresh_t": self._last_fresh_t,
                     "reason": reason or (first.raw if first is not None else ""),
                     "polls_missed": len(self._unfresh), **counted, "lines_lost": 0, "came_back": "",
                     "reset": False}
        return self.open

    def link_event(self, ev: LinkEvent) -> dict:
        """Take one :class:`drivers.state.LinkEvent`: record it, and let a lost link or a
        reset open a gap (a BACK event's Gap gives the gap record its lines lost and how
        the controller came back). Returns the event as a JSON-ready dict
        (``{"event": "link", "kind", "message", "t", ...}``)."""
        kind = LinkKind(ev.kind)
        rec = {"event": "link", "kind": kind.value, "message": ev.message, "t": ev.t}
        if ev.raw:
            rec["raw"] = ev.raw
        if ev.gap is not None:
            g = ev.gap
            rec["gap"] = {"t_lost": g.t_lost, "t_back": g.t_back, "seconds": g.seconds, "reason": g.reason,
                          "polls_missed": g.polls_missed, "lines_lost": g.lines_lost, "came_back": g.came_back}
        if self.run is not None:
            self.run.append_link_event(ev.t, kind.value, rec)
        if kind in (LinkKind.LOST, LinkKind.RESET, LinkKind.BACK):
            gap = self.open_gap(reason=ev.message if kind == LinkKind.LOST else "", t=ev.t)
            if kind == LinkKind.RESET:
                gap["reset"] = True
                gap["came_back"] = gap["came_back"] or ev.message
                gap["reason"] = gap["reason"] or ev.message
            if ev.gap is not None:
                gap["lines_lost"] += int(ev.gap.lines_lost)
                gap["came_back"] = ev.gap.came_back or gap["came_back"]
                gap["reason"] = gap["reason"] or ev.gap.reason
        return rec

    def close(self, gap: dict, t: float, **facts) -> dict:
        """Finish ``gap`` at ``t`` (None: the run ended inside it) with the session's
        ``facts`` (jump, re-sync, rows cut), say it and file it; returns it."""
        if gap is self.open:
            self.open = None
        back = t is not None and facts.pop("back", True)
        gap.update(t_back=t if back else None,
                   seconds=None if not back or gap["t_lost"] is None else t - gap["t_lost"], **facts)
        gap["message"] = gap_message(gap)
        self.gaps.append(gap)
        if self.run is not None:
            self.run.append_link_event(t if t is not None else gap["t_lost"], "gap", gap)
        if self.on_gap is not None and back:
            self.on_gap(gap)
        return gap


def gap_message(gap: dict) -> str:
    """One line for a person about a gap record: how long, what was missed, how it came
    back and where the monitor found the machine again."""
    seconds = gap.get("seconds")
    head = (f"link gap of {seconds:.1f} s" if seconds is not None and gap.get("t_back") is not None
            else "link lost (not back when the run ended)")
    if gap.get("run_s") is not None:
        head += f" at {_clock(gap['run_s'])} into the run"
    missed = [f"{gap.get('polls_missed', 0)} polls missed"]
    if gap.get("lines_lost"):
        missed.append(f"{gap['lines_lost']} lines lost")
    text = f"{head}: {', '.join(missed)}"
    if gap.get("reason"):
        text += f" ({gap['reason']})"
    if gap.get("came_back"):
        text += f"; came back {gap['came_back']}"
    if gap.get("jump_mm") is not None:
        text += f"; position jumped {gap['jump_mm']:.2f} mm (not cut: the path is unknown)"
    rs = gap.get("resync")
    if rs:
        text += (f"; off the program after it (from line {gap.get('from_line')})" if rs["how"] == "lost"
                 else f"; re-synced at line {rs['line']} (was at line {gap.get('from_line')})")
    if gap.get("rows_cut_unchecked"):
        lines = gap["rows_cut_unchecked"]
        which = f"line {lines[0]}" if lines[0] == lines[-1] else f"lines {lines[0]}..{lines[-1]}"
        text += f"; {which} cut as programmed, unchecked"
    return text


def _clock(seconds: float) -> str:
    """``m:ss.s`` (or ``h:mm:ss``) for a person."""
    m, s = divmod(float(seconds), 60.0)
    h, m = divmod(int(m), 60)
    return f"{h}:{m:02d}:{s:04.1f}" if h else f"{m}:{s:04.1f}"
