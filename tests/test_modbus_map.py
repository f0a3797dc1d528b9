"""Modbus register maps: validation that names the entry, presets plus overrides, and the encodings.

The driver decodes with its own struct code (drivers/modbus/registers.py); the simulated device
encodes with pymodbus' conversion (fakes/modbus/store.py). These tests check each against the
other and against register values worked out by hand from the vendors' documentation.
"""

import math

import pytest
import yaml

from conftest import ROOT, tweak
from payload_agent.configuration.config import parse_config
from payload_agent.drivers.modbus.options import resolve_map
from payload_agent.drivers.modbus.registers import EncodingError, Entry, group_reads, group_writes
from payload_agent.drivers.modbus.regmap import load_preset
from payload_agent.drivers.registry import parse_driver_options
from payload_agent.errors import ConfigError
from payload_agent.fakes.modbus.store import decode as fake_decode
from payload_agent.fakes.modbus.store import encode as fake_encode


def _opts(**changes):
    data = {"type": "modbus", "host": "127.0.0.1", "preset": "ur_modbus_server"}
    data.update(changes)
    return parse_driver_options(data, "driver", "robot.yaml")


def _error(match, **changes):
    with pytest.raises(ConfigError, match=match) as info:
        _opts(**changes)
    return info.value


def test_presets_load_and_validate():
    for name in ("ur_modbus_server", "igus_rebel", "generic_float32"):
        regmap = resolve_map(_opts(preset=name))
        assert regmap.effort_unit in ("A", "Nm")
        assert regmap.has_all("joint_angles", "joint_efforts", "cmd_target", "cmd_seq", "stop_request", "stop_ack")


def test_unknown_type_names_the_entry():
    err = _error(r"driver\.map\.joint_efforts\.type: unknown type 'int24'", map={"joint_efforts": {"type": "int24"}})
    assert err.source == "robot.yaml"


def test_count_that_does_not_fit_the_type():
    _error(r"joint_angles\.count: 11 registers do not fit type int32 \(2 registers per value\)",
           map={"joint_angles": {"type": "int32", "count": 11}})
    _error(r"joint_angles\.count: joint_angles has 6 values: count must be 12 \(6 × int32\), got 6",
           map={"joint_angles": {"type": "int32"}})


def test_overlapping_entries_are_named():
    err = _error(r"overlaps", map={"joint_efforts": {"address": 272}})
    assert "joint_angles" in str(err) and "joint_efforts" in str(err) and "270-275" in str(err)


def test_required_signal_missing_and_not_removable():
    _error(r"driver\.map\.stop_ack: is required and cannot be removed", map={"stop_ack": None})
    full = dict(load_preset("generic_float32")["signals"])
    del full["stop_ack"]
    _error(r"required signals missing: stop_ack", preset=None, map=full)


def test_agent_written_signal_in_read_only_table():
    _error(r"cmd_seq\.table: the agent writes cmd_seq, but a input table is read-only",
           map={"cmd_seq": {"table": "input"}})


def test_unknown_signal_unit_and_keys():
    _error(r"driver\.map\.joint_speeds: unknown signal", map={"joint_speeds": {"table": "holding"}})
    _error(r"joint_efforts\.unit: joint_efforts takes one of", map={"joint_efforts": {"unit": "mA"}})
    _error(r"joint_angles\.scal: unknown key", map={"joint_angles": {"scal": 2}})
    _error(r"driver\.preset: unknown preset 'ur10'", preset="ur10")
    _error(r"driver\.host: Modbus TCP needs", host=None)
    _error(r"driver\.serial_port: Modbus RTU needs", transport="rtu")
    _error(r"driver\.port: ", port="502")
    _error(r"driver\.port: must be between 0 and 65535", port=70000)


def test_incomplete_groups_and_bad_types_for_counters():
    _error(r"tcp_position needs tcp_rotation", map={"tcp_rotation": None})
    _error(r"cmd_seq\.type: cmd_seq is a counter or code and needs an integer type",
           map={"cmd_seq": {"type": "float32", "count": 2}})
    _error(r"must be of type bool", map={"emergency_stop": {"table": "coil", "type": "uint16"}})


def test_overrides_merge_key_by_key_and_null_removes():
    regmap = resolve_map(_opts(map={"cmd_seq": {"address": 150}, "tool_change": None}))
    assert regmap["cmd_seq"].address == 150 and regmap["cmd_seq"].type == "uint16"
    assert "tool_change" not in regmap
    assert regmap["cmd_seq"].source == "preset ur_modbus_server + map"


def test_plan_rejects_a_bad_map_without_connecting():
    data = yaml.safe_load((ROOT / "configs" / "sim-ur5e-modbus.yaml").read_text())
    bad = tweak(data, "driver.map", {"joint_angles": {"count": 5}})
    with pytest.raises(ConfigError, match=r"driver\.map\.joint_angles\.count"):
        parse_config(bad, source="sim-ur5e-modbus.yaml")
    cfg = parse_config(data, source="sim-ur5e-modbus.yaml")
    assert cfg.driver_options.preset == "ur_modbus_server"


def test_effort_unit_of_the_map_is_the_drivers():
    from payload_agent.drivers.base import MotionLimits
    from payload_agent.drivers.modbus.driver import ModbusDriver

    drv = ModbusDriver(_opts(map={"joint_efforts": {"scale": 1.0, "unit": "Nm"}}), MotionLimits(3.0, 3.0))
    assert drv.effort_unit == "Nm"
    with pytest.raises(ConfigError, match="effort.unit"):
        drv.check_effort_unit("A")
    assert ModbusDriver(_opts(), MotionLimits(3.0, 3.0)).effort_unit == "A"


# -- encodings ---------------------------------------------------------------------------------
def _ur(name):
    return resolve_map(_opts())[name]


def test_ur_negative_angle_uses_revolution_counter():
    # UR forum (docs/sources.md): angles count up from 0 within a turn; the counter reads 65535 for
    # [-360°, 0). -0.5 rad is 2π - 0.5 = 5.783 rad in the angle register, -1 in the counter.
    angles, revs = _ur("joint_angles"), _ur("joint_revolutions")
    q = -0.5
    turn = 2 * math.pi
    n = math.floor(q / turn)
    words = fake_encode(angles, [q - n * turn] + [0.0] * 5)
    rev_words = fake_encode(revs, [n * revs.scale] + [0.0] * 5)
    assert words[0] == 5783 and rev_words[0] == 65535
    decoded = angles.decode(words)[0] + revs.decode(rev_words)[0]
    assert decoded == pytest.approx(q, abs=0.0006)
    # and a positive angle leaves the counter at 0
    assert fake_encode(revs, [0.0] * 6) == [0] * 6 and angles.decode([1234] + [0] * 5)[0] == pytest.approx(1.234)


def test_current_is_twos_complement_milliamps():
    e = _ur("joint_efforts")
    assert fake_encode(e, [-1.5, 2.0, 0, 0, 0, 0])[:2] == [65536 - 1500, 2000]
    assert e.decode([65536 - 1500, 2000, 0, 0, 0, 0])[:2] == pytest.approx([-1.5, 2.0])


@pytest.mark.parametrize("type_name,word_order,byte_order,value", [
    ("int32", "big", "big", -123456), ("int32", "little", "big", -123456), ("uint32", "little", "little", 4000000000),
    ("float32", "big", "big", -2.5), ("float32", "little", "little", 1.0e-3), ("int16", "big", "little", -2),
])
def test_driver_and_device_codecs_agree(type_name, word_order, byte_order, value):
    width = 2 if type_name.endswith("32") else 1
    e = Entry("x", "holding", 10, width, type_name, word_order, byte_order)
    words = fake_encode(e, [value])
    assert e.encode([value]) == words
    assert e.decode(words)[0] == pytest.approx(value, rel=1e-6)
    assert fake_decode(e, e.encode([value]))[0] == pytest.approx(value, rel=1e-6)


def test_word_order_matches_hand_worked_registers():
    # igus manual: least significant register first. -1 in int32 is 0xFFFF 0xFFFF; 70000 is 0x0001 0x1170
    e = Entry("x", "input", 142, 2, "int32", "little", "big")
    assert e.encode([70000]) == [0x1170, 0x0001]
    assert Entry("x", "input", 142, 2, "int32").encode([70000]) == [0x0001, 0x1170]
    assert Entry("x", "input", 0, 2, "float32").encode([1.0]) == [0x3F80, 0x0000]


def test_values_that_do_not_fit_raise_naming_the_entry():
    e = Entry("cmd_target", "holding", 456, 6, "int16", scale=0.1, unit="deg")
    with pytest.raises(EncodingError, match=r"cmd_target\[0\] = 4000 deg is 40000 in int16 units"):
        e.encode([4000.0] + [0.0] * 5)
    with pytest.raises(EncodingError, match="not a finite number"):
        e.encode([math.nan] + [0.0] * 5)


def test_grouping_one_read_per_sample_where_addresses_allow():
    regmap = resolve_map(_opts())
    sample = [regmap[n] for n in ("joint_angles", "joint_efforts", "joint_revolutions")]
    blocks = group_reads(sample, regmap.bridge_gaps)
    assert [(b.table, b.address, b.count) for b in blocks] == [("holding", 270, 56)]
    assert len(group_reads(sample, 0)) == 3  # a device that answers no undefined address: one read each
    writes = group_writes([regmap[n] for n in ("cmd_target", "cmd_speed", "cmd_accel", "cmd_kind", "cmd_seq")])
    assert [(b.address, b.count) for b in writes] == [(128, 15), (148, 1)]  # never across a gap
