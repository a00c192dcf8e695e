"""The live status line shown in a terminal: state, position, line, progress, findings.

Drawn with ``rich.live.Live`` (refreshed at most ``refresh_hz`` times a second, whatever the
poll rate), so alerts printed through the same console scroll above it. Off when the
output is not a terminal or ``--quiet``/``--json`` was given.
"""

from __future__ import annotations

import time

from rich.console import Console
from rich.live import Live
from rich.text import Text


def status_text(state, sync, duration: float, n_findings: int, latency_ms: float | None = None,
                note: str = "") -> Text:
    """One line: run state, work position, program line, progress %, findings (, latency),
    and ``note`` when there is one ("lost 30 s, retrying")."""
    st = getattr(getattr(state, "state", None), "value", "?")
    wpos = getattr(state, "wpos", (float("nan"),) * 3)
    line = "?" if sync is None else sync.line
    pct = 0.0 if sync is None or duration <= 0 else min(100.0, 100.0 * sync.progress / duration)
    colour = {"Run": "green", "Hold": "yellow", "Alarm": "bold red", "Idle": "cyan", "Disconnected": "bold red",
              "Missed": "yellow", "Bad": "yellow"}.get(st, "white")
    t = Text()
    t.append(f"{st:<6}", style=colour)
    t.append(f"  X{wpos[0]:9.3f} Y{wpos[1]:9.3f} Z{wpos[2]:9.3f}")
    t.append(f"  line {line:>6}  {pct:5.1f}%")
    t.append(f"  findings {n_findings}", style="bold red" if n_findings else "")
    if sync is not None and sync.how in ("lost", "search"):
        t.append(f"  sync {sync.how}", style="yellow")
    if latency_ms is not None:
        t.append(f"  {latency_ms:5.1f} ms", style="dim")
    if note:
        t.append(f"  {note}", style="bold yellow")
    return t


class StatusLine:
    """A single refreshing line; a no-op when ``enabled`` is False."""

    def __init__(self, console: Console | None, enabled: bool = True, refresh_hz: float = 8.0):
        self.console = console
        self.enabled = bool(enabled and console is not None and console.is_terminal)
        self.period = 1.0 / refresh_hz
        self._live: Live | None = None
        self._last = 0.0

    def start(self) -> "StatusLine":
        if self.enabled and self._live is None:
            self._live = Live(Text(""), console=self.console, auto_refresh=False, transient=True)
            self._live.start()
        return self

    def update(self, state, sync, duration: float, n_findings: int, latency_ms: float | None = None,
               force: bool = False, note: str = "") -> None:
        if self._live is None:
            return
        now = time.monotonic()
        if not force and now - self._last < self.period:
            return
        self._last = now
        self._live.update(status_text(state, sync, duration, n_findings, latency_ms, note), refresh=True)

    def stop(self) -> None:
        if self._live is not None:
            self._live.stop()
            self._live = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
        return False
