"""The live status line: state, work position, line, progress, findings, the next predicted
finding's countdown, the step's latency.

On a terminal it is one line drawn with ``rich.live.Live`` (refreshed at most ``refresh_hz``
times a second, whatever the poll rate), so alerts printed through the same console scroll
above it. With the output piped (a log) it becomes a plain progress line every
``progress_every`` s instead, so the log shows the run is alive. Off with ``--quiet`` or
``--json`` (no console).
"""

from __future__ import annotations

import time
from typing import Callable

from rich.console import Console
from rich.live import Live
from rich.text import Text

#: with the output piped, a progress line this often (s, wall clock)
PROGRESS_EVERY_S = 5.0

_COLOURS = {"Run": "green", "Hold": "yellow", "Alarm": "bold red", "Idle": "cyan", "Disconnected": "bold red",
            "Missed": "yellow", "Bad": "yellow"}


def next_finding(findings, row_t0, progress: float, feed_override: float = 100.0) -> str:
    """The countdown to the next predicted finding the spindle has not reached:
    ``"next: gouge line 22 in 4.2 s"``, or "" when none is ahead.

    ``findings``: alerted finding records (``move`` = program row + 1, ``status``);
    ``row_t0`` float (n,): program s at which each row starts; ``progress``: program s
    now; the time left is scaled by the feed override (%), as lead times are."""
    scale = 100.0 / feed_override if feed_override and feed_override > 0 else 1.0
    best = None
    for f in findings:
        row = int(f.get("move") or 0) - 1
        if f.get("status", "predicted") != "predicted" or not 0 <= row < len(row_t0):
            continue
        left = float(row_t0[row]) - progress
        if left > 0 and (best is None or left < best[0]):
            best = (left, f)
    if best is None:
        return ""
    left, f = best
    return f"next: {f.get('kind', '?').replace('_', ' ')} line {f.get('line', '?')} in {left * scale:.1f} s"


def _progress_pct(sync, duration: float) -> float:
    return 0.0 if sync is None or duration <= 0 else min(100.0, 100.0 * sync.progress / duration)


def status_text(state, sync, duration: float, n_findings: int, latency_ms: float | None = None,
                note: str = "", upcoming: str = "") -> Text:
    """One line, every figure labelled: ``state Run  work X 1.000 Y 2.000 Z 3.000  line 22
    progress 45.0 %  findings 1  next: gouge line 22 in 4.2 s  latency 2.1 ms`` and
    ``note`` when there is one ("lost 30 s, retrying")."""
    st = getattr(getattr(state, "state", None), "value", "?")
    wpos = getattr(state, "wpos", (float("nan"),) * 3)
    line = "?" if sync is None else sync.line
    t = Text()
    t.append("state ")
    t.append(f"{st:<6}", style=_COLOURS.get(st, "white"))
    t.append(f"  work X{wpos[0]:9.3f} Y{wpos[1]:9.3f} Z{wpos[2]:9.3f}")
    t.append(f"  line {line:>6}  progress {_progress_pct(sync, duration):5.1f} %")
    t.append(f"  findings {n_findings}", style="bold red" if n_findings else "")
    if upcoming:
        t.append(f"  {upcoming}", style="bold red")
    if sync is not None and sync.how in ("lost", "search"):
        t.append(f"  sync {sync.how}", style="yellow")
    if latency_ms is not None:
        t.append(f"  latency {latency_ms:5.1f} ms", style="dim")
    if note:
        t.append(f"  {note}", style="bold yellow")
    return t


def progress_line(state, sync, duration: float, n_findings: int, note: str = "", upcoming: str = "") -> str:
    """The piped output's progress line: ``progress: state Run, line 22, 45.0 %, findings 1,
    next: gouge line 22 in 4.2 s``."""
    st = getattr(getattr(state, "state", None), "value", "?")
    parts = [f"state {st}", f"line {'?' if sync is None else sync.line}",
             f"{_progress_pct(sync, duration):.1f} %", f"findings {n_findings}"]
    parts += [x for x in (upcoming, note) if x]
    return "progress: " + ", ".join(parts)


class StatusLine:
    """The status: a refreshing line on a terminal, a progress line every ``progress_every``
    s (``clock`` s) when the console is not a terminal; a no-op when ``enabled`` is False
    or there is no console."""

    def __init__(self, console: Console | None, enabled: bool = True, refresh_hz: float = 8.0,
                 progress_every: float = PROGRESS_EVERY_S, clock: Callable[[], float] = time.monotonic):
        on = bool(enabled and console is not None)
        self.console = console
        self.enabled = on and console.is_terminal
        self.logging = on and not console.is_terminal and progress_every > 0
        self.period = 1.0 / refresh_hz
        self.progress_every = float(progress_every)
        self.clock = clock
        self._live: Live | None = None
        self._last: float | None = None

    def start(self) -> "StatusLine":
        if self.enabled and self._live is None:
            self._live = Live(Text(""), console=self.console, auto_refresh=False, transient=True)
            self._live.start()
        return self

    def update(self, state, sync, duration: float, n_findings: int, latency_ms: float | None = None,
               force: bool = False, note: str = "", upcoming: str | Callable[[], str] = "") -> None:
        """Show the figures (at most ``refresh_hz`` times a second on a terminal, every
        ``progress_every`` s in a log). ``upcoming``: the countdown text, or a callable
        giving it (only called when the line is drawn)."""
        if self._live is None and not self.logging:
            return
        now = self.clock()
        every = self.period if self._live is not None else self.progress_every
        if not force and self._last is not None and now - self._last < every:
            return
        self._last = now
        nxt = upcoming() if callable(upcoming) else upcoming
        if self._live is not None:
            self._live.update(status_text(state, sync, duration, n_findings, latency_ms, note, nxt), refresh=True)
        else:
            self.console.print(progress_line(state, sync, duration, n_findings, note, nxt), highlight=False,
                               soft_wrap=True, markup=False)

    def stop(self) -> None:
        if self._live is not None:
            self._live.stop()
            self._live = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False
