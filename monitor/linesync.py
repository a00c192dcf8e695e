"""Where the machine is in the program, from the lines a G-code sender streams.

Behind a passthrough (:class:`drivers.grbl.passthrough.Passthrough`) the monitor sees every
line the user's sender streams and GRBL's ``ok``/``error:N`` for it. That bounds the line
the machine executes:

* it was sent (the machine never runs ahead of the stream), and it was not refused;
* GRBL acknowledges a motion line once its block is in the planner, so the executing
  block is among the last ``occupied`` acknowledged motion lines (``Bf:`` tells how many
  planner blocks are in use; an arc fills several, which only widens the window) or a line
  still in flight;
* with ``Ln:`` (firmware built with line numbers and a sender adding N words) the line is
  known exactly.

:class:`StreamedLines` maps each streamed line to the program's source line (in order,
text compared after removing comments, spaces, N words and number formatting, so a sender
that strips comments or rewrites ``X68`` as ``X68.000`` still matches), and for every
state picks, among the lines of that window, the one the tool tip is on. The session hands
that line to :class:`monitor.sync.ProgramSync` (line sync); with no window (nothing
streamed, or a program other than the job's) it returns the controller's own line, and
position sync does the rest.
"""

from __future__ import annotations

import re

import numpy as np

from drivers.state import MachineState, RunState
from sim.gcode.moves import MoveKind

#: program lines searched ahead of the last match for the next streamed line
MATCH_WINDOW = 400
#: planner blocks assumed in use when the controller does not report ``Bf:`` (GRBL's planner)
DEFAULT_PLANNER_BLOCKS = 16
#: the smallest planner size assumed when ``Bf:`` is reported (GRBL 1.1: 15 free blocks
#: when empty, 14 with line numbers): the monitor may start while the planner is full
MIN_PLANNER_BLOCKS = 15
#: streamed lines searched back for the N word of ``Ln:``
LN_LOOKBACK = 256

_COMMENT = re.compile(r"\([^)]*\)|;.*$")
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
_N_WORD = re.compile(r"^N\d+")
_MOTION = (MoveKind.RAPID, MoveKind.FEED, MoveKind.ARC_CW, MoveKind.ARC_CCW, MoveKind.PROBE, MoveKind.DWELL)


def normalise(text: str) -> str | None:
    """A G-code line reduced to what the controller executes: comments, spaces and the N
    word removed, upper case, numbers in one format (``X68`` == ``x 68.000``). None for a
    line that executes nothing (empty, comment only) or is not G-code (``$``, ``%``)."""
    s = _COMMENT.sub("", text.upper()).replace(" ", "").replace("\t", "").strip()
    s = _N_WORD.sub("", s)
    if not s or s[0] in "$%":
        return None
    words = _WORD.findall(s)
    if "".join(a + b for a, b in words) != s:  # expressions, parameters: compare as text
        return s
    return " ".join(f"{a}{float(b):.4f}" for a, b in words)


class StreamedLines:
    """Follow a sender's stream through the program (see the module docstring).

    Parameters
    ----------
    controller : has ``learned_lines`` (list of objects with ``text``, ``n``, ``result``,
        appended in stream order, e.g. ``Passthrough.lines``) and ``last_state``.
    program_text : the job's program source (line ``k`` of the file is ``splitlines()[k-1]``).
    moves : MOVE_DTYPE (n,) the program's move table (its ``line`` column is the source line).
    """

    def __init__(self, controller, program_text: str, moves: np.ndarray):
        self.controller = controller
        self.source = [normalise(t) for t in program_text.splitlines()]
        lines = np.asarray(moves["line"], np.int64)
        moving = np.isin(moves["kind"], _MOTION)
        self.motion_lines = set(lines[moving].tolist())
        self.last_line = int(lines.max()) if lines.size else 0
        self._unique: dict[str, int] = {}
        seen: dict[str, int] = {}
        for k, t in enumerate(self.source):
            if t is not None:
                seen[t] = seen.get(t, 0) + 1
                self._unique.setdefault(t, k + 1)
        self._unique = {t: ln for t, ln in self._unique.items() if seen[t] == 1}
        self.mapped: list[int | None] = []   # per streamed line: program line (1-based) or None
        self._cursor = 0                      # index in ``source`` to match the next line from
        self._capacity = 0                    # most free planner blocks seen (= the planner's size)
        self._floor = 0                       # streamed index the machine is at least at
        self._seg_order: np.ndarray | None = None
        self.last_window: tuple[int, int] | None = None   # (lo, hi) streamed indices, for tests

    # -- mapping streamed lines to program lines
    def _map_new(self) -> list:
        learned = self.controller.learned_lines
        for k in range(len(self.mapped), len(learned)):
            self.mapped.append(self._match(normalise(learned[k].text)))
        return learned

    def _match(self, t: str | None) -> int | None:
        if t is None:
            return None
        src = self.source
        for k in range(self._cursor, min(self._cursor + MATCH_WINDOW, len(src))):
            if src[k] == t:
                self._cursor = k + 1
                return k + 1
        ln = self._unique.get(t)  # a jump (the sender started mid-program): only if unambiguous
        if ln is not None:
            self._cursor = ln
        return ln

    # -- the window of lines the machine may be executing
    def window(self, state: MachineState) -> list[int]:
        """Program lines (1-based, in stream order) the machine may be executing now."""
        learned = self._map_new()
        n = len(learned)
        if n == 0:
            return []
        ok = [k for k in range(self._floor, n)
              if self.mapped[k] in self.motion_lines and learned[k].result in (None, "ok")]
        if not ok:
            return []
        acked = [k for k in ok if learned[k].result == "ok"]
        in_flight = [k for k in ok if learned[k].result is None]
        if state.buffer is not None:
            free = int(state.buffer[0])
            self._capacity = max(self._capacity, free, MIN_PLANNER_BLOCKS)
            occupied = max(self._capacity - free, 0)
        else:
            occupied = DEFAULT_PLANNER_BLOCKS
        # an empty planner: the machine stands at the end of the newest acknowledged line
        keep = acked[-max(occupied, 1):] + in_flight
        if not keep:
            return []
        self.last_window = (keep[0], keep[-1])
        # the lines before the window ran to their end (the planner only shrinks from its
        # tail): never look at them again
        self._floor = keep[0]
        return [self.mapped[k] for k in keep]

    def line_for(self, state: MachineState, tip: np.ndarray, sync) -> int | None:
        """The program line to sync on for ``state`` with the tool ``tip`` (3,) mm work
        coordinates, given ``sync`` (a :class:`monitor.sync.ProgramSync`); the state's own
        line when the stream says nothing."""
        learned = self._map_new()
        if state.line is not None:
            # Ln: is the N word of the executing block: the newest streamed line with it
            for k in range(len(learned) - 1, max(len(learned) - LN_LOOKBACK, 0) - 1, -1):
                if learned[k].n == state.line and self.mapped[k] is not None:
                    return self.mapped[k]
        if state.state in (RunState.DISCONNECTED, RunState.ALARM):
            return state.line
        cands = self.window(state)
        if not cands:
            return state.line
        got = self._nearest(np.asarray(tip, np.float64)[:sync.path.p0.shape[1]], cands, sync)
        return state.line if got is None else got

    def _nearest(self, tip: np.ndarray, cands: list[int], sync) -> int | None:
        path = sync.path
        if self._seg_order is None:
            seg_lines = path.lines[path.row]
            self._seg_order = np.argsort(seg_lines, kind="stable")
            self._seg_sorted = seg_lines[self._seg_order]
        lines = np.unique(np.asarray(cands, np.int64))
        a = np.searchsorted(self._seg_sorted, lines, side="left")
        b = np.searchsorted(self._seg_sorted, lines, side="right")
        if not np.any(b > a):
            return None
        segs = np.concatenate([self._seg_order[i:j] for i, j in zip(a, b)])
        dist, prog = path.project_segments(tip, segs)
        if dist.min() > sync.lost:
            return None  # not on any line of the window: leave it to position sync
        # the earliest match within the noise band that is not behind the progress (a
        # retract up its own plunge is the retract, not the plunge)
        near = dist <= dist.min() + sync.noise
        if sync.progress is not None:
            ahead = near & (prog >= sync.progress - sync.back)
            if ahead.any():
                near = ahead
        idx = np.nonzero(near)[0]
        k = idx[np.argmin(prog[idx])]
        return int(path.lines[path.row[segs[k]]])

    def finished(self) -> bool:
        """The sender streamed the program's last line, the controller answered it
        (``ok`` or ``error:N``), and the machine stands idle: the job is over.

        A line whose answer went with the link (``"lost"``) or with a reset (``"reset"``)
        is not answered: the machine may never have run it, and the sender may send it
        again."""
        learned = self._map_new()
        done = any(self.mapped[k] == self.last_line and _answered(learned[k].result)
                   for k in range(len(learned) - 1, max(len(learned) - 8, 0) - 1, -1))
        state = getattr(self.controller, "last_state", None)
        return bool(done and state is not None and state.state == RunState.IDLE)


def _answered(result: str | None) -> bool:
    """True when ``result`` is the controller's own answer to a line (``ok``/``error:N``)."""
    return result is not None and (result == "ok" or result.startswith("error:"))
