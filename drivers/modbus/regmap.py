"""Modbus register maps: which register holds which machine value, read from TOML.

A map file looks like this (see ``maps/generic.toml`` for a complete one)::

    [map]
    name = "generic"
    unit = 1                 # default device id (slave address), 1..247
    word_order = "big"       # default: most significant word first
    byte_order = "big"       # default: most significant byte first in each word

    [fields.x]               # one table per field
    table = "holding"        # holding | input | coil | discrete
    address = 0              # 0-based protocol address
    type = "float32"         # int16 uint16 int32 uint32 float32 float64 (bool for coil/discrete)
    scale = 1.0              # value = raw * scale + offset
    offset = 0.0
    # word_order / byte_order / unit may be set per field

    [states]                 # state code -> run state name (Idle Run Hold Jog Alarm Door ...)
    0 = "Idle"
    1 = "Run"

Field names: axis positions ``x y z a b c`` (mm, deg, machine coordinates); work offsets
``wco_x`` .. ``wco_c``; axis velocities ``vx`` .. ``vc`` (mm/min, combined into the path
feed when no ``feed`` field is mapped); ``feed`` (mm/min), ``spindle`` (rpm), ``state``
(code, named through ``[states]``), ``alarm`` (code, 0 = none), ``line``,
``feed_override`` ``rapid_override`` ``spindle_override`` (percent), and the optional
writable ``feed_hold``: a coil (``hold_value`` / ``resume_value`` 1 / 0 by default; 0 / 1
for an active-low coil) or one int16/uint16 holding register (``hold_value`` /
``resume_value``, register words 0..65535 that differ); it alone may be on unit 0
(broadcast), which no device answers. The machine's limits, for program timing, may be named too and are
read once at connect: ``max_rate_x`` .. ``max_rate_z`` (mm/min), ``accel_x`` ..
``accel_z`` (mm/s^2), ``junction_deviation`` (mm).

Pure functions :func:`encode` and :func:`decode` turn values into register words and
back; :func:`plan_reads` coalesces contiguous registers into few requests.
"""

from __future__ import annotations

import math
import struct
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from drivers.errors import DriverError
from drivers.state import ControllerLimits, RunState

TABLES = ("holding", "input", "coil", "discrete")
#: type -> (struct code, number of 16-bit registers)
TYPES = {
    "int16": ("h", 1),
    "uint16": ("H", 1),
    "int32": ("i", 2),
    "uint32": ("I", 2),
    "float32": ("f", 2),
    "float64": ("d", 4),
    "bool": ("?", 1),
}
ORDERS = ("big", "little")
AXES = "xyzabc"
FIELD_NAMES = (
    tuple(AXES)
    + tuple(f"wco_{a}" for a in AXES)
    + tuple(f"v{a}" for a in AXES)
    + ("feed", "spindle", "state", "alarm", "line", "feed_override", "rapid_override", "spindle_override", "feed_hold")
)
#: the machine's limits, read once at connect (not at every poll)
LIMIT_FIELDS = (tuple(f"max_rate_{a}" for a in "xyz") + tuple(f"accel_{a}" for a in "xyz")
                + ("junction_deviation",))
FIELD_NAMES += LIMIT_FIELDS
#: keys of the ``[map]`` table and of each ``[fields.NAME]`` table
MAP_KEYS = frozenset({"name", "source", "unit", "word_order", "byte_order", "description"})
FIELD_KEYS = frozenset({"table", "address", "type", "scale", "offset", "word_order", "byte_order", "unit",
                        "hold_value", "resume_value", "description"})
#: types the feed-hold register may have: it is written with one "write single register"
HOLD_REGISTER_TYPES = ("int16", "uint16")
#: Modbus limits per request (registers, bits)
MAX_REGS_PER_READ = 125
MAX_BITS_PER_READ = 2000


class RegisterMapError(DriverError):
    """A register map file that is not what was expected (names file and key)."""


@dataclass(frozen=True)
class Field:
    """Where one value lives and how it is coded.

    ``count`` is the number of registers (or 1 bit for coil/discrete tables).
    """

    name: str
    table: str
    address: int
    type: str
    scale: float = 1.0
    offset: float = 0.0
    word_order: str = "big"
    byte_order: str = "big"
    unit: int = 1
    hold_value: int = 1
    resume_value: int = 0

    @property
    def count(self) -> int:
        return TYPES[self.type][1]

    @property
    def is_bit(self) -> bool:
        return self.table in ("coil", "discrete")

    def to_value(self, raw) -> float:
        """Physical value of a decoded raw number (``raw * scale + offset``)."""
        return float(raw) * self.scale + self.offset

    def to_raw(self, value: float):
        """Raw number to store for a physical value (rounded for integer types)."""
        raw = (float(value) - self.offset) / self.scale
        if self.type.startswith(("int", "uint")):
            return int(round(raw))
        if self.type == "bool":
            return bool(raw)
        return raw


@dataclass(frozen=True)
class RegisterMap:
    """A parsed map: fields by name, state names by code, where it came from."""

    name: str
    source: str
    fields: dict[str, Field]
    states: dict[int, RunState] = field(default_factory=dict)
    unit: int = 1
    path: str = "<map>"

    def reading_fields(self) -> list[Field]:
        """Fields read at each poll (all but the feed-hold command and the limits)."""
        return [f for n, f in self.fields.items() if n != "feed_hold" and n not in LIMIT_FIELDS]

    def limit_fields(self) -> list[Field]:
        """The machine-limit fields mapped (read once at connect)."""
        return [f for n, f in self.fields.items() if n in LIMIT_FIELDS]

    @property
    def feed_hold(self) -> Field | None:
        return self.fields.get("feed_hold")

    def state_code(self, state: RunState) -> int | None:
        """First code named ``state`` in ``[states]``."""
        for code, name in self.states.items():
            if name == state:
                return code
        return None


# --------------------------------------------------------------------------- coding
def _check_range(value, ftype: str):
    code = TYPES[ftype][0]
    if code in "hHiI":
        bits = 16 if code in "hH" else 32
        lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if code in "hi" else (0, (1 << bits) - 1)
        if not lo <= value <= hi:
            raise ValueError(f"{value} does not fit {ftype} ({lo}..{hi})")


def encode(value, ftype: str, word_order: str = "big", byte_order: str = "big") -> list[int]:
    """Register words (list of int 0..65535) holding raw ``value`` of ``ftype``.

    ``word_order`` "big" puts the most significant word first; ``byte_order`` "little"
    swaps the two bytes of every word. For ``bool``: ``[1]`` or ``[0]``.
    """
    if ftype not in TYPES:
        raise ValueError(f"unknown type {ftype!r}; expected one of {', '.join(TYPES)}")
    if ftype == "bool":
        return [1 if value else 0]
    code, n = TYPES[ftype]
    if code in "hHiI":
        value = int(value)
        _check_range(value, ftype)
    data = struct.pack(">" + code, value)
    words = [int.from_bytes(data[2 * i:2 * i + 2], "big") for i in range(n)]
    if word_order == "little":
        words.reverse()
    if byte_order == "little":
        words = [((w & 0xFF) << 8) | (w >> 8) for w in words]
    return words


def decode(words, ftype: str, word_order: str = "big", byte_order: str = "big"):
    """Raw value of ``ftype`` from its register words (inverse of :func:`encode`)."""
    if ftype not in TYPES:
        raise ValueError(f"unknown type {ftype!r}; expected one of {', '.join(TYPES)}")
    code, n = TYPES[ftype]
    words = [int(w) for w in words]
    if len(words) != n:
        raise ValueError(f"{ftype} needs {n} registers, got {len(words)}")
    if ftype == "bool":
        return bool(words[0])
    if any(not 0 <= w <= 0xFFFF for w in words):
        raise ValueError(f"register words must be 0..65535, got {words}")
    if byte_order == "little":
        words = [((w & 0xFF) << 8) | (w >> 8) for w in words]
    if word_order == "little":
        words = words[::-1]
    data = b"".join(w.to_bytes(2, "big") for w in words)
    return struct.unpack(">" + code, data)[0]


def encode_field(f: Field, value: float) -> list[int]:
    """Words (or ``[0|1]`` for bits) holding physical ``value`` in field ``f``."""
    raw = f.to_raw(value)
    if isinstance(raw, float) and not math.isfinite(raw) and f.type.startswith(("int", "uint")):
        raise ValueError(f"field {f.name}: cannot store {value}")
    return encode(raw, f.type, f.word_order, f.byte_order)


def decode_field(f: Field, words) -> float:
    """Physical value of field ``f`` from its words (or bits)."""
    return f.to_value(decode(words, f.type, f.word_order, f.byte_order))


# --------------------------------------------------------------------------- read planning
@dataclass(frozen=True)
class ReadBlock:
    """One read request: ``count`` registers (or bits) of ``table`` from ``address``."""

    unit: int
    table: str
    address: int
    count: int
    fields: tuple[Field, ...]


def plan_reads(fields: list[Field], max_regs: int = MAX_REGS_PER_READ, max_bits: int = MAX_BITS_PER_READ) -> list[ReadBlock]:
    """Coalesce fields into few requests: per (unit, table), runs of contiguous (or
    overlapping) addresses become one read, split at the protocol's size limits. Gaps are
    never bridged, because a device may answer an unmapped address with an exception."""
    blocks: list[ReadBlock] = []
    groups: dict[tuple[int, str], list[Field]] = {}
    for f in fields:
        groups.setdefault((f.unit, f.table), []).append(f)
    for (unit, table), fs in sorted(groups.items()):
        limit = max_bits if table in ("coil", "discrete") else max_regs
        fs = sorted(fs, key=lambda f: f.address)
        start = fs[0].address
        end = start + fs[0].count
        members = [fs[0]]
        for f in fs[1:]:
            new_end = max(end, f.address + f.count)
            if f.address <= end and new_end - start <= limit:
                end = new_end
                members.append(f)
            else:
                blocks.append(ReadBlock(unit, table, start, end - start, tuple(members)))
                start, end, members = f.address, f.address + f.count, [f]
        blocks.append(ReadBlock(unit, table, start, end - start, tuple(members)))
    return blocks


def limits_from_values(values: dict[str, float], source: str) -> ControllerLimits | None:
    """The machine's limits from decoded limit fields: a group (max rates, accelerations)
    counts only with all three axes positive and finite; None when nothing is known."""

    def axes(prefix: str) -> tuple[float, float, float] | None:
        vals = [values.get(f"{prefix}_{a}") for a in "xyz"]
        if all(v is not None and math.isfinite(v) and v > 0 for v in vals):
            return tuple(float(v) for v in vals)
        return None

    jd = values.get("junction_deviation")
    jd = float(jd) if jd is not None and math.isfinite(jd) and jd > 0 else None
    rate, accel = axes("max_rate"), axes("accel")
    if rate is None and accel is None and jd is None:
        return None
    return ControllerLimits(max_rate=rate, acceleration=accel, junction_deviation=jd, source=source)


# --------------------------------------------------------------------------- loading
_STATE_NAMES = {s.value.lower(): s for s in RunState}


def _err(path: str, key: str, msg: str) -> RegisterMapError:
    return RegisterMapError(f"{path}: {key}: {msg}")


def _get(d: dict, key: str, kind, path: str, where: str, default=None, required=False):
    if key not in d:
        if required:
            raise _err(path, where, f"missing key {key!r}")
        return default
    v = d[key]
    if kind is float and isinstance(v, int) and not isinstance(v, bool):
        v = float(v)
    if not isinstance(v, kind) or (kind is int and isinstance(v, bool)):
        raise _err(path, f"{where}.{key}", f"expected {kind.__name__}, got {v!r}")
    return v


def parse_map(doc: dict, path: str = "<map>") -> RegisterMap:
    """Build a :class:`RegisterMap` from a parsed TOML document; errors name the key."""
    head = doc.get("map", {})
    if not isinstance(head, dict):
        raise _err(path, "map", "expected a table [map]")
    unknown = set(doc) - {"map", "fields", "states"}
    if unknown:
        raise _err(path, sorted(unknown)[0], "unknown top-level table; expected [map], [fields.*], [states]")
    # a misspelt default (``wordorder``) would leave every field on the other default and
    # decode positions wrongly yet as fresh: refuse it, as field tables do
    extra = set(head) - MAP_KEYS
    if extra:
        raise _err(path, f"map.{sorted(extra)[0]}", f"unknown key; expected one of {', '.join(sorted(MAP_KEYS))}")
    name = _get(head, "name", str, path, "map", default=Path(path).stem)
    source = _get(head, "source", str, path, "map", default="")
    unit = _get(head, "unit", int, path, "map", default=1)
    d_word = _get(head, "word_order", str, path, "map", default="big")
    d_byte = _get(head, "byte_order", str, path, "map", default="big")
    for key, v in (("word_order", d_word), ("byte_order", d_byte)):
        if v not in ORDERS:
            raise _err(path, f"map.{key}", f"expected 'big' or 'little', got {v!r}")
    raw_fields = doc.get("fields")
    if not isinstance(raw_fields, dict) or not raw_fields:
        raise _err(path, "fields", "expected at least one [fields.NAME] table")
    fields: dict[str, Field] = {}
    allowed_keys = FIELD_KEYS
    for fname, spec in raw_fields.items():
        where = f"fields.{fname}"
        if fname not in FIELD_NAMES:
            raise _err(path, where, f"unknown field; expected one of {', '.join(FIELD_NAMES)}")
        if not isinstance(spec, dict):
            raise _err(path, where, "expected a table")
        extra = set(spec) - allowed_keys
        if extra:
            raise _err(path, f"{where}.{sorted(extra)[0]}", f"unknown key; expected one of {', '.join(sorted(allowed_keys))}")
        table = _get(spec, "table", str, path, where, required=True)
        if table not in TABLES:
            raise _err(path, f"{where}.table", f"expected one of {', '.join(TABLES)}, got {table!r}")
        address = _get(spec, "address", int, path, where, required=True)
        if not 0 <= address <= 0xFFFF:
            raise _err(path, f"{where}.address", f"expected 0..65535, got {address}")
        bit = table in ("coil", "discrete")
        ftype = _get(spec, "type", str, path, where, default="bool" if bit else None, required=not bit)
        if ftype not in TYPES:
            raise _err(path, f"{where}.type", f"expected one of {', '.join(TYPES)}, got {ftype!r}")
        if bit != (ftype == "bool"):
            raise _err(path, f"{where}.type", f"table {table} holds {'bits: use bool' if bit else 'registers: bool only for coil/discrete'}")
        if address + TYPES[ftype][1] - 1 > 0xFFFF:
            raise _err(path, f"{where}.address", "field runs past register 65535")
        scale = _get(spec, "scale", float, path, where, default=1.0)
        offset = _get(spec, "offset", float, path, where, default=0.0)
        # TOML has nan and inf: every reading would then be BAD, blamed on the controller
        for key, v in (("scale", scale), ("offset", offset)):
            if not math.isfinite(v):
                raise _err(path, f"{where}.{key}", f"expected a finite number, got {v!r}")
        if scale == 0:
            raise _err(path, f"{where}.scale", "must not be 0")
        f = Field(
            name=fname, table=table, address=address, type=ftype, scale=scale, offset=offset,
            word_order=_get(spec, "word_order", str, path, where, default=d_word),
            byte_order=_get(spec, "byte_order", str, path, where, default=d_byte),
            unit=_get(spec, "unit", int, path, where, default=unit),
            hold_value=_get(spec, "hold_value", int, path, where, default=1),
            resume_value=_get(spec, "resume_value", int, path, where, default=0),
        )
        for key in ("word_order", "byte_order"):
            if getattr(f, key) not in ORDERS:
                raise _err(path, f"{where}.{key}", f"expected 'big' or 'little', got {getattr(f, key)!r}")
        if not 0 <= f.unit <= 247:
            raise _err(path, f"{where}.unit", f"expected a device id 0..247, got {f.unit}")
        if f.unit == 0 and fname != "feed_hold":
            # no device answers a broadcast: every poll would time out and read as "link lost"
            raise _err(path, f"{where}.unit", "unit 0 is broadcast, which no device answers: a field that is "
                                              "read needs a device id 1..247 (only feed_hold may be broadcast)")
        if fname == "feed_hold":
            _check_feed_hold(f, path, where)
        fields[fname] = f
    if not any(a in fields for a in AXES):
        raise _err(path, "fields", "map names no axis position (x, y, z, a, b or c)")
    _check_overlaps(fields, path)
    states: dict[int, RunState] = {}
    raw_states = doc.get("states", {})
    if not isinstance(raw_states, dict):
        raise _err(path, "states", "expected a table of CODE = \"Name\"")
    for code, sname in raw_states.items():
        try:
            icode = int(code)
        except ValueError:
            raise _err(path, f"states.{code}", "expected an integer code") from None
        if not isinstance(sname, str) or sname.lower() not in _STATE_NAMES:
            names = ", ".join(s.value for s in RunState)
            raise _err(path, f"states.{code}", f"expected a state name ({names}), got {sname!r}")
        states[icode] = _STATE_NAMES[sname.lower()]
    if "state" in fields and not states:
        raise _err(path, "states", "field 'state' is mapped but no [states] table names its codes")
    return RegisterMap(name=name, source=source, fields=fields, states=states, unit=unit, path=path)


def _check_feed_hold(f: Field, path: str, where: str) -> None:
    """The feed-hold cell is written, not read: what is written must fit the cell, and
    hold and resume must differ, or the mistake shows only when the monitor tries to stop
    the machine."""
    if f.table not in ("coil", "holding"):
        raise _err(path, f"{where}.table", "feed_hold must be a coil or a holding register (writable)")
    if f.table == "coil":
        for key in ("hold_value", "resume_value"):
            if getattr(f, key) not in (0, 1):
                raise _err(path, f"{where}.{key}", f"a coil is 0 or 1, got {getattr(f, key)}")
    else:
        if f.type not in HOLD_REGISTER_TYPES:
            raise _err(path, f"{where}.type", f"feed_hold is written as one 16-bit register: "
                                              f"{' or '.join(HOLD_REGISTER_TYPES)}, got {f.type!r}")
        for key in ("hold_value", "resume_value"):
            if not 0 <= getattr(f, key) <= 0xFFFF:
                raise _err(path, f"{where}.{key}", f"expected a register word 0..65535, got {getattr(f, key)}")
    if f.hold_value == f.resume_value:
        raise _err(path, f"{where}.resume_value", f"equals hold_value ({f.hold_value}): resuming would hold again")


def _check_overlaps(fields: dict[str, Field], path: str) -> None:
    spans = sorted(((f.unit, f.table, f.address, f.address + f.count, f.name) for f in fields.values()))
    for a, b in zip(spans, spans[1:]):
        if a[:2] == b[:2] and b[2] < a[3]:
            raise _err(path, f"fields.{b[4]}.address", f"overlaps field {a[4]} ({a[1]} {a[2]}..{a[3] - 1})")


def load_map(path) -> RegisterMap:
    """Read and validate a TOML map file. Bare names (``generic``, ``iai_robo_cylinder``)
    refer to the maps shipped in ``drivers/modbus/maps``."""
    p = Path(path)
    if not p.suffix and not p.exists():
        p = Path(__file__).parent / "maps" / f"{path}.toml"
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise RegisterMapError(f"{path}: cannot read register map ({exc.strerror or exc})") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RegisterMapError(f"{p}: not valid TOML: {exc}") from None
    return parse_map(doc, str(p))
