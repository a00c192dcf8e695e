"""Alerts: tell the machinist about each finding once — terminal, JSON lines, bell, feed hold.

Findings arrive as JSON-ready dicts (``Finding.to_json()`` plus ``lead_time_s``). The
look-ahead may see one problem more than once, with a slightly different worst point or
line range as more of it enters the horizon, so a finding is *new* only if no finding of
the same kind already alerted lies within ``radius`` mm of it, or within ``line_radius``
mm while sharing a program line (:meth:`Alerter.match`). A finding seen again is followed
along (its points grow), so a gouge that goes on as the tool moves stays one finding. The
look-ahead and the live checks feed the same alerter: a predicted finding that then really
happens is one alert, its record updated to ``status = "happened"``.

Feed hold is sent through the controller's ``feed_hold()`` and only when the job turned it
on (``[alerts] actions = ["feed_hold"]`` or ``--feed-hold``): the monitor never moves the
machine and never sends anything else. A hold is said at once on every channel (terminal,
JSON ``{"event": "feed_hold"}``, run file): that dexmon sent it, for which finding, and how
to go on (:data:`RESUME_HOW`); :meth:`Alerter.follow_state` then says when the machine
really holds and when it leaves the hold (``{"event": "resumed"}``).
"""

from __future__ import annotations

import json
import math
import sys
from typing import Callable, TextIO

import numpy as np

from drivers.state import RunState
from monitor.jsonable import json_default

#: the kinds that justify a feed hold (machine or part at risk), when feed hold is enabled
HOLD_KINDS = frozenset({"gouge", "rapid_into_stock", "holder_contact", "shank_contact",
                        "above_flute_contact", "fixture_collision", "spindle_stopped_cutting",
                        "travel_limit", "non_center_cutting_plunge"})

#: how to go on after dexmon held the feed, said with every hold
RESUME_HOW = ("resume from your G-code sender, or with ~ (cycle start) on the controller, when it is safe; "
              "dexmon keeps monitoring")
#: a hold the machine has not shown after this long (controller s) is said to have failed
HOLD_CONFIRM_S = 2.0

#: points remembered per alerted finding to follow it along (a long gouge)
MAX_TRACK_POINTS = 4096
#: what a ``finding_update`` JSON line may carry of the grown / happened record: only the
#: keys that changed (and ``kind``, ``status``), its new lines as ``lines_added`` with
#: ``line_range``, never the whole list again
UPDATE_KEYS = ("kind", "line", "worst_line", "move", "position", "depth", "area", "volume", "message", "status",
               "stage", "time_s", "happened_t", "happened_position", "happened_line")


def _nan(v) -> float:
    return math.nan if v is None else float(v)


def grow_record(rec: dict, f: dict, merged: set) -> bool:
    """Merge the repeat ``f`` of an alerted finding into its record ``rec`` in place, as
    ``sim.checks.findings.merge_findings`` merges the hits of one finding: all lines, the
    deepest hit's line and position, the maximum depth, the summed area and volume.

    Sizes are only summed over what is new: a repeat from the other source (the live cut
    of a predicted finding) adds its lines only, and a predicted repeat only for move ids
    not in ``merged`` (the move ids whose size ``rec`` holds; updated). Returns True when
    the record changed.
    """
    from sim.checks.findings import Finding, describe

    lines = sorted((set(rec.get("lines") or ()) | set(f.get("lines") or ())
                    | {rec.get("line") or 0, f.get("line") or 0}) - {0})
    changed = lines != list(rec.get("lines") or ())
    rec["lines"] = lines
    # the first and last line of all (a record's list may be cut to its first lines)
    ends = [x for g in (rec, f) for x in (g.get("line_range") or ())] + lines[:1] + lines[-1:]
    if ends:
        rec["line_range"] = [min(ends), max(ends)]
    rec["lines_total"] = max(len(lines), int(rec.get("lines_total") or 0), int(f.get("lines_total") or 0))
    if rec["lines_total"] == len(lines):
        rec.pop("lines_total")
    same_source = bool(f.get("predicted", True)) == bool(rec.get("predicted", True))
    ids = _stages(f)
    # a predicted repeat is new material only for moves not merged yet (the look-ahead
    # checks each row once, but again after re-anchoring); without move ids it cannot tell
    new_material = same_source and (not f.get("predicted", True) or bool(ids - merged))
    if same_source:
        d0, d1 = _nan(rec.get("depth")), _nan(f.get("depth"))
        if not math.isnan(d1) and (math.isnan(d0) or d1 > d0):
            # ``line`` stays where the finding started; the worst hit moves
            rec["depth"], rec["position"] = d1, f.get("position")
            rec["worst_line"] = f.get("worst_line", f.get("line", rec.get("worst_line")))
            for key in ("move", "contact", "programmed", "time_s"):
                if f.get(key) is not None:
                    rec[key] = f[key]
            changed = True
    if new_material:
        merged |= ids
        for name in ("area", "volume"):
            v = _nan(f.get(name))
            if not math.isnan(v) and v > 0:
                rec[name] = round(_nan(rec.get(name)) + v if name in rec else v, 6)
                changed = True
    if changed:
        try:
            fnd = Finding(kind=rec.get("kind", ""), line=int(rec.get("line") or 0),
                          lines=tuple(lines) + tuple(rec.get("line_range") or ()),
                          worst_line=int(rec.get("worst_line") or 0),
                          position=tuple(rec.get("position") or (math.nan,) * 3), depth=_nan(rec.get("depth")),
                          area=_nan(rec.get("area")), volume=_nan(rec.get("volume")),
                          detail=dict(rec.get("detail") or {}))
            rec["message"] = _message_like(rec.get("message", ""), fnd, describe(fnd))
        except (ValueError, TypeError):  # a kind sim does not know: keep its own message
            pass
    return changed


def _message_like(old: str, f, described: str) -> str:
    """The grown finding's message: sim's own wording for the kind (its ``describe``),
    except for kinds whose message is a sentence of their own (a rapid's volume)."""
    if f.kind == "rapid_into_stock" and not math.isnan(f.volume):
        where = f"line {f.line}" if len(f.lines) <= 1 else f"lines {f.lines[0]}-{f.lines[-1]}"
        return f"rapid (G0) into material at {where}: {f.volume:.3f} mm^3"
    return described


def _where(rec: dict) -> str:
    lines = rec.get("lines") or []
    if len(lines) > 1:
        return f"lines {lines[0]}-{lines[-1]}"
    return f"line {rec.get('line', '?')}"


def format_finding(f: dict) -> str:
    """One line for a person: kind, line, position, lead time (and why it is short, the
    record's ``lead_note``)."""
    lead = f.get("lead_time_s")
    when = "now" if lead is None or lead <= 0 else f"in {lead:.1f} s"
    pos = f.get("position") or []
    if f.get("kind") == "setup":  # no lead time: its message says what looks wrong, what to check
        return "SETUP: " + str(f.get("message", "")).removeprefix("setup: ")
    where = ", ".join(f"{v:.2f}" for v in pos) if pos else "?"
    size = ""
    if f.get("depth") is not None and f.get("kind") in ("gouge", "undercut"):
        size = f", {f['depth']:.3f} mm deep"
    if f.get("lead_note"):  # why the lead is short or 0: never silently
        when += f" ({f['lead_note']})"
    return f"{f.get('kind', '?').upper().replace('_', ' ')} line {f.get('line', '?')} at ({where}){size} — {when}"


def hold_message(f: dict, resume_how: str = RESUME_HOW) -> str:
    """The line said when dexmon held the feed for finding ``f``: what, why, how to go on."""
    return f"FEED HOLD sent by dexmon: {f.get('kind', '?')} at {_where(f)} {_when(f)}. To go on: {resume_how}"


def _when(f: dict) -> str:
    lead = f.get("lead_time_s")
    return "(now)" if lead is None or lead <= 0 else f"(predicted in {lead:.1f} s)"


class Alerter:
    """Emit each new finding once on every enabled channel.

    Parameters
    ----------
    console : rich.console.Console or None
        Where the terminal alert goes (None: no terminal alerts).
    json_stream : text stream or None
        Where JSON lines go (one object per finding, ``"event": "finding"``).
    bell : bool
        Ring the terminal bell on a new finding (through ``console``).
    feed_hold : callable or None
        Called (no arguments) on a new finding of a :data:`HOLD_KINDS` kind; None when the
        job did not enable feed hold.
    run : monitor.runfile.RunWriter or None
        Findings and alerts are appended to it.
    radius : float
        mm within which two findings of one kind are the same finding.
    line_radius : float
        mm within which two findings of one kind sharing a program line are the same finding.
    resume_how : str
        How to go on after a feed hold, said with it (default :data:`RESUME_HOW`).
    propose : callable or None
        Called with each new *predicted* gouge; returns ``{"file", "lines", "message"}``
        of the corrected lines it wrote for the user (:mod:`monitor.propose`), said as a
        ``proposal`` record; never sends anything to the machine.
    """

    def __init__(self, console=None, json_stream: TextIO | None = None, bell: bool = False,
                 feed_hold: Callable[[], None] | None = None, run=None, radius: float = 5.0, line_radius: float = 25.0,
                 resume_how: str = RESUME_HOW, propose: Callable[[dict], dict | None] | None = None):
        self.console = console
        self.propose = propose
        self.json_stream = json_stream
        self.bell = bell
        self.feed_hold = feed_hold
        self.run = run
        self.radius = float(radius)
        self.line_radius = float(line_radius)
        self.resume_how = resume_how
        self.findings: list[dict] = []  # every alerted finding, in order
        self.holds_sent = 0
        #: the last hold dexmon sent, until the machine leaves it: {"id", "kind", "line",
        #: "t" (sent), "held_t" (seen held, or None)}; None when no hold is pending
        self.hold: dict | None = None
        # finding index -> move ids whose size its record already holds
        self._merged: dict[int, set] = {}
        # kind -> [[lines seen, points seen (m, 3), index in findings, move ids seen], ...]
        self._by_kind: dict[str, list[list]] = {}

    def match(self, f: dict) -> int | None:
        """Index in :attr:`findings` of the alerted finding ``f`` repeats, or None when new.

        Same kind and: made by the same move (a shared ``stages`` id), or naming the same
        cause (``detail["cause"]``: the spindle off since one line), or a region whose XY
        box (``detail["box"]``) comes within ``radius`` mm of that finding's, or within
        ``radius`` mm of any point where that finding was seen, or within ``line_radius``
        mm while sharing a program line. A finding that keeps being seen as the tool moves
        (a long gouge) is followed along: every repeat adds its point, lines and moves.
        """
        lines = frozenset(f.get("lines") or ()) | {f.get("line", 0)}
        stages = _stages(f)
        pos = _pos(f)
        known = bool(np.all(np.isfinite(pos)))
        detail = f.get("detail") or {}
        for seen_lines, seen_pos, idx, seen_stages in self._by_kind.get(f.get("kind", ""), ()):
            if stages & seen_stages:
                return idx
            seen = self.findings[idx].get("detail") or {}
            if detail.get("cause") is not None and detail.get("cause") == seen.get("cause"):
                return idx
            if _boxes_near(detail.get("box"), seen.get("box"), self.radius):
                return idx
            pts = seen_pos[np.all(np.isfinite(seen_pos), axis=1)] if known else seen_pos[:0]
            dist = float(np.min(np.linalg.norm(pts - pos, axis=1))) if pts.shape[0] else 0.0
            if dist <= self.radius or (seen_lines & lines and dist <= self.line_radius):
                return idx
        return None

    def is_new(self, f: dict) -> bool:
        """True when no alerted finding of the same kind shares a line with ``f`` within ``radius``."""
        return self.match(f) is None

    def offer(self, findings, t: float | None = None) -> list[dict]:
        """Alert the new ones among ``findings`` (dicts); return those alerted.

        A repeat of an alerted finding is not alerted again. When the repeat comes from
        the real motion (``predicted`` false) and the alerted finding was only predicted,
        that finding's record becomes ``status = "happened"`` (with ``happened_t`` and
        ``happened_position``), in memory and in the run file, and a ``finding_update``
        JSON line says so -- still one alert.
        """
        fresh = []
        for f in findings:
            idx = self.match(f)
            if idx is not None:
                self._follow(f, idx, t)
                continue
            lines = frozenset(f.get("lines") or ()) | {f.get("line", 0)}
            idx = len(self.findings)
            self._by_kind.setdefault(f.get("kind", ""), []).append([lines, _pos(f)[None, :], idx, _stages(f)])
            self.findings.append(f)
            fresh.append(f)
            self._emit(f, idx + 1, t)
        return fresh

    def _follow(self, f: dict, idx: int, t) -> None:
        """Grow the alerted finding ``idx`` by its repeat ``f``: its record takes the
        repeat's lines and (when the repeat measured new material, :func:`grow_record`)
        its size, and says so in the run file and the JSON stream."""
        for entry in self._by_kind.get(f.get("kind", ""), ()):
            if entry[2] == idx:
                if entry[1].shape[0] < MAX_TRACK_POINTS:
                    entry[1] = np.concatenate([entry[1], _pos(f)[None, :]])
                entry[0] = entry[0] | frozenset(f.get("lines") or ()) | {f.get("line", 0)}
                entry[3] = entry[3] | _stages(f)
                break
        rec = self.findings[idx]
        lines_before = set(rec.get("lines") or ())
        before = {k: rec.get(k) for k in UPDATE_KEYS + ("line_range", "lines_total")}
        grew = grow_record(rec, f, self._merged.setdefault(idx, set(_stages(rec))))
        box, new_box = (rec.get("detail") or {}).get("box"), (f.get("detail") or {}).get("box")
        if box is not None and new_box is not None:  # the region's box grows with it
            rec["detail"] = {**rec["detail"], "box": [min(box[0], new_box[0]), min(box[1], new_box[1]),
                                                      max(box[2], new_box[2]), max(box[3], new_box[3])]}
        happened = not f.get("predicted", True) and rec.get("status", "predicted") == "predicted"
        if happened:
            rec["status"] = "happened"
            if t is not None:
                rec["happened_t"] = float(t)
            rec["happened_position"] = list(f.get("position") or [])
            rec["happened_line"] = f.get("line")
            if f.get("stage") is not None:
                rec["stage"] = f["stage"]  # the live stage it happened at
        if not (grew or happened):
            return
        if self.run is not None:
            self.run.update_finding(idx + 1, rec)
        if happened and self.console is not None:  # a note, not a second alert: no bell, no colour
            self.console.print(f"[dim]{_escape(rec.get('kind', '?').upper().replace('_', ' '))} "
                               f"{_escape(_where(rec))}: happened as predicted[/dim]", highlight=False)
        if self.json_stream is not None:
            # what changed (with the kind and status to read it by), never the whole record
            upd = {"event": "finding_update", "id": idx + 1, "kind": rec.get("kind"), "status": rec.get("status"),
                   **{k: rec[k] for k in before if k in rec and rec[k] != before[k]}}
            added = sorted(set(rec.get("lines") or ()) - lines_before)
            if added:
                upd["lines_added"] = added
            upd["t"] = t
            self.json_stream.write(json.dumps(upd, default=json_default) + "\n")
            self.json_stream.flush()

    def _emit(self, f: dict, finding_id: int, t) -> None:
        text = format_finding(f)
        if self.run is not None:
            self.run.append_finding(f, t=t)
        if self.console is not None:
            style = "bold red" if f.get("kind") != "undercut" else "yellow"
            self.console.print(f"[{style}]{_escape(text)}[/{style}]", highlight=False, soft_wrap=True)
            self._record("terminal", text, t, finding_id)
            if self.bell:
                self.console.bell()
                self._record("bell", "\a", t, finding_id)
        if self.json_stream is not None:
            self.json_stream.write(json.dumps({"event": "finding", **f}, default=json_default) + "\n")
            self.json_stream.flush()
            self._record("json", f.get("kind", ""), t, finding_id)
        if self.feed_hold is not None and f.get("kind") in HOLD_KINDS:
            self._hold(f, finding_id, t)
        if self.propose is not None and f.get("kind") == "gouge" and f.get("predicted"):
            try:
                got = self.propose(f)
            except Exception as exc:  # a proposal is a courtesy: it must never stop the monitor
                got = {"file": None, "lines": [], "message": f"no correction proposed for line {f.get('line')}: {exc}"}
            if got is not None:
                self._say({"event": "proposal", "id": finding_id, "line": f.get("line"), "t": t, **got}, "cyan",
                          "proposal", finding_id)

    def _hold(self, f: dict, finding_id: int, t) -> None:
        """Send the feed hold for finding ``f`` and say so at once on every channel."""
        rec = {"event": "feed_hold", "id": finding_id, "kind": f.get("kind"), "line": f.get("line"),
               "lead_time_s": f.get("lead_time_s"), "t": t}
        try:
            self.feed_hold()
        except Exception as exc:  # a failed hold must be said loudly, not crash the monitor
            msg = f"FEED HOLD FAILED: {exc}"
            if self.console is None and self.json_stream is None:
                print(msg, file=sys.stderr)
            self._say({**rec, "sent": False, "message": msg}, "bold red", "feed_hold", finding_id)
            return
        self.holds_sent += 1
        self.hold = {"id": finding_id, "kind": f.get("kind"), "line": f.get("line"), "t": t, "held_t": None,
                     "warned": False}
        self._say({**rec, "sent": True, "message": hold_message(f, self.resume_how), "resume": self.resume_how},
                  "bold red",
                  "feed_hold", finding_id)

    def follow_state(self, state) -> None:
        """Follow the machine after dexmon's feed hold (call with every state): say when it
        leaves the hold ("resumed ... dexmon keeps monitoring", ``{"event": "resumed"}``),
        and once if it shows no hold :data:`HOLD_CONFIRM_S` controller seconds after it
        was sent (the controller ignored it: hold by hand)."""
        h = self.hold
        if h is None or not state.fresh:
            return
        if state.state == RunState.HOLD:
            if h["held_t"] is None:
                h["held_t"] = state.t
            return
        if h["held_t"] is None:
            if not h["warned"] and h["t"] is not None and state.t - h["t"] >= HOLD_CONFIRM_S:
                h["warned"] = True
                msg = (f"feed hold sent {state.t - h['t']:.1f} s ago for {h['kind']} at line {h['line']}, "
                       f"but the machine is not held (state {state.state.value}): hold it by hand")
                self._say({"event": "feed_hold_ignored", "id": h["id"], "t": state.t, "state": state.state.value,
                           "message": msg}, "bold red", "feed_hold", h["id"])
            return
        self.hold = None
        what = "resumed" if state.state == RunState.RUN else f"left the hold (now {state.state.value})"
        msg = (f"machine {what} after dexmon's feed hold for {h['kind']} at line {h['line']} "
               f"(held {state.t - h['held_t']:.1f} s); dexmon keeps monitoring")
        self._say({"event": "resumed", "id": h["id"], "t": state.t, "state": state.state.value,
                   "held_s": round(state.t - h["held_t"], 3), "message": msg}, "bold yellow", "feed_hold", h["id"])

    def _say(self, rec: dict, style: str, channel: str, finding_id: int | None) -> None:
        """One record on every channel: its ``message`` on the terminal, the record as a
        JSON line, the message in the run file's alerts (``channel``)."""
        if self.console is not None:
            self.console.print(f"[{style}]{_escape(rec['message'])}[/{style}]", highlight=False, soft_wrap=True)
        if self.json_stream is not None:
            self.json_stream.write(json.dumps(rec, default=json_default) + "\n")
            self.json_stream.flush()
        self._record(channel, rec["message"], rec.get("t"), finding_id)

    def _record(self, channel: str, text: str, t, finding_id: int) -> None:
        if self.run is not None:
            self.run.append_alert(channel, text, t=t, finding_id=finding_id)


def _stages(f: dict) -> frozenset:
    """Move ids (``moves``/``move``; records older than that: ``stages``/``stage``) of a
    finding; 0 (unknown) is left out."""
    if "move" in f or "moves" in f:
        got = f.get("moves") or ([f["move"]] if f.get("move") else [])
    else:
        got = f.get("stages") or ([f["stage"]] if f.get("stage") else [])
    return frozenset(int(x) for x in got if x)


def _boxes_near(a, b, gap: float) -> bool:
    """XY boxes ``[x0, y0, x1, y1]`` (mm) ``a`` and ``b`` within ``gap`` mm of each other
    (False when either is missing)."""
    if a is None or b is None:
        return False
    return (b[0] <= a[2] + gap and a[0] <= b[2] + gap and b[1] <= a[3] + gap and a[1] <= b[3] + gap)


def _pos(f: dict) -> np.ndarray:
    p = f.get("position")
    try:
        a = np.asarray(p, np.float64).reshape(3)
    except (TypeError, ValueError):
        a = np.full(3, math.nan)
    return a


def _escape(text: str) -> str:
    return text.replace("[", "\\[")
