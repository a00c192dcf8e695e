"""What the browser view shows of a recorded run, stage by stage: heights, tool tip, line,
time, the program listing and the findings (read from a :class:`monitor.trace_io.RunView`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: lines of the listing the page shows around the current line
LISTING_BEFORE, LISTING_AFTER = 12, 28


@dataclass
class StageRow:
    """One recorded cut: its stage, controller time (s), program line, tool tip (3,) mm."""

    stage: int
    t: float
    line: int
    tip: np.ndarray


class RunModel:
    """A run file as the page needs it. ``view``: an open RunView (closed by the caller)."""

    def __init__(self, view):
        self.view = view
        self.first = view.first_stage
        self.last = view.last_stage
        self.frame = view.frame
        self.program_lines = (view.meta.get("program") or "").splitlines()
        # the same cuts, times and tips as the replay pictures: one stage table, times told
        # from the run's first recorded state
        from monitor.render.runpicture import run_start_time

        tab = view.stage_table
        self._stages, self._line, self._tips = tab["stage"], tab["line"], tab["p1"]
        self._t = tab["t"] - run_start_time(view)
        self.findings = [finding_item(i, f, self) for i, f in enumerate(view.findings)]

    def heights(self, stage: int) -> np.ndarray:
        """Top heights (nv, nu) float32 mm at ``stage`` (a buffer reused by the next call)."""
        return self.view.state_at(int(stage))[0]

    def _row(self, stage: int) -> int:
        """Index of the last recorded cut at or before ``stage`` (-1: before the first)."""
        return int(np.searchsorted(self._stages, stage, side="right")) - 1

    def at(self, stage: int) -> StageRow:
        """Line, time and tip at ``stage`` (line -1, time NaN, tip NaN before the first cut)."""
        k = self._row(stage)
        if k < 0:
            return StageRow(int(stage), float("nan"), -1, np.full(3, np.nan))
        return StageRow(int(stage), float(self._t[k]), int(self._line[k]), self._tips[k])

    def stage_of_line(self, line: int) -> int | None:
        """The first stage cut on program line ``line``, or on the next line cut after it;
        None when no cut comes at or after it."""
        if not self._line.size:
            return None
        at = np.nonzero(self._line == line)[0]
        if at.size:
            return int(self._stages[at[0]])
        after = np.nonzero(self._line > line)[0]
        return int(self._stages[after[0]]) if after.size else None

    def listing_around(self, line: int) -> list[dict]:
        """Numbered program lines around ``line`` (1-based): ``{"n", "text", "current"}``."""
        return listing_window(self.program_lines, line)

    def row(self, stage: int) -> int | None:
        """The move-table row cut at ``stage`` (None before the first cut)."""
        move_id = self.view.stage_info(int(stage)).get("move_id", 0)
        return move_id - 1 if move_id > 0 else None

    def tool(self):
        """The run's first tool (sim Tool), or None when the run file does not say it."""
        return self.view.tool()

    @property
    def moves(self):
        return self.view.moves


def listing_window(lines: list[str], line: int) -> list[dict]:
    """``lines`` (the program) numbered from 1, the window around ``line`` the page shows."""
    centre = max(1, int(line))
    lo = max(1, centre - LISTING_BEFORE)
    hi = min(len(lines), max(lo + LISTING_BEFORE + LISTING_AFTER, centre + LISTING_AFTER))
    return [{"n": n, "text": lines[n - 1], "current": n == line} for n in range(lo, hi + 1)]


def finding_item(i: int, f: dict, model: RunModel | None = None) -> dict:
    """A finding as the page lists it: index, kind, line, the stage it happened at (or the
    first stage of its line), position, its label in the 3-D view and one sentence."""
    from monitor.commands.replay import format_finding
    from monitor.render.live import finding_label

    stage = f.get("stage")
    if not isinstance(stage, int) and model is not None and isinstance(f.get("line"), int):
        stage = model.stage_of_line(f["line"])
    pos = f.get("position")
    return {"i": i, "kind": str(f.get("kind", "finding")), "line": f.get("line"),
            "stage": stage if isinstance(stage, int) else None,
            "position": [float(x) for x in pos[:3]] if isinstance(pos, list) and len(pos) >= 3 else None,
            "predicted": f.get("status") == "predicted", "label": finding_label(f), "text": format_finding(f)}
