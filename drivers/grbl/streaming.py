"""Sending program lines to GRBL: the character-counting protocol and its bookkeeping.

:class:`Streaming` is a mixin of :class:`drivers.grbl.driver.GrblController`: ``send``
one line when GRBL's RX buffer has room for it, ``command`` (send and wait for the
``ok``), ``stream`` a whole program (character counting or send-response). The reader
thread of the controller finishes each :class:`Command` with the ``ok``/``error:N`` that
acknowledges it. The monitor itself never streams: these serve tests, benchmarks and the
handshake's queries.

Lines go out without their comments (:func:`wire_text`), as real senders send them: GRBL's
serial interrupt takes ``!`` ``~`` ``?`` and Ctrl-X out of the byte stream wherever they
stand, so a ``(careful!)`` sent as written would feed-hold the machine.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable

from drivers.errors import ConnectionLost, DriverError
from drivers.grbl import protocol as p
from drivers.state import RunState


class GrblError(DriverError):
    """GRBL refused a line with ``error:N``."""

    def __init__(self, line: str, code: int):
        self.line = line
        self.code = code
        self.meaning = p.error_meaning(code)
        super().__init__(f"GRBL refused {line!r}: error:{code} ({self.meaning})")


class Command:
    """One line in GRBL's RX buffer awaiting its ``ok``/``error:N``.

    ``replies`` collects the lines GRBL printed before the acknowledgement (``$$``
    settings, ``[GC:...]`` ...). ``t_sent``/``t_done`` are ``time.monotonic()`` seconds.
    """

    __slots__ = ("text", "nbytes", "t_sent", "t_done", "replies", "result", "failure", "_done", "index")

    def __init__(self, text: str, index: int | None = None):
        self.text = text
        self.nbytes = len(text) + 1
        self.index = index
        self.t_sent = 0.0
        self.t_done = 0.0
        self.replies: list[p.Message] = []
        self.result: p.Message | None = None
        self.failure: DriverError | None = None
        self._done = threading.Event()

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def wait(self, timeout: float | None = None) -> list[p.Message]:
        """Wait for the acknowledgement; return the replies, raise GrblError on ``error:N``."""
        if not self._done.wait(timeout):
            raise DriverError(f"GRBL: no reply to {self.text!r} within {timeout:g} s")
        if self.failure is not None:
            raise self.failure
        if isinstance(self.result, p.Error):
            raise GrblError(self.text, self.result.code)
        return self.replies

    def _finish(self, result: p.Message | None, failure: DriverError | None, t: float) -> None:
        self.result, self.failure, self.t_done = result, failure, t
        self._done.set()


@dataclass
class StreamResult:
    """What happened to a streamed program.

    ``errors``: (index in ``lines``, line text, error code, meaning) per refused line.
    ``stopped``: why the stream stopped early (alarm, reset, connection lost) or None.
    """

    sent: int = 0
    acked: int = 0
    errors: list[tuple[int, str, int, str]] = field(default_factory=list)
    alarm: int | None = None
    stopped: str | None = None
    t_start: float = 0.0
    t_end: float = 0.0

    @property
    def completed(self) -> bool:
        return self.stopped is None


class Streaming:
    """Line sending for a GRBL controller (mixed into ``GrblController``, whose reader
    thread acknowledges the lines: it provides ``_cond``, ``_connected``, ``_pending``,
    ``_in_flight``, ``_write``, ``rx_size``, ``timeout``, ``port`` and the alarm and
    banner counters)."""

    def send(self, line: str, index: int | None = None, block: bool = True) -> Command:
        """Send one line under the character-counting protocol and return its :class:`Command`.

        Waits (up to ``timeout``) until the unacknowledged bytes plus this line fit in
        GRBL's RX buffer (``rx_size - 1`` bytes). Does not wait for the ``ok``. The line is
        sent as :func:`wire_text` makes it (no comments; DriverError for a real-time byte).
        """
        text = wire_text(line)
        try:
            data = (text + "\n").encode("ascii")
        except UnicodeEncodeError:
            raise DriverError(f"GRBL: line {text!r} is not ASCII") from None
        if len(data) > self.rx_size - 1:
            raise DriverError(f"GRBL: line {text!r} is {len(data)} bytes with newline; at most {self.rx_size - 1}")
        cmd = Command(text, index)
        with self._cond:
            ok = self._cond.wait_for(
                lambda: not self._connected or self._in_flight + cmd.nbytes <= self.rx_size - 1,
                self.timeout if block else 0,
            )
            if not self._connected:
                raise ConnectionLost(f"GRBL {self.port}: not connected; {text!r} not sent")
            if not ok:
                raise DriverError(f"GRBL: RX buffer still full after {self.timeout:g} s; {text!r} not sent")
            cmd.t_sent = time.monotonic()
            self._pending.append(cmd)
            self._in_flight += cmd.nbytes
            self.max_in_flight = max(self.max_in_flight, self._in_flight)
            try:
                self._write(data)
            except ConnectionLost:
                self._pending.remove(cmd)
                self._in_flight -= cmd.nbytes
                raise
        return cmd

    def command(self, line: str, timeout: float | None = None) -> list[p.Message]:
        """Send a line, wait for its ``ok`` and return the replies before it (raises GrblError).

        With no reply in time the line is taken as lost (its ``ok`` will not acknowledge
        the next line): DriverError. Not so while the machine is held (``Hold``, ``Door``,
        ``Sleep``): GRBL keeps the line unread in its RX buffer and answers it after cycle
        start, so it stays pending (its late reply is consumed, not given to the next line)."""
        cmd = self.send(line)
        wait = self.timeout if timeout is None else timeout
        try:
            return cmd.wait(wait)
        except DriverError:
            if cmd.failure is not None or cmd.done:
                raise
            with self._cond:
                held = _held_state(self.last_state)
                if held is None and cmd in self._pending:
                    self._pending.remove(cmd)
                    self._in_flight -= cmd.nbytes
            if held is None:
                raise
            raise DriverError(f"GRBL {self.port}: no reply to {cmd.text!r} within {wait:g} s: the machine is in "
                              f"{held}; GRBL answers the line after cycle start (~) or drops it on a reset") from None

    def stream(self, lines: Iterable[str], mode: str = "counting", timeout: float | None = None,
               on_ack: Callable[[Command], None] | None = None) -> StreamResult:
        """Stream a program; return what happened.

        ``mode`` ``"counting"`` keeps the RX buffer full (sum of unacknowledged line
        lengths ≤ ``rx_size - 1``); ``"send-response"`` sends a line only after the
        previous one was acknowledged. Comments are stripped (:func:`wire_text`; a line
        with a real-time byte outside them raises DriverError); blank and comment-only
        lines and ``%`` are not sent.
        Refused lines (``error:N``) are recorded and the stream goes on (as UGS does);
        an ``ALARM``, a reset or a lost connection stop it. ``timeout`` bounds the wait
        for each acknowledgement (a motion line's ``ok`` waits for planner room).
        """
        if mode not in ("counting", "send-response"):
            raise ValueError(f"stream mode must be 'counting' or 'send-response', got {mode!r}")
        wait = max(self.timeout, 30.0) if timeout is None else timeout
        res = StreamResult(t_start=time.monotonic())
        with self._cond:
            alarm0, banner0 = self._alarm_seq, self._banner_seq
        sent: list[Command] = []

        def collect(upto: int) -> None:
            # account acknowledgements of sent[:upto] in order
            while res.acked < upto and sent[res.acked].done:
                cmd = sent[res.acked]
                if cmd.failure is None:
                    res.acked += 1
                    if isinstance(cmd.result, p.Error):
                        res.errors.append((cmd.index, cmd.text, cmd.result.code, p.ERROR_MEANINGS.get(cmd.result.code, "")))
                    if on_ack is not None:
                        on_ack(cmd)
                else:
                    return

        def interrupted() -> str | None:
            if self._alarm_seq != alarm0:
                res.alarm = self._alarm
                return f"ALARM:{self._alarm}"
            if self._banner_seq != banner0:
                return "controller reset"
            if not self._connected:
                return "connection lost"
            return None

        for index, raw in enumerate(lines):
            text = clean_line(raw)
            if not text:
                continue
            cmd = Command(text, index)
            if len(text) + 1 > self.rx_size - 1:
                raise DriverError(f"GRBL: program line {index + 1} is {len(text) + 1} bytes; at most {self.rx_size - 1}")
            with self._cond:
                ok = self._cond.wait_for(
                    lambda: interrupted() is not None
                    or (self._in_flight + cmd.nbytes <= self.rx_size - 1
                        and (mode == "counting" or not self._pending)),
                    wait,
                )
                why = interrupted()
            if why is not None:
                res.stopped = why
                break
            if not ok:
                res.stopped = f"no acknowledgement within {wait:g} s"
                break
            try:
                sent.append(self.send(text, index))
            except ConnectionLost:
                res.stopped = "connection lost"
                break
            except DriverError as exc:
                res.stopped = str(exc)
                break
            res.sent += 1
            collect(len(sent))
        if res.stopped is None:
            with self._cond:
                self._cond.wait_for(lambda: interrupted() is not None or all(c.done for c in sent), wait)
                why = interrupted()
            if why is not None:
                res.stopped = why
            elif not all(c.done for c in sent):
                res.stopped = f"no acknowledgement within {wait:g} s"
        collect(len(sent))
        res.t_end = time.monotonic()
        return res


def _held_state(state) -> str | None:
    """``Hold:0`` / ``Door:1`` / ``Sleep`` when ``state`` (a MachineState or None) is one in
    which GRBL's main loop reads no line; else None."""
    if state is None or state.state not in (RunState.HOLD, RunState.DOOR, RunState.SLEEP):
        return None
    if state.substate is None:
        return state.state.value
    return f"{state.state.value}:{state.substate}"


#: bytes GRBL's serial interrupt acts on wherever they stand (serial.c): inside a line
#: they would hold, resume, report or reset instead of reaching the line buffer
_REALTIME_CHARS = "?!~\x18"


def strip_comments(raw: str) -> str:
    """``raw`` without its ``(...)`` and ``;...`` comments, read as GRBL's main loop reads
    a line: a ``;`` inside parentheses does not end the line, ``(`` runs to the next ``)``
    or to the end of the line."""
    out = []
    in_paren = False
    for ch in raw:
        if in_paren:
            in_paren = ch != ")"
        elif ch == "(":
            in_paren = True
        elif ch == ";":
            break
        else:
            out.append(ch)
    return "".join(out)


def wire_text(line: str) -> str:
    """The text sent for ``line``: no comments, control characters and runs of whitespace
    made one space (GRBL drops both, so the line means the same), no space at the ends.

    Raises DriverError when a real-time character (``? ! ~`` Ctrl-X) is left outside the
    comments, or a line end inside the line: sent, it would act at once or split the line
    (and the character count with it)."""
    if "\n" in line.strip("\r\n") or "\r" in line.strip("\r\n"):
        raise DriverError(f"GRBL: line {line!r} has a line end inside it")
    text = strip_comments(line.strip("\r\n"))
    bad = sorted({ch for ch in text if ch in _REALTIME_CHARS})
    if bad:
        raise DriverError(f"GRBL: line {line!r} has the real-time character(s) {bad} outside a comment: "
                          f"GRBL would act on them at once, not as part of the line")
    return " ".join("".join(" " if ch < " " else ch for ch in text).split())


def clean_line(raw: str) -> str:
    """A program line as it is sent (:func:`wire_text`); "" for blank, comment-only and
    '%' lines."""
    text = wire_text(raw)
    return "" if text.startswith("%") else text
