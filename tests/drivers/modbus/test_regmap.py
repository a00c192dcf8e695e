"""Register maps: coding round trips, read planning, validation messages."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, strategies as st

from drivers.modbus.regmap import (
    RegisterMapError,
    decode,
    decode_field,
    encode,
    encode_field,
    load_map,
    parse_map,
    plan_reads,
    Field,
)
from drivers.state import RunState

ORDERS = [("big", "big"), ("little", "big"), ("big", "little"), ("little", "little")]


def test_known_words():
    # 1.0f = 0x3F800000
    assert encode(1.0, "float32") == [0x3F80, 0x0000]
    assert encode(1.0, "float32", word_order="little") == [0x0000, 0x3F80]
    assert encode(1.0, "float32", byte_order="little") == [0x803F, 0x0000]
    assert encode(-2, "int16") == [0xFFFE]
    assert encode(0x12345678, "uint32") == [0x1234, 0x5678]
    assert encode(0x12345678, "uint32", "little", "little") == [0x7856, 0x3412]
    assert encode(1.0, "float64") == [0x3FF0, 0, 0, 0]
    assert decode([0x1234, 0x5678], "int32") == 0x12345678


@pytest.mark.parametrize("word_order,byte_order", ORDERS)
@pytest.mark.parametrize(
    "ftype,value",
    [("int16", -12345), ("uint16", 65535), ("int32", -2_000_000_000), ("uint32", 4_000_000_000),
     ("float32", -123.25), ("float64", math.pi)],
)
def test_round_trip_every_type_and_order(ftype, value, word_order, byte_order):
    words = encode(value, ftype, word_order, byte_order)
    assert all(0 <= w <= 0xFFFF for w in words)
    assert decode(words, ftype, word_order, byte_order) == value


@given(st.floats(allow_nan=False, allow_infinity=False, width=32), st.sampled_from(ORDERS))
def test_float32_round_trip_property(value, orders):
    assert decode(encode(value, "float32", *orders), "float32", *orders) == value


def test_out_of_range_and_bad_words():
    with pytest.raises(ValueError, match="does not fit int16"):
        encode(40000, "int16")
    with pytest.raises(ValueError, match="needs 2 registers"):
        decode([1], "float32")
    with pytest.raises(ValueError, match="unknown type"):
        encode(1, "int64")


def test_scale_and_offset():
    f = Field("x", "holding", 0, "int32", scale=0.01, offset=-5.0)
    words = encode_field(f, 12.34)
    assert decode(words, "int32") == 1734
    assert decode_field(f, words) == pytest.approx(12.34)


def test_plan_reads_coalesces_contiguous_only():
    fs = [Field("x", "input", 0, "float32"), Field("y", "input", 2, "float32"), Field("z", "input", 10, "float32"),
          Field("state", "holding", 3, "uint16"), Field("feed_hold", "coil", 5, "bool"),
          Field("a", "input", 0, "float32", unit=2)]
    blocks = plan_reads(fs)
    got = {(b.unit, b.table, b.address, b.count) for b in blocks}
    assert got == {(1, "input", 0, 4), (1, "input", 10, 2), (1, "holding", 3, 1), (1, "coil", 5, 1), (2, "input", 0, 2)}


def test_plan_reads_respects_request_limit():
    fs = [Field("x", "input", 2 * i, "float32") for i in range(100)]  # 200 contiguous registers
    fs = [Field(n, f.table, f.address, f.type) for n, f in zip(["x"] * 100, fs)]
    blocks = plan_reads(fs, max_regs=125)
    assert [b.count for b in blocks] == [124, 76]


def test_shipped_maps_load():
    g = load_map("generic")
    assert g.states[2] == RunState.HOLD and g.feed_hold.table == "coil"
    assert len(plan_reads(g.reading_fields())) == 1
    iai = load_map("iai_robo_cylinder")
    assert iai.fields["x"].address == 0x9000 and iai.fields["y"].unit == 2
    assert iai.feed_hold.address == 0x040A and iai.feed_hold.unit == 0
    assert "ME0162" in iai.source


@pytest.mark.parametrize(
    "doc,match",
    [
        ({"fields": {"x": {"table": "holdin", "address": 0, "type": "int16"}}}, r"fields.x.table: expected one of"),
        ({"fields": {"x": {"table": "holding", "address": 0, "type": "int64"}}}, r"fields.x.type: expected one of"),
        ({"fields": {"x": {"table": "holding", "type": "int16"}}}, r"fields.x: missing key 'address'"),
        ({"fields": {"x": {"table": "holding", "address": "0", "type": "int16"}}}, r"fields.x.address: expected int"),
        ({"fields": {"x": {"table": "holding", "address": 70000, "type": "int16"}}}, r"expected 0..65535"),
        ({"fields": {"q": {"table": "holding", "address": 0, "type": "int16"}}}, r"fields.q: unknown field"),
        ({"fields": {"x": {"table": "holding", "address": 0, "type": "int16", "scal": 2}}}, r"fields.x.scal: unknown key"),
        ({"fields": {"x": {"table": "coil", "address": 0, "type": "int16"}}}, r"holds bits"),
        ({"fields": {"x": {"table": "holding", "address": 0, "type": "int32"},
                     "y": {"table": "holding", "address": 1, "type": "int16"}}}, r"fields.y.address: overlaps field x"),
        ({"fields": {"x": {"table": "holding", "address": 0, "type": "int16"},
                     "state": {"table": "holding", "address": 1, "type": "int16"}}}, r"no \[states\]"),
        ({"fields": {"x": {"table": "holding", "address": 0, "type": "int16"}}, "states": {"0": "Running"}}, r"states.0: expected a state name"),
        ({"fields": {"feed": {"table": "holding", "address": 0, "type": "int16"}}}, r"names no axis"),
        ({"map": {"word_order": "middle"}, "fields": {"x": {"table": "holding", "address": 0, "type": "int16"}}}, r"map.word_order"),
        ({"fields": {"x": {"table": "holding", "address": 0, "type": "int16"},
                     "feed_hold": {"table": "input", "address": 1, "type": "uint16"}}}, r"feed_hold must be a coil"),
    ],
)
def test_validation_names_key(doc, match):
    with pytest.raises(RegisterMapError, match=match) as info:
        parse_map(doc, "m.toml")
    assert str(info.value).startswith("m.toml: ")


def test_load_map_file_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[fields.x\n")
    with pytest.raises(RegisterMapError, match="bad.toml: not valid TOML"):
        load_map(bad)
    with pytest.raises(RegisterMapError, match="cannot read"):
        load_map(tmp_path / "missing.toml")


X = {"table": "input", "address": 0, "type": "float32"}


@pytest.mark.parametrize("key", ["wordorder", "byte-order", "unitt"])
def test_unknown_key_in_map_head_is_rejected_naming_file_and_key(tmp_path, key):
    """A misspelt [map] key was ignored: the map loaded with the default word order and
    positions decoded wrongly, yet fresh."""
    p = tmp_path / "typo.toml"
    p.write_text(f'[map]\nname = "t"\n{key} = "little"\n[fields.x]\ntable = "input"\naddress = 0\ntype = "float32"\n')
    with pytest.raises(RegisterMapError) as info:
        load_map(p)
    msg = str(info.value)
    assert msg.startswith(f"{p}: map.{key}: unknown key; expected one of ")
    assert "byte_order" in msg and "word_order" in msg and "unit" in msg


@pytest.mark.parametrize(
    "hold,match",
    [
        ({"table": "holding", "address": 10, "type": "uint16", "hold_value": 70000}, r"fields.feed_hold.hold_value: expected a register word 0..65535, got 70000"),
        ({"table": "holding", "address": 10, "type": "uint16", "hold_value": -1}, r"fields.feed_hold.hold_value: expected a register word 0..65535, got -1"),
        ({"table": "holding", "address": 10, "type": "uint16", "resume_value": 65536}, r"fields.feed_hold.resume_value: expected a register word"),
        ({"table": "holding", "address": 10, "type": "uint16", "hold_value": 0, "resume_value": 0}, r"fields.feed_hold.resume_value: equals hold_value"),
        ({"table": "holding", "address": 10, "type": "uint16", "hold_value": 1, "resume_value": 1}, r"fields.feed_hold.resume_value: equals hold_value"),
        ({"table": "holding", "address": 10, "type": "float32"}, r"fields.feed_hold.type: .*one 16-bit register: int16 or uint16, got 'float32'"),
        ({"table": "holding", "address": 10, "type": "uint32"}, r"fields.feed_hold.type: .*one 16-bit register"),
        ({"table": "coil", "address": 0, "hold_value": 2}, r"fields.feed_hold.hold_value: a coil is 0 or 1, got 2"),
        ({"table": "coil", "address": 0, "hold_value": 1, "resume_value": 1}, r"fields.feed_hold.resume_value: equals hold_value"),
    ],
)
def test_feed_hold_cell_mistakes_are_rejected_at_load(hold, match):
    with pytest.raises(RegisterMapError, match=match) as info:
        parse_map({"fields": {"x": X, "feed_hold": hold}}, "m.toml")
    assert str(info.value).startswith("m.toml: ")


def test_feed_hold_coil_may_be_active_low():
    m = parse_map({"fields": {"x": X, "feed_hold": {"table": "coil", "address": 0, "hold_value": 0,
                                                    "resume_value": 1}}}, "m.toml")
    assert (m.feed_hold.hold_value, m.feed_hold.resume_value) == (0, 1)


@pytest.mark.parametrize("key,value", [("scale", math.nan), ("scale", math.inf), ("scale", -math.inf),
                                       ("offset", math.nan), ("offset", math.inf)])
def test_non_finite_scale_or_offset_is_rejected(key, value):
    with pytest.raises(RegisterMapError, match=rf"m.toml: fields.x.{key}: expected a finite number, got {value!r}"):
        parse_map({"fields": {"x": {**X, key: value}}}, "m.toml")


@pytest.mark.parametrize("doc,where", [
    ({"fields": {"x": {**X, "unit": 0}}}, "fields.x.unit"),
    ({"map": {"unit": 0}, "fields": {"x": X}}, "fields.x.unit"),
    ({"fields": {"x": X, "max_rate_x": {"table": "input", "address": 40, "type": "float32", "unit": 0}}},
     "fields.max_rate_x.unit"),
])
def test_a_read_field_on_the_broadcast_unit_is_rejected(doc, where):
    """Devices never answer unit 0 (broadcast): every poll would time out as 'link lost'."""
    with pytest.raises(RegisterMapError, match=rf"m.toml: {where}: unit 0 is broadcast.*only feed_hold"):
        parse_map(doc, "m.toml")


def test_feed_hold_may_be_broadcast():
    m = parse_map({"fields": {"x": X, "feed_hold": {"table": "coil", "address": 0, "unit": 0}}}, "m.toml")
    assert m.feed_hold.unit == 0 and m.fields["x"].unit == 1
