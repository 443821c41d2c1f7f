"""The Dynamixel control tables and unit conversions (haptic_teleop/plants/dynamixel/tables.py)."""

import itertools
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from haptic_teleop.plants.dynamixel import tables as t

MODELS = list(t.MODELS.values())


@pytest.mark.parametrize("m", MODELS, ids=lambda m: m.name)
def test_no_two_fields_overlap_and_every_field_fits(m):
    spans = sorted((f.address, f.end, f.name) for f in m.fields)
    for (a0, e0, n0), (a1, _e1, n1) in itertools.pairwise(spans):
        assert e0 <= a1, f"{n0} [{a0}, {e0}) overlaps {n1} at {a1}"
    assert all(0 <= f.address and f.end <= m.table_size for f in m.fields)
    assert all(f.size in (1, 2, 4) for f in m.fields)
    names = [f.name for f in m.fields]
    assert len(names) == len(set(names))


@pytest.mark.parametrize("m", MODELS, ids=lambda m: m.name)
def test_named_addresses_match_the_table(m):
    for const, name in [
        ("ADDR_MODEL_NUMBER", "model_number"),
        ("ADDR_FIRMWARE_VERSION", "firmware_version"),
        ("ADDR_ID", "id"),
        ("ADDR_BAUD_RATE", "baud_rate"),
        ("ADDR_RETURN_DELAY_TIME", "return_delay_time"),
        ("ADDR_DRIVE_MODE", "drive_mode"),
        ("ADDR_OPERATING_MODE", "operating_mode"),
        ("ADDR_HOMING_OFFSET", "homing_offset"),
        ("ADDR_CURRENT_LIMIT", "current_limit"),
        ("ADDR_VELOCITY_LIMIT", "velocity_limit"),
        ("ADDR_MAX_POSITION_LIMIT", "max_position_limit"),
        ("ADDR_MIN_POSITION_LIMIT", "min_position_limit"),
        ("ADDR_SHUTDOWN", "shutdown"),
        ("ADDR_TORQUE_ENABLE", "torque_enable"),
        ("ADDR_LED", "led"),
        ("ADDR_STATUS_RETURN_LEVEL", "status_return_level"),
        ("ADDR_REGISTERED_INSTRUCTION", "registered_instruction"),
        ("ADDR_HARDWARE_ERROR_STATUS", "hardware_error_status"),
        ("ADDR_BUS_WATCHDOG", "bus_watchdog"),
        ("ADDR_GOAL_CURRENT", "goal_current"),
        ("ADDR_GOAL_VELOCITY", "goal_velocity"),
        ("ADDR_GOAL_POSITION", "goal_position"),
        ("ADDR_REALTIME_TICK", "realtime_tick"),
        ("ADDR_MOVING", "moving"),
        ("ADDR_PRESENT_CURRENT", "present_current"),
        ("ADDR_PRESENT_VELOCITY", "present_velocity"),
        ("ADDR_PRESENT_POSITION", "present_position"),
        ("ADDR_PRESENT_INPUT_VOLTAGE", "present_input_voltage"),
        ("ADDR_PRESENT_TEMPERATURE", "present_temperature"),
    ]:
        assert getattr(t, const) == m.field(name).address, const
    # The per-tick state block is contiguous: current, velocity, position.
    cur, vel, pos = m.field("present_current"), m.field("present_velocity"), m.field("present_position")
    assert cur.end == vel.address and vel.end == pos.address
    assert t.STATE_BLOCK_ADDRESS == cur.address and t.STATE_BLOCK_SIZE == pos.end - cur.address
    # EEPROM is everything below Torque Enable, RAM from it on.
    te = m.field("torque_enable").address
    assert all((f.area == "EEPROM") == (f.address < te) for f in m.fields)


def test_model_facts():
    assert t.XM430_W350.model_number == 1020 and t.XM540_W270.model_number == 1120
    assert t.XM430_W350.current_limit_max == 1193 and t.XM540_W270.current_limit_max == 2047
    assert t.XM430_W350.field("current_limit").default == 1193
    # The project's torque constants (docs/models.md) are stall torque / stall current at 12 V.
    for m in MODELS:
        assert m.torque_constant_nm_per_a == pytest.approx(m.stall_torque_nm / m.stall_current_a, abs=1e-3)
    assert t.MODELS_BY_NUMBER[1120] is t.XM540_W270
    with pytest.raises(ValueError, match="known"):
        t.model("XM999")


@pytest.mark.parametrize("m", MODELS, ids=lambda m: m.name)
def test_default_table_holds_the_defaults(m):
    table = m.default_table()
    assert len(table) == m.table_size
    for f in m.fields:
        if f.default is not None:
            assert f.decode(table[f.address : f.end]) == f.default, f.name
            if f.low is not None and f.high is not None:
                assert f.low <= f.default <= f.high or f.name == "bus_watchdog", f.name


def test_baud_codes():
    assert t.BAUD_RATES_BPS[3] == 1_000_000 and t.BAUD_RATES_BPS[6] == 4_000_000
    assert t.baud_code(4_500_000) == 7
    with pytest.raises(ValueError, match="allowed"):
        t.baud_code(250_000)


def test_hardware_error_decoding():
    bits = t.decode_hardware_error(0b0010_0101)
    assert [b.bit for b in bits] == [0, 2, 5]
    text = t.describe_hardware_error(0b0010_0000)
    assert text.startswith("overload error") and "REBOOT" in text
    assert "unknown" in t.describe_hardware_error(0x02)
    assert t.describe_hardware_error(0) == "no hardware error"


def test_signed_fields_round_trip_and_refuse_overflow():
    f = t.XM430_W350.field("goal_current")
    assert f.decode(f.encode(-5)) == -5 and f.encode(-1) == b"\xff\xff"
    with pytest.raises(ValueError, match="does not fit"):
        f.encode(40000)
    w = t.XM430_W350.field("bus_watchdog")
    assert w.decode(b"\xff") == -1


@given(st.integers(-2047, 2047), st.floats(0.5, 5.0))
def test_current_units_round_trip(units, k_t):
    tau = t.current_units_to_torque_nm(units, k_t)
    assert t.torque_nm_to_current_units(tau, k_t) == units


@given(st.floats(-100.0, 100.0), st.sampled_from([t.XM430_W350, t.XM540_W270]))
def test_torque_to_current_rounds_to_nearest_and_clips(tau, m):
    k_t = m.torque_constant_nm_per_a
    lim = m.current_limit_max
    u = t.torque_nm_to_current_units(tau, k_t, lim)
    assert -lim <= u <= lim
    exact = tau / (k_t * t.CURRENT_UNIT_A)
    if abs(exact) <= lim - 1:
        assert abs(u - exact) <= 0.5 + 1e-9


@given(st.integers(-(2**20), 2**20))
def test_position_round_trip(ticks):
    assert t.rad_to_position_ticks(t.position_ticks_to_rad(ticks)) == ticks


@given(st.integers(-1023, 1023))
def test_velocity_round_trip(units):
    assert t.rad_per_s_to_velocity_units(t.velocity_units_to_rad_per_s(units)) == units


def test_unit_values():
    assert t.position_ticks_to_rad(4096) == pytest.approx(2 * math.pi)
    assert t.velocity_units_to_rad_per_s(1) == pytest.approx(0.229 * 2 * math.pi / 60)
    assert t.rad_per_s_to_velocity_units(10.0, limit_units=350) == 350
    assert t.wire_time_s(100, 1_000_000) == pytest.approx(1e-3)
    with pytest.raises(ValueError, match="> 0"):
        t.torque_nm_to_current_units(1.0, 0.0)
