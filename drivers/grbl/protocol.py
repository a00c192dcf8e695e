"""GRBL 1.1 wire protocol as pure functions: lines in, messages out.

Nothing here touches a port. :class:`LineAssembler` turns arbitrary byte chunks into
text lines; :func:`parse_line` turns one line into a :class:`Message`. What the messages mean in mm
(:class:`drivers.state.MachineState`, units, offsets, limits) is :mod:`.readings`.

Facts the parsers rely on (Grbl 1.1h, grblHAL):

* every line ends with ``\\r\\n``; a reply is ``ok`` or ``error:N``; pushes are
  ``<...>`` status reports, ``ALARM:N``, ``[TAG:...]`` feedback and the banner;
* a status report's fields are ``|``-separated, first the state (``Hold:0``), then
  ``MPos:`` or ``WPos:``, then optional ``Bf: Ln: FS:|F: Pn: WCO: Ov: A:`` (grblHAL adds
  more, kept verbatim in :attr:`StatusReport.extra`);
* ``WCO:`` comes only every 10th-30th report, ``Ov:`` (and ``A:`` with it) every
  10th-20th: :func:`drivers.grbl.readings.status_to_state` carries them over.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from drivers.errors import ProtocolError
from drivers.state import MAX_REPORTED_INT, RunState

# --------------------------------------------------------------------------------------
# Real-time bytes (sent alone, never followed by a newline; GRBL acts on them at once)
# --------------------------------------------------------------------------------------

RT_STATUS = b"?"
RT_FEED_HOLD = b"!"
RT_CYCLE_START = b"~"
RT_SOFT_RESET = b"\x18"
RT_SAFETY_DOOR = b"\x84"
RT_JOG_CANCEL = b"\x85"
RT_FEED_OV_RESET = b"\x90"
RT_FEED_OV_COARSE_PLUS = b"\x91"
RT_FEED_OV_COARSE_MINUS = b"\x92"
RT_FEED_OV_FINE_PLUS = b"\x93"
RT_FEED_OV_FINE_MINUS = b"\x94"
RT_RAPID_OV_RESET = b"\x95"
RT_RAPID_OV_MEDIUM = b"\x96"
RT_RAPID_OV_LOW = b"\x97"
RT_SPINDLE_OV_RESET = b"\x99"
RT_SPINDLE_OV_COARSE_PLUS = b"\x9a"
RT_SPINDLE_OV_COARSE_MINUS = b"\x9b"
RT_SPINDLE_OV_FINE_PLUS = b"\x9c"
RT_SPINDLE_OV_FINE_MINUS = b"\x9d"
RT_SPINDLE_STOP = b"\x9e"
RT_FLOOD_TOGGLE = b"\xa0"
RT_MIST_TOGGLE = b"\xa1"

#: every byte GRBL takes out of the stream as a real-time command
REALTIME_BYTES = frozenset(
    b"?!~\x18" + bytes([0x84, 0x85]) + bytes(range(0x90, 0x98)) + bytes(range(0x99, 0x9F)) + bytes([0xA0, 0xA1])
)

#: GRBL's serial receive buffer, bytes (a counted stream keeps at most RX_BUFFER_SIZE - 1 in flight)
RX_BUFFER_SIZE = 128

#: override limits of Grbl 1.1 (config.h), percent
FEED_OV_MIN, FEED_OV_MAX = 10, 200
SPINDLE_OV_MIN, SPINDLE_OV_MAX = 10, 200
RAPID_OV_LEVELS = (100, 50, 25)

MM_PER_INCH = 25.4

# --------------------------------------------------------------------------------------
# Meanings (GRBL 1.1 interface docs, error_codes_en_US.csv / alarm_codes_en_US.csv)
# --------------------------------------------------------------------------------------

ERROR_MEANINGS: dict[int, str] = {
    1: "Expected command letter: G-code words consist of a letter and a value; letter was not found",
    2: "Bad number format: missing the expected G-code word value or numeric value format is not valid",
    3: "Invalid statement: '$' system command was not recognized or supported",
    4: "Value < 0: negative value received for an expected positive value",
    5: "Setting disabled: homing cycle is not enabled via settings",
    6: "Value < 3 usec: minimum step pulse time must be greater than 3 usec",
    7: "EEPROM read fail: using defaults; an EEPROM read failed, affected settings restored to defaults",
    8: "Not idle: '$' command cannot be used unless Grbl is IDLE",
    9: "G-code lock: G-code commands are locked out during alarm or jog state",
    10: "Homing not enabled: soft limits cannot be enabled without homing also enabled",
    11: "Line overflow: max characters per line exceeded; the line was not executed",
    12: "Step rate > 30 kHz: '$' setting value causes the step rate to exceed the maximum supported",
    13: "Check door: safety door detected as opened and door state initiated",
    14: "Line length exceeded: build info or startup line exceeds EEPROM line length limit; not stored",
    15: "Travel exceeded: jog target exceeds machine travel; jog command ignored",
    16: "Invalid jog command: jog command has no '=' or contains prohibited G-code",
    17: "Setting disabled: laser mode requires PWM output",
    20: "Unsupported command: unsupported or invalid G-code command found in block",
    21: "Modal group violation: more than one G-code command from the same modal group in block",
    22: "Undefined feed rate: feed rate has not yet been set or is undefined",
    23: "G-code command in block requires an integer value",
    24: "More than one G-code command that requires axis words found in block",
    25: "Repeated G-code word found in block",
    26: "No axis words found in block for G-code command or current modal state which requires them",
    27: "Line number value is invalid",
    28: "G-code command is missing a required value word",
    29: "G59.x work coordinate systems are not supported",
    30: "G53 only allowed with G0 and G1 motion modes",
    31: "Axis words found in block when no command or current modal state uses them",
    32: "G2 and G3 arcs require at least one in-plane axis word",
    33: "Motion command target is invalid",
    34: "Arc radius value is invalid",
    35: "G2 and G3 arcs require at least one in-plane offset word",
    36: "Unused value words found in block",
    37: "G43.1 dynamic tool length offset is not assigned to configured tool length axis",
    38: "Tool number greater than max supported value",
    # grblHAL additions seen in the wild
    39: "Value word conflict (grblHAL)",
    60: "SD card: failed to mount device (grblHAL)",
    79: "Emergency stop active (grblHAL)",
}

ALARM_MEANINGS: dict[int, str] = {
    1: "Hard limit triggered: machine position is likely lost due to sudden halt; re-homing is highly recommended",
    2: "Soft limit: G-code motion target exceeds machine travel; machine position safely retained; alarm may be unlocked",
    3: "Reset while in motion: Grbl cannot guarantee position, lost steps are likely; re-homing is highly recommended",
    4: "Probe fail: the probe is not in the expected initial state before starting the probe cycle",
    5: "Probe fail: probe did not contact the workpiece within the programmed travel",
    6: "Homing fail: reset during active homing cycle",
    7: "Homing fail: safety door was opened during active homing cycle",
    8: "Homing fail: cycle failed to clear limit switch when pulling off",
    9: "Homing fail: could not find limit switch within search distance",
    10: "Homing fail: second dual-axis limit switch failed to trigger (grblHAL: E-stop)",
    11: "Homing required (grblHAL)",
    12: "Limit switch engaged (grblHAL)",
}

SETTING_NAMES: dict[int, str] = {
    0: "step pulse, usec", 1: "step idle delay, msec", 2: "step port invert mask",
    3: "direction port invert mask", 4: "step enable invert", 5: "limit pins invert",
    6: "probe pin invert", 10: "status report mask", 11: "junction deviation, mm",
    12: "arc tolerance, mm", 13: "report inches", 20: "soft limits", 21: "hard limits",
    22: "homing cycle", 23: "homing dir invert mask", 24: "homing feed, mm/min",
    25: "homing seek, mm/min", 26: "homing debounce, msec", 27: "homing pull-off, mm",
    30: "max spindle speed, rpm", 31: "min spindle speed, rpm", 32: "laser mode",
    100: "X steps/mm", 101: "Y steps/mm", 102: "Z steps/mm",
    110: "X max rate, mm/min", 111: "Y max rate, mm/min", 112: "Z max rate, mm/min",
    120: "X acceleration, mm/s^2", 121: "Y acceleration, mm/s^2", 122: "Z acceleration, mm/s^2",
    130: "X max travel, mm", 131: "Y max travel, mm", 132: "Z max travel, mm",
}

#: Grbl 1.1h defaults (defaults.h, DEFAULTS_GENERIC) as the wire-facts observed them
DEFAULT_SETTINGS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
    20: 0, 21: 0, 22: 0, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
    100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}

PIN_NAMES = {"X": "X limit", "Y": "Y limit", "Z": "Z limit", "A": "A limit", "B": "B limit",
             "C": "C limit", "P": "probe", "D": "door", "H": "hold", "R": "soft reset",
             "S": "cycle start", "E": "E-stop", "T": "tool"}

SUBSTATE_MEANINGS = {
    ("Hold", 0): "hold complete, ready to resume",
    ("Hold", 1): "hold in progress, decelerating",
    ("Door", 0): "door closed, ready to resume",
    ("Door", 1): "machine stopped, door still ajar; cannot resume until closed",
    ("Door", 2): "door opened, hold (or parking retract) in progress",
    ("Door", 3): "door closed and resuming; restoring from park",
}

OFFSET_TAGS = ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92")


def error_meaning(code: int) -> str:
    """What GRBL's ``error:code`` means (``"unknown error code N"`` beyond the table)."""
    return ERROR_MEANINGS.get(code, f"unknown error code {code}")


def alarm_meaning(code: int) -> str:
    """What GRBL's ``ALARM:code`` means (``"unknown alarm code N"`` beyond the table)."""
    return ALARM_MEANINGS.get(code, f"unknown alarm code {code}")

# --------------------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Message:
    """One line GRBL sent. ``raw`` is the line as received (no line ending)."""

    raw: str


@dataclass(frozen=True)
class Ok(Message):
    """``ok``: the oldest unacknowledged line was accepted."""


@dataclass(frozen=True)
class Error(Message):
    """``error:N``: the oldest unacknowledged line was refused."""

    code: int = 0

    @property
    def meaning(self) -> str:
        return error_meaning(self.code)


@dataclass(frozen=True)
class Alarm(Message):
    """``ALARM:N`` pushed when the machine enters the alarm state."""

    code: int = 0

    @property
    def meaning(self) -> str:
        return alarm_meaning(self.code)


@dataclass(frozen=True)
class Banner(Message):
    """Welcome line after a reset: ``Grbl 1.1h ['$' for help]`` or grblHAL's."""

    firmware: str = "Grbl"
    version: str = ""


@dataclass(frozen=True)
class Feedback(Message):
    """``[MSG:text]`` (and any ``[TAG:text]`` this module has no richer type for)."""

    tag: str = "MSG"
    text: str = ""


@dataclass(frozen=True)
class ParserState(Message):
    """``[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]`` from ``$G``.

    ``words`` are the modal words in order; ``tool``/``feed``/``spindle`` their values.
    """

    words: tuple[str, ...] = ()
    tool: int | None = None
    feed: float | None = None
    spindle: float | None = None


@dataclass(frozen=True)
class Help(Message):
    """``[HLP:$$ $# $G ...]`` from ``$``."""

    commands: tuple[str, ...] = ()


@dataclass(frozen=True)
class Version(Message):
    """``[VER:1.1h.20190830:build info]`` from ``$I``."""

    version: str = ""
    info: str = ""


@dataclass(frozen=True)
class Options(Message):
    """``[OPT:VN,15,128]`` from ``$I``: option letters, planner blocks, RX buffer bytes."""

    codes: str = ""
    blocks: int | None = None
    rx_size: int | None = None
    extra: tuple[str, ...] = ()


@dataclass(frozen=True)
class Offset(Message):
    """One line of ``$#``: ``[G54:x,y,z]`` ... ``[G92:...]`` or ``[TLO:z]`` (mm or inch, as sent)."""

    name: str = ""
    values: tuple[float, ...] = ()


@dataclass(frozen=True)
class Probe(Message):
    """``[PRB:x,y,z:1]``: last probe position (machine coords) and whether it touched."""

    position: tuple[float, ...] = ()
    success: bool = False


@dataclass(frozen=True)
class Echo(Message):
    """``[echo:line]``: GRBL echoing the line it received (compile option)."""

    text: str = ""


@dataclass(frozen=True)
class Setting(Message):
    """``$N=value`` from ``$$`` (grblHAL may send non-numeric values: ``value`` is then NaN)."""

    number: int = 0
    value: float = 0.0
    text: str = ""


@dataclass(frozen=True)
class StartupLine(Message):
    """``$N0=G20 G54`` from ``$N``: a stored startup block."""

    index: int = 0
    text: str = ""


@dataclass(frozen=True)
class StartupResult(Message):
    """``>G54G20:ok`` / ``>G1:error:22``: a startup block run after reset, and its result."""

    text: str = ""
    ok: bool = True
    code: int | None = None


@dataclass(frozen=True)
class StatusReport(Message):
    """A ``<...>`` status report, field by field, in the units GRBL sent them.

    ``mpos``/``wpos``: exactly one is set (tuple of n axes); ``wco`` only when the report
    carried it; ``overrides``/``accessories`` only when the report carried ``Ov:``
    (``accessories`` is then ``""`` when ``A:`` was absent, meaning all off).
    """

    state: str = "Unknown"
    substate: int | None = None
    mpos: tuple[float, ...] | None = None
    wpos: tuple[float, ...] | None = None
    buffer: tuple[int, int] | None = None
    line: int | None = None
    feed: float | None = None
    spindle: float | None = None
    pins: str = ""
    wco: tuple[float, ...] | None = None
    overrides: tuple[int, int, int] | None = None
    accessories: str | None = None
    extra: tuple[tuple[str, str], ...] = field(default=())

    @property
    def run_state(self) -> RunState:
        return _STATES.get(self.state, RunState.UNKNOWN)


# --------------------------------------------------------------------------------------
# Line assembly
# --------------------------------------------------------------------------------------


class LineAssembler:
    """Turn byte chunks from a port into text lines, whatever the chunking and noise.

    * lines end at ``\\n`` (a ``\\r`` before it, or alone, is dropped: GRBL sends ``\\r\\n``);
    * bytes that are not printable ASCII (noise on a cable, a reset's garbage) are dropped
      and counted in :attr:`dropped`, never raising;
    * a line longer than ``max_line`` bytes is cut and counted in :attr:`overflows` (a
      stream with its newlines lost must not grow memory without bound);
    * blank lines are skipped.

    ``feed(chunk) -> list[str]`` returns the lines completed by ``chunk``.
    """

    def __init__(self, max_line: int = 1024):
        self.max_line = int(max_line)
        self._buf = bytearray()
        self.dropped = 0
        self.overflows = 0

    def feed(self, chunk: bytes) -> list[str]:
        lines: list[str] = []
        for piece in _split_keep(bytes(chunk)):
            if piece == b"\n":
                if self._buf:
                    lines.append(self._buf.decode("ascii"))
                    self._buf.clear()
                continue
            piece = piece.replace(b"\r", b"")  # the expected line ending, not noise
            clean = piece.translate(None, _NOISE)
            self.dropped += len(piece) - len(clean)
            room = self.max_line - len(self._buf)
            if len(clean) > room:
                # keep the head; the rest of this over-long line is noise
                self._buf += clean[:room]
                self.overflows += 1
                self.dropped += len(clean) - room
            else:
                self._buf += clean
        return lines

    @property
    def pending(self) -> bytes:
        """Bytes of an incomplete line held back until its newline arrives."""
        return bytes(self._buf)

    def reset(self) -> None:
        self._buf.clear()


#: bytes LineAssembler drops: control characters (but not newline) and everything >= 0x7F
_NOISE = bytes(b for b in range(256) if b < 0x20 or b >= 0x7F)


def _split_keep(chunk: bytes) -> list[bytes]:
    out: list[bytes] = []
    start = 0
    while True:
        i = chunk.find(b"\n", start)
        if i < 0:
            if start < len(chunk):
                out.append(chunk[start:])
            return out
        if i > start:
            out.append(chunk[start:i])
        out.append(b"\n")
        start = i + 1


# --------------------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------------------

_STATES = {s.value: s for s in RunState if s not in (RunState.UNKNOWN, RunState.DISCONNECTED)}
_STATES["Tool"] = RunState.HOLD  # grblHAL tool change state: motion held
_BANNER = re.compile(r"^(Grbl|GrblHAL|grblHAL|Grbl_ESP32|FluidNC)\s+v?(\d+\.\d+[A-Za-z]*)\b(.*)$")
_INT = re.compile(r"^[+-]?\d+$")
_NUM = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)$")


#: sane ranges of the integers GRBL reports (Grbl 1.1h keeps them in uint8/int32; grblHAL
#: goes further for line numbers and buffers): beyond them a line is garbage, not a state
CODE_RANGE = (0, 255)              # error:N, ALARM:N (uint8 in the firmware)
SUBSTATE_RANGE = (0, 9)            # Hold:0..1, Door:0..3 (grblHAL adds a few)
OVERRIDE_RANGE = (0, 255)          # Ov: percent (Grbl 1.1h: 10..200, rapid 25..100)
COUNT_RANGE = (0, MAX_REPORTED_INT)  # Ln:, Bf:, [OPT:] sizes, T, $N


def _number(text: str, what: str, raw: str) -> float:
    text = text.strip()
    if not _NUM.match(text):
        raise ProtocolError(f"GRBL {what}: expected a number, got {text!r} in {raw!r}", raw)
    value = float(text)
    if not math.isfinite(value):  # hundreds of digits overflow to inf
        raise ProtocolError(f"GRBL {what}: {text[:20]!r}... is too long to be a number GRBL prints, in {raw[:80]!r}",
                            raw)
    return value


def _integer(text: str, what: str, raw: str, bounds: tuple[int, int] = (-MAX_REPORTED_INT, MAX_REPORTED_INT)) -> int:
    text = text.strip()
    if not _INT.match(text):
        raise ProtocolError(f"GRBL {what}: expected an integer, got {text!r} in {raw!r}", raw)
    lo, hi = bounds
    if len(text) > 12 or not lo <= int(text) <= hi:  # the length test spares int() of a megabyte of digits
        raise ProtocolError(f"GRBL {what}: expected an integer in {lo}..{hi}, got {text[:24]!r} in {raw[:80]!r}", raw)
    return int(text)


def _vector(text: str, what: str, raw: str, n_min: int = 1, n_max: int = 6) -> tuple[float, ...]:
    parts = text.split(",")
    if not n_min <= len(parts) <= n_max:
        raise ProtocolError(
            f"GRBL {what}: expected {n_min}..{n_max} comma-separated numbers, got {text!r} in {raw!r}", raw
        )
    return tuple(_number(p, what, raw) for p in parts)


def parse_line(text: str) -> Message:
    """Parse one line GRBL sent (without its line ending) into a :class:`Message`.

    Raises :class:`drivers.errors.ProtocolError` naming the offending text when the line
    is none of GRBL 1.1's forms or a known form is malformed. Only ``ProtocolError``.
    """
    raw = text
    line = text.strip()
    if not line:
        raise ProtocolError("GRBL: empty line", raw)
    if line == "ok":
        return Ok(raw)
    head = line[0]
    if head == "<":
        return parse_status(line)
    if head == "[":
        return _parse_bracket(line)
    if line.startswith("error:"):
        return Error(raw, _integer(line[6:], "error code", raw, CODE_RANGE))
    if line.startswith("ALARM:"):
        return Alarm(raw, _integer(line[6:], "alarm code", raw, CODE_RANGE))
    if head == "$":
        return _parse_dollar(line)
    if head == ">":
        return _parse_startup_result(line)
    m = _BANNER.match(line)
    if m:
        firmware = "grblHAL" if m.group(1).lower() == "grblhal" else m.group(1)
        return Banner(raw, firmware, m.group(2))
    raise ProtocolError(f"GRBL: unrecognised line {raw!r}", raw)


def _parse_bracket(line: str) -> Message:
    raw = line
    if not line.endswith("]") or ":" not in line:
        raise ProtocolError(f"GRBL feedback: expected [TAG:text], got {raw!r}", raw)
    tag, _, body = line[1:-1].partition(":")
    if tag == "MSG":
        return Feedback(raw, "MSG", body)
    if tag == "GC":
        return _parse_gc(raw, body)
    if tag == "HLP":
        return Help(raw, tuple(body.split()))
    if tag == "VER":
        version, _, info = body.partition(":")
        if not version:
            raise ProtocolError(f"GRBL [VER:]: missing version in {raw!r}", raw)
        return Version(raw, version, info)
    if tag == "OPT":
        parts = body.split(",")
        blocks = _integer(parts[1], "[OPT:] planner blocks", raw, COUNT_RANGE) if len(parts) > 1 else None
        rx = _integer(parts[2], "[OPT:] RX buffer size", raw, COUNT_RANGE) if len(parts) > 2 else None
        return Options(raw, parts[0], blocks, rx, tuple(parts[3:]))
    if tag in OFFSET_TAGS:
        return Offset(raw, tag, _vector(body, f"[{tag}:] offset", raw))
    if tag == "TLO":
        return Offset(raw, tag, _vector(body, "[TLO:] tool length offset", raw, 1, 6))
    if tag == "PRB":
        pos, sep, flag = body.rpartition(":")
        if not sep or flag not in ("0", "1"):
            raise ProtocolError(f"GRBL [PRB:]: expected [PRB:x,y,z:0|1], got {raw!r}", raw)
        return Probe(raw, _vector(pos, "[PRB:] position", raw), flag == "1")
    if tag == "echo":
        return Echo(raw, body)
    if not tag or not tag.replace("_", "").isalnum():
        raise ProtocolError(f"GRBL feedback: bad tag {tag!r} in {raw!r}", raw)
    # grblHAL and forks add [AXS:], [NEWOPT:], [FIRMWARE:], [SETTING:] ...: keep them as text
    return Feedback(raw, tag, body)


def _parse_gc(raw: str, body: str) -> ParserState:
    words = tuple(body.split())
    tool = feed = spindle = None
    for w in words:
        letter, value = w[:1], w[1:]
        if letter == "T":
            tool = _integer(value, "[GC:] tool", raw, COUNT_RANGE)
        elif letter == "F":
            feed = _number(value, "[GC:] feed", raw)
        elif letter == "S":
            spindle = _number(value, "[GC:] spindle", raw)
        elif letter not in ("G", "M") or not value:
            raise ProtocolError(f"GRBL [GC:]: unexpected word {w!r} in {raw!r}", raw)
    return ParserState(raw, words, tool, feed, spindle)


def _parse_dollar(line: str) -> Message:
    raw = line
    key, sep, value = line[1:].partition("=")
    if not sep:
        raise ProtocolError(f"GRBL setting: expected $N=value, got {raw!r}", raw)
    if key.startswith("N") and key[1:].isdigit():
        return StartupLine(raw, _integer(key[1:], "startup line number", raw, COUNT_RANGE), value)
    if not key.isdigit():
        raise ProtocolError(f"GRBL setting: expected a setting number after '$', got {key!r} in {raw!r}", raw)
    number = _integer(key, "setting number", raw, COUNT_RANGE)
    # grblHAL has string-valued settings (hostnames ...): NaN keeps the type numeric
    num = float(value) if _NUM.match(value.strip()) else math.nan
    if not value.strip():
        raise ProtocolError(f"GRBL setting ${key}: missing value in {raw!r}", raw)
    return Setting(raw, number, num, value)


def _parse_startup_result(line: str) -> StartupResult:
    raw = line
    body, sep, result = line[1:].rpartition(":")
    if not sep:
        raise ProtocolError(f"GRBL startup line: expected >block:ok or >block:error:N, got {raw!r}", raw)
    if result == "ok":
        return StartupResult(raw, body, True, None)
    body2, sep2, word = body.rpartition(":")
    if sep2 and word == "error":
        return StartupResult(raw, body2, False, _integer(result, "startup line error code", raw, CODE_RANGE))
    raise ProtocolError(f"GRBL startup line: expected :ok or :error:N at the end of {raw!r}", raw)


def parse_status(line: str) -> StatusReport:
    """Parse a ``<State|MPos:...|...>`` report into a :class:`StatusReport` (units as sent)."""
    raw = line
    line = line.strip()
    if not (line.startswith("<") and line.endswith(">")) or len(line) < 3:
        raise ProtocolError(f"GRBL status report: expected <...>, got {raw!r}", raw)
    fields = line[1:-1].split("|")
    state_text = fields[0]
    name, sep, sub = state_text.partition(":")
    if name not in _STATES:
        raise ProtocolError(f"GRBL status report: unknown state {state_text!r} in {raw!r}", raw)
    substate = _integer(sub, "status sub-state", raw, SUBSTATE_RANGE) if sep else None
    values: dict = {"state": name, "substate": substate}
    extra = []
    seen = set()
    for f in fields[1:]:
        key, sep, body = f.partition(":")
        if not sep:
            raise ProtocolError(f"GRBL status report: field {f!r} has no ':' in {raw!r}", raw)
        if key in seen:
            raise ProtocolError(f"GRBL status report: field {key!r} repeated in {raw!r}", raw)
        seen.add(key)
        if key == "MPos":
            values["mpos"] = _vector(body, "MPos", raw, 3)
        elif key == "WPos":
            values["wpos"] = _vector(body, "WPos", raw, 3)
        elif key == "WCO":
            values["wco"] = _vector(body, "WCO", raw, 3)
        elif key == "Bf":
            bf = body.split(",")
            if len(bf) != 2:
                raise ProtocolError(f"GRBL status report: Bf expects blocks,bytes, got {body!r} in {raw!r}", raw)
            values["buffer"] = (_integer(bf[0], "Bf blocks", raw, COUNT_RANGE),
                                _integer(bf[1], "Bf bytes", raw, COUNT_RANGE))
        elif key == "Ln":
            values["line"] = _integer(body, "Ln", raw, COUNT_RANGE)
        elif key == "FS":
            fs = body.split(",")
            if len(fs) != 2:
                raise ProtocolError(f"GRBL status report: FS expects feed,spindle, got {body!r} in {raw!r}", raw)
            values["feed"] = _number(fs[0], "FS feed", raw)
            values["spindle"] = _number(fs[1], "FS spindle", raw)
        elif key == "F":
            values["feed"] = _number(body, "F feed", raw)
        elif key == "Pn":
            bad = [c for c in body if c not in PIN_NAMES]
            if bad or not body:
                raise ProtocolError(f"GRBL status report: Pn expects pin letters XYZABCPDHRSET, got {body!r}", raw)
            values["pins"] = body
        elif key == "Ov":
            ov = body.split(",")
            if len(ov) != 3:
                raise ProtocolError(f"GRBL status report: Ov expects feed,rapid,spindle, got {body!r} in {raw!r}", raw)
            values["overrides"] = tuple(_integer(v, "Ov", raw, OVERRIDE_RANGE) for v in ov)
        elif key == "A":
            bad = [c for c in body if c not in "SCFMT"]
            if bad:
                raise ProtocolError(f"GRBL status report: A expects letters of SCFM, got {body!r} in {raw!r}", raw)
            values["accessories"] = body
        elif key and key.isalnum():
            extra.append((key, body))  # grblHAL extras (T:, H:, SD:, MPG: ...)
        else:
            raise ProtocolError(f"GRBL status report: bad field {f!r} in {raw!r}", raw)
    if ("mpos" in values) == ("wpos" in values):
        raise ProtocolError(f"GRBL status report: expected exactly one of MPos/WPos in {raw!r}", raw)
    if "overrides" in values and "accessories" not in values:
        values["accessories"] = ""  # A: is sent with Ov only when something is on
    return StatusReport(raw, extra=tuple(extra), **values)


# --------------------------------------------------------------------------------------
# Report -> MachineState
# --------------------------------------------------------------------------------------


def override_steps(current: int, target: int, kind: str = "feed") -> list[bytes]:
    """Real-time bytes that take an override from ``current`` to ``target`` percent.

    ``kind`` is ``"feed"``, ``"spindle"`` (coarse ±10 then fine ±1 steps, clamped to
    10..200 %) or ``"rapid"`` (one of 100/50/25 %; others raise ValueError).
    """
    if kind == "rapid":
        table = {100: RT_RAPID_OV_RESET, 50: RT_RAPID_OV_MEDIUM, 25: RT_RAPID_OV_LOW}
        if target not in table:
            raise ValueError(f"rapid override must be one of 100, 50, 25 %, got {target}")
        return [table[target]]
    if kind == "feed":
        reset, cp, cm, fp, fm = (RT_FEED_OV_RESET, RT_FEED_OV_COARSE_PLUS, RT_FEED_OV_COARSE_MINUS,
                                 RT_FEED_OV_FINE_PLUS, RT_FEED_OV_FINE_MINUS)
        lo, hi = FEED_OV_MIN, FEED_OV_MAX
    elif kind == "spindle":
        reset, cp, cm, fp, fm = (RT_SPINDLE_OV_RESET, RT_SPINDLE_OV_COARSE_PLUS, RT_SPINDLE_OV_COARSE_MINUS,
                                 RT_SPINDLE_OV_FINE_PLUS, RT_SPINDLE_OV_FINE_MINUS)
        lo, hi = SPINDLE_OV_MIN, SPINDLE_OV_MAX
    else:
        raise ValueError(f"override kind must be feed, rapid or spindle, got {kind!r}")
    target = int(target)
    if not lo <= target <= hi:
        raise ValueError(f"{kind} override must be {lo}..{hi} %, got {target}")
    out: list[bytes] = []
    if target == 100 or abs(target - 100) < abs(target - current):
        out.append(reset)
        current = 100
    diff = target - current
    coarse, fine = divmod(abs(diff), 10)
    sign_c, sign_f = (cp, fp) if diff > 0 else (cm, fm)
    out += [sign_c] * coarse + [sign_f] * fine
    return out


def apply_override(current: int, byte: int, kind: str) -> int:
    """Override percent after GRBL applies one real-time byte on its own (identical bytes
    that reach GRBL together count once: see ``drivers.grbl.peer``)."""
    if kind == "feed":
        base, lo, hi = 0x90, FEED_OV_MIN, FEED_OV_MAX
    else:
        base, lo, hi = 0x99, SPINDLE_OV_MIN, SPINDLE_OV_MAX
    step = byte - base
    if step == 0:
        return 100
    delta = {1: 10, 2: -10, 3: 1, 4: -1}[step]
    return max(lo, min(hi, current + delta))
