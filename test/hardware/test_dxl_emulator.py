"""The Dynamixel bus emulator in its own process, spoken to by the unmodified dynamixel_sdk only.

The emulator runs in lockstep time (physics advances a fixed step per Goal Current write) where a
test checks motion, so the expected numbers come from the physics, not from the clock. No test
asserts a wall-clock duration; waits are safety nets or "the host goes quiet" by far more than
the configured time. A rule of the servo alone (switching Operating Mode) is also checked on a
real `Servo`, without a process.
"""

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from haptic_teleop.emulators.dynamixel.config import BusConfig, ServoConfig
from haptic_teleop.emulators.dynamixel.process import start_bus
from haptic_teleop.emulators.dynamixel.servo import Servo
from haptic_teleop.plants.dynamixel import tables as t
from haptic_teleop.plants.dynamixel.chain import DynamixelChainConfig, DynamixelJoint
from haptic_teleop.plants.dynamixel.driver import DynamixelDriver

BAUD = 1_000_000
FAST = {"return_delay_time": 0, "operating_mode": 0}


def inertia_cfg(servos, joints, **extra):
    return BusConfig.from_dict(
        {
            "baud_bps": BAUD,
            "time": {"mode": "lockstep", "lockstep_dt_s": 0.001},
            "physics": {"kind": "inertia", "dt_s": 0.0005, "joints": joints},
            "servos": servos,
            **extra,
        }
    )


def one_servo(**extra):
    return inertia_cfg(
        [{"id": 1, "model": "XM430-W350", "joint": "j", "registers": FAST}],
        [{"name": "j", "inertia_kg_m2": 0.01, "viscous_nm_s_per_rad": 0.1}],
        **extra,
    )


@pytest.fixture
def sdk():
    ports = []

    def open_(bus):
        port = PortHandler(bus.port)
        assert port.openPort()
        assert port.setBaudRate(BAUD)
        ports.append(port)
        return port, PacketHandler(2.0)

    yield open_
    for p in ports:
        p.closePort()


def read_when_the_line_is_free(ph, port, servo_id, address, tries=10):
    """A 4-byte READ, repeated while it times out behind traffic still on the emulated wire."""
    for _ in range(tries):
        value, result, error = ph.read4ByteTxRx(port, servo_id, address)
        if result == COMM_SUCCESS:
            assert error == 0
            return value
    raise AssertionError(f"servo {servo_id} did not answer a READ of {address} in {tries} tries: {result}")


def sync_read(gsr, port):
    """A SYNC READ expected to succeed: sent, then its replies read with a 2 s timeout (set through
    the SDK's `setPacketTimeoutMillis`, as the project's driver does) instead of the SDK's 34 ms
    (LATENCY_TIMER 16 ms x 2 + 2 ms): the emulator's process can be held back longer than that on
    this shared 2-core machine, which is not what these tests check."""
    result = gsr.txPacket()
    if result != COMM_SUCCESS:
        return result
    port.setPacketTimeoutMillis(2000.0)
    return gsr.rxPacket()


def s16(v):
    return v - (1 << 16) if v & 0x8000 else v


def s32(v):
    return v - (1 << 32) if v & 0x80000000 else v


def test_ping_read_write_and_the_write_rules(sdk):
    cfg = inertia_cfg(
        [
            {"id": 1, "model": "XM540-W270", "joint": "a", "registers": FAST},
            {"id": 7, "model": "XM430-W350", "joint": "b", "registers": FAST},
        ],
        [{"name": "a", "inertia_kg_m2": 0.01}, {"name": "b", "inertia_kg_m2": 0.01}],
    )
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        assert ph.ping(port, 1)[:2] == (1120, COMM_SUCCESS)
        assert ph.ping(port, 7)[:2] == (1020, COMM_SUCCESS)
        assert ph.ping(port, 3)[1] == COMM_RX_TIMEOUT  # no such servo
        found, res = ph.broadcastPing(port)
        assert res == COMM_SUCCESS and sorted(found) == [1, 7] and found[7][0] == 1020
        # a RAM field: LED
        assert ph.write1ByteTxRx(port, 7, t.ADDR_LED, 1) == (COMM_SUCCESS, 0)
        assert ph.read1ByteTxRx(port, 7, t.ADDR_LED) == (1, COMM_SUCCESS, 0)
        # an EEPROM field: writable with torque off, access error with torque on
        assert ph.write2ByteTxRx(port, 7, t.ADDR_CURRENT_LIMIT, 600) == (COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 7, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        assert ph.write2ByteTxRx(port, 7, t.ADDR_CURRENT_LIMIT, 500) == (COMM_SUCCESS, t.StatusError.ACCESS)
        assert ph.read2ByteTxRx(port, 7, t.ADDR_CURRENT_LIMIT)[0] == 600
        # Goal Current within +-Current Limit; beyond: data range error, value unchanged
        assert ph.write2ByteTxRx(port, 7, t.ADDR_GOAL_CURRENT, (-600) & 0xFFFF) == (COMM_SUCCESS, 0)
        assert ph.write2ByteTxRx(port, 7, t.ADDR_GOAL_CURRENT, 601) == (COMM_SUCCESS, t.StatusError.DATA_RANGE)
        assert s16(ph.read2ByteTxRx(port, 7, t.ADDR_GOAL_CURRENT)[0]) == -600
        # read-only field
        assert ph.write4ByteTxRx(port, 1, t.ADDR_PRESENT_POSITION, 0)[1] == t.StatusError.ACCESS
        assert ph.read2ByteTxRx(port, 1, t.ADDR_MODEL_NUMBER)[0] == 1120
    assert bus.proc.returncode == 0


def test_sync_write_then_sync_read_and_fast_sync_read_agree(sdk):
    cfg = inertia_cfg(
        [{"id": i, "model": "XM430-W350", "joint": f"j{i}", "registers": FAST} for i in (1, 2, 3)],
        [{"name": f"j{i}", "inertia_kg_m2": 0.02, "viscous_nm_s_per_rad": 0.05} for i in (1, 2, 3)],
    )
    goals = {1: 100, 2: -250, 3: 1193}
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        for i in goals:
            assert ph.write1ByteTxRx(port, i, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        gsw = GroupSyncWrite(port, ph, t.ADDR_GOAL_CURRENT, 2)
        for i, g in goals.items():
            assert gsw.addParam(i, list((g & 0xFFFF).to_bytes(2, "little")))
        gsr = GroupSyncRead(port, ph, t.STATE_BLOCK_ADDRESS, t.STATE_BLOCK_SIZE)
        for i in goals:
            assert gsr.addParam(i)
        for _ in range(20):
            assert gsw.txPacket() == COMM_SUCCESS
        assert sync_read(gsr, port) == COMM_SUCCESS
        normal = {i: [gsr.getData(i, a, n) for a, n in ((126, 2), (128, 4), (132, 4))] for i in goals}
        assert gsr.fastSyncRead() == COMM_SUCCESS
        fast = {i: [gsr.getData(i, a, n) for a, n in ((126, 2), (128, 4), (132, 4))] for i in goals}
    assert fast == normal
    for i, g in goals.items():
        cur, vel, pos = s16(normal[i][0]), s32(normal[i][1]), s32(normal[i][2])
        assert cur == g
        assert (vel > 0) == (g > 0) and (pos > 2048) == (g > 0)


def test_constant_current_accelerates_in_the_sense_of_the_sign_and_viscous_joint_settles_at_tau_over_b(sdk):
    k_true = 2.0  # the emulated servo's true torque constant, not the model's 2.409
    b, inertia = 0.5, 0.005
    cfg = inertia_cfg(
        [
            {"id": 1, "model": "XM540-W270", "joint": "fwd", "registers": FAST, "torque_constant_nm_per_a": k_true},
            {"id": 2, "model": "XM540-W270", "joint": "rev", "registers": FAST, "sign": -1},
        ],
        [
            {"name": "fwd", "inertia_kg_m2": inertia, "viscous_nm_s_per_rad": b},
            {"name": "rev", "inertia_kg_m2": 0.01},
        ],
    )
    goal = 150
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        for i in (1, 2):
            assert ph.write1ByteTxRx(port, i, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        gsw = GroupSyncWrite(port, ph, t.ADDR_GOAL_CURRENT, 2)
        gsw.addParam(1, [goal, 0])
        gsw.addParam(2, [goal, 0])
        for _ in range(200):  # 0.2 s of lockstep time: 40 time constants I/b
            assert gsw.txPacket() == COMM_SUCCESS
        # The 200 packets (4 kB, 41 ms at 1 Mbps) are on the emulated wire before the first read's
        # reply can be: a read sent at once may time out in the SDK (about 34 ms) while they pass.
        vel_units = s32(read_when_the_line_is_free(ph, port, 1, t.ADDR_PRESENT_VELOCITY))
        state = bus.state()
        pos2 = s32(read_when_the_line_is_free(ph, port, 2, t.ADDR_PRESENT_POSITION))
    tau = goal * 2.69e-3 * k_true
    v_expected = tau / b  # rad/s, from the physics: I dv/dt = tau - b v
    v_read = vel_units * 0.229 * 2 * math.pi / 60
    assert abs(v_read - v_expected) <= 0.229 * 2 * math.pi / 60  # one register unit
    assert state["time_s"] == pytest.approx(0.2)
    # sign -1: a positive goal current turns the joint negative; the servo reports its own frame
    q_rev = state["q_rad"][state["joints"].index("rev")]
    assert q_rev < -0.1 and pos2 > 2048


def test_mujoco_arm_moves_with_the_current_and_counters_charge_the_wire(sdk):
    cfg = BusConfig.from_dict(
        {
            "baud_bps": BAUD,
            "usb_latency_s": 0.001,
            "time": {"mode": "lockstep", "lockstep_dt_s": 0.001},
            "physics": {"kind": "mujoco", "model": "dxl_arm.xml"},
            "servos": [
                {"id": 1, "model": "XM540-W270", "joint": "base_yaw", "sign": -1, "registers": FAST},
                {
                    "id": 2,
                    "model": "XM540-W270",
                    "joint": "shoulder",
                    "registers": {"return_delay_time": 10, "operating_mode": 0},
                },
                {"id": 3, "model": "XM430-W350", "joint": "elbow", "registers": FAST},
            ],
        }
    )
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        gsw = GroupSyncWrite(port, ph, t.ADDR_GOAL_CURRENT, 2)
        gsw.addParam(1, [200, 0])
        gsr = GroupSyncRead(port, ph, t.STATE_BLOCK_ADDRESS, t.STATE_BLOCK_SIZE)
        for i in (1, 2, 3):
            gsr.addParam(i)
        for _ in range(100):
            assert sync_read(gsr, port) == COMM_SUCCESS
            assert gsw.txPacket() == COMM_SUCCESS
        state = bus.state()
        counters = bus.stop()
    yaw = state["q_rad"][state["joints"].index("base_yaw")]
    assert yaw < -0.01  # sign -1
    # every byte both ways at 10 bits a byte, and the return delays and USB latency charged per reply
    total = counters["bytes_in"] + counters["bytes_out"]
    assert counters["wire_time_s"] == pytest.approx(total * 10 / BAUD, rel=1e-9)
    replies_by_2 = 100 + 0  # one per sync read; the write was to servo 1
    assert counters["return_delay_s"] == pytest.approx(replies_by_2 * 10 * 2e-6, rel=1e-9)
    assert counters["usb_latency_s"] == pytest.approx(counters["status_packets"] * 0.001, rel=1e-9)
    assert counters["status_packets"] == 1 + 300


def test_hardware_error_sets_alert_and_shuts_down_until_reboot(sdk):
    # overload (bit 5) at the 4th instruction; Shutdown's default 52 includes bit 5
    cfg = one_servo(faults=[{"servo_id": 1, "kind": "hardware_error", "bits": 32, "at_transaction": 4}])
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)  # 1
        assert ph.write2ByteTxRx(port, 1, t.ADDR_GOAL_CURRENT, 50) == (COMM_SUCCESS, 0)  # 2
        assert ph.read1ByteTxRx(port, 1, t.ADDR_HARDWARE_ERROR_STATUS) == (0, COMM_SUCCESS, 0)  # 3
        value, res, err = ph.read1ByteTxRx(port, 1, t.ADDR_HARDWARE_ERROR_STATUS)  # 4: the fault
        assert (value, res) == (32, COMM_SUCCESS) and err & t.ALERT_BIT
        assert t.describe_hardware_error(value).startswith("overload error")
        assert ph.read1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE)[0] == 0  # shut down
        assert ph.read2ByteTxRx(port, 1, t.ADDR_PRESENT_CURRENT)[0] == 0
        assert ph.ping(port, 1)[2] & t.ALERT_BIT  # every status packet, PING's too
        assert ph.write1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE, 1)[1] & 0x7F == t.StatusError.RESULT_FAIL
        assert ph.reboot(port, 1) == (COMM_SUCCESS, t.ALERT_BIT)  # answered before rebooting
        assert ph.read1ByteTxRx(port, 1, t.ADDR_HARDWARE_ERROR_STATUS) == (0, COMM_SUCCESS, 0)
        assert ph.read1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE)[0] == 0
        assert ph.write1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)


def test_hardware_error_outside_the_shutdown_mask_keeps_torque(sdk):
    with start_bus(one_servo()) as bus:
        port, ph = sdk(bus)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        bus.inject(servo_id=1, kind="hardware_error", bits=1)  # input voltage: not in Shutdown 52
        value, res, err = ph.read1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE)
        assert (value, res) == (1, COMM_SUCCESS) and err == t.ALERT_BIT


def test_dropped_corrupted_and_vanished_replies(sdk):
    with start_bus(one_servo()) as bus:
        port, ph = sdk(bus)
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
        bus.inject(servo_id=1, kind="drop_replies", count=2)
        assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
        assert ph.read1ByteTxRx(port, 1, t.ADDR_LED)[1] == COMM_RX_TIMEOUT
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
        bus.inject(servo_id=1, kind="corrupt_crc", count=1)
        assert ph.ping(port, 1)[1] == COMM_RX_CORRUPT
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
        bus.inject(servo_id=1, kind="vanish")
        for _ in range(3):
            assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
        counters = bus.counters()
    assert counters["dropped_replies"] == 2 and counters["corrupted_replies"] == 1


def test_fast_sync_read_faults_of_any_servo_in_the_packet(sdk):
    cfg = inertia_cfg(
        [{"id": i, "model": "XM430-W350", "joint": f"j{i}", "registers": FAST} for i in (1, 2, 3)],
        [{"name": f"j{i}", "inertia_kg_m2": 0.02} for i in (1, 2, 3)],
    )
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        gsr = GroupSyncRead(port, ph, t.STATE_BLOCK_ADDRESS, t.STATE_BLOCK_SIZE)
        for i in (1, 2, 3):
            gsr.addParam(i)
        assert gsr.fastSyncRead() == COMM_SUCCESS
        bus.inject(servo_id=3, kind="corrupt_crc", count=1)  # the last part damaged
        assert gsr.fastSyncRead() == COMM_RX_CORRUPT
        bus.inject(servo_id=2, kind="corrupt_crc", count=1)  # a middle part damaged
        assert gsr.fastSyncRead() == COMM_RX_CORRUPT
        bus.inject(servo_id=2, kind="drop_replies", count=1)  # servo 1's part came, 2's never did
        assert gsr.fastSyncRead() == COMM_RX_CORRUPT
        bus.inject(servo_id=1, kind="drop_replies", count=1)  # nothing came
        assert gsr.fastSyncRead() == COMM_RX_TIMEOUT
        assert gsr.fastSyncRead() == COMM_SUCCESS
        bus.inject(servo_id=3, kind="vanish")
        assert gsr.fastSyncRead() == COMM_RX_CORRUPT
        assert gsr.txRxPacket() == COMM_RX_TIMEOUT  # plain SYNC READ: servo 3 silent


def test_old_firmware_does_not_answer_fast_sync_read(sdk):
    cfg = inertia_cfg(
        [{"id": 1, "model": "XM430-W350", "joint": "j", "registers": FAST, "firmware_version": 44}],
        [{"name": "j", "inertia_kg_m2": 0.02}],
    )
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        gsr = GroupSyncRead(port, ph, t.STATE_BLOCK_ADDRESS, t.STATE_BLOCK_SIZE)
        gsr.addParam(1)
        assert ph.ping(port, 1) == (1020, COMM_SUCCESS, 0) and ph.read1ByteTxRx(port, 1, 6)[0] == 44
        assert gsr.fastSyncRead() == COMM_RX_TIMEOUT
        assert gsr.txRxPacket() == COMM_SUCCESS


def test_realtime_physics_follows_the_clock(sdk):
    cfg = BusConfig.from_dict(
        {
            "physics": {"kind": "inertia", "joints": [{"name": "j", "inertia_kg_m2": 0.01}]},
            "servos": [{"id": 1, "model": "XM430-W350", "joint": "j", "registers": FAST}],
        }
    )
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        assert ph.write2ByteTxRx(port, 1, t.ADDR_GOAL_CURRENT, 100) == (COMM_SUCCESS, 0)
        first = bus.state()
        time.sleep(0.2)
        vel = s32(ph.read4ByteTxRx(port, 1, t.ADDR_PRESENT_VELOCITY)[0])
        tick = ph.read2ByteTxRx(port, 1, t.ADDR_REALTIME_TICK)[0]
        second = bus.state()
    assert second["time_s"] > first["time_s"] and tick > 0 and vel > 0
    # constant torque between the two looks: dv = tau dt / I over the emulator's own time
    tau = 100 * 2.69e-3 * t.XM430_W350.torque_constant_nm_per_a
    dv = second["qd_rad_per_s"][0] - first["qd_rad_per_s"][0]
    assert dv == pytest.approx(tau * (second["time_s"] - first["time_s"]) / 0.01, rel=1e-6)


def test_slow_reply_arrives_after_the_host_gave_up(sdk):
    with start_bus(one_servo()) as bus:
        port, ph = sdk(bus)
        bus.inject(servo_id=1, kind="slow_replies", count=1, extra_delay_s=2.0)
        assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT  # the SDK waits about 34 ms at 1 Mbps
        time.sleep(2.5)  # the late reply lands on the line; the next transaction clears it
        assert ph.ping(port, 1)[:2] == (1020, COMM_SUCCESS)
        counters = bus.counters()
    assert counters["slowed_replies"] == 1 and counters["extra_delay_s"] == pytest.approx(2.0)


def test_bus_watchdog_stops_a_servo_when_the_host_goes_quiet(sdk):
    # real time: the watchdog's clock is the wall clock (in lockstep the emulator's own time, which
    # a quiet host does not advance: test_dxl_driver.test_a_lockstep_emulator_keeps_the_watchdog_...)
    with start_bus(one_servo(time={"mode": "realtime"})) as bus:
        port, ph = sdk(bus)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        assert ph.write2ByteTxRx(port, 1, t.ADDR_GOAL_CURRENT, 80) == (COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_BUS_WATCHDOG, 5) == (COMM_SUCCESS, 0)  # 100 ms
        time.sleep(1.0)  # the host goes quiet for 10 x the watchdog time
        assert ph.read1ByteTxRx(port, 1, t.ADDR_BUS_WATCHDOG)[:2] == (0xFF, COMM_SUCCESS)  # -1
        assert ph.read2ByteTxRx(port, 1, t.ADDR_PRESENT_CURRENT)[0] == 0  # stopped
        assert ph.read1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE)[:2] == (1, COMM_SUCCESS)  # torque stays on
        assert ph.write2ByteTxRx(port, 1, t.ADDR_GOAL_CURRENT, 10) == (COMM_SUCCESS, t.StatusError.DATA_RANGE)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_BUS_WATCHDOG, 0) == (COMM_SUCCESS, 0)  # clears it
        assert ph.write2ByteTxRx(port, 1, t.ADDR_GOAL_CURRENT, 10) == (COMM_SUCCESS, 0)
        assert ph.read2ByteTxRx(port, 1, t.ADDR_PRESENT_CURRENT)[0] == 10
        assert bus.counters()["watchdog_trips"] == 1


# ---------------------------------------------------------------- switching Operating Mode(11)
# e-Manual, XM430-W350 page, "Operating Mode(11)": "Switching Operating Mode will reset ... Profile
# Velocity(112), Profile Acceleration(108) : Reset to '0'; Goal PWM(100), Goal Current(102) : Reset
# to PWM Limit(36), Current Limit(38) respectively".


def write_field(servo, name, value):
    """A host's WRITE of one field, by name, through the servo's rules; its error number."""
    f = servo.model.field(name)
    return servo.write(f.address, f.encode(value))


def test_switching_operating_mode_resets_goal_pwm_goal_current_and_the_profile():
    servo = Servo(ServoConfig(id=1, model="XM430-W350", joint="j"), BAUD)  # factory: position mode (3)
    before = {
        "pwm_limit": 500,
        "current_limit": 600,
        "goal_pwm": -100,
        "goal_current": -50,
        "goal_velocity": 30,
        "profile_acceleration": 10,
        "profile_velocity": 20,
        "goal_position": 1000,
    }
    for name, value in before.items():
        assert write_field(servo, name, value) == 0, name
    assert write_field(servo, "operating_mode", t.OPERATING_MODE_CURRENT) == 0
    after = {name: servo.get(name) for name in before}
    # the limits, Goal Velocity and Goal Position are not in the e-Manual's list: kept
    assert after == {**before, "goal_pwm": 500, "goal_current": 600, "profile_acceleration": 0, "profile_velocity": 0}
    # the same mode again is no switch
    assert write_field(servo, "goal_current", 5) == 0
    assert write_field(servo, "operating_mode", t.OPERATING_MODE_CURRENT) == 0
    assert servo.get("goal_current") == 5
    # a refused write switches nothing: a packet from Operating Mode(11) through Goal Current(102)
    # (it covers the gap 14..19), and the mode written with the torque on (EEPROM)
    packet = bytes([t.OPERATING_MODE_POSITION]) + bytes(servo.table[12 : t.ADDR_GOAL_CURRENT + 2])
    assert servo.write(t.ADDR_OPERATING_MODE, packet) == t.StatusError.ACCESS
    assert write_field(servo, "torque_enable", 1) == 0
    assert write_field(servo, "operating_mode", t.OPERATING_MODE_POSITION) == t.StatusError.ACCESS
    assert servo.get("operating_mode") == t.OPERATING_MODE_CURRENT and servo.get("goal_current") == 5


def test_torque_on_after_a_mode_switch_without_a_new_goal_current_applies_the_current_limit():
    careless = Servo(ServoConfig(id=1, model="XM540-W270", joint="j"), BAUD)
    careful = Servo(ServoConfig(id=2, model="XM540-W270", joint="j"), BAUD)
    for servo in (careless, careful):
        assert write_field(servo, "current_limit", 1500) == 0
        assert write_field(servo, "operating_mode", t.OPERATING_MODE_CURRENT) == 0
    assert write_field(careful, "goal_current", 0) == 0
    for servo in (careless, careful):
        assert write_field(servo, "torque_enable", 1) == 0
    assert careless.applied_current_units() == 1500  # full current: the whole Current Limit
    assert careful.applied_current_units() == 0


def test_over_the_wire_a_mode_switch_then_torque_on_drives_the_current_limit(sdk):
    cfg = inertia_cfg(
        [{"id": 1, "model": "XM430-W350", "joint": "j", "registers": {"return_delay_time": 0}}],
        [{"name": "j", "inertia_kg_m2": 0.01, "viscous_nm_s_per_rad": 0.1}],
    )
    with start_bus(cfg) as bus:
        port, ph = sdk(bus)
        assert ph.read1ByteTxRx(port, 1, t.ADDR_OPERATING_MODE) == (t.OPERATING_MODE_POSITION, COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_OPERATING_MODE, t.OPERATING_MODE_CURRENT) == (COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        assert ph.read2ByteTxRx(port, 1, t.ADDR_GOAL_CURRENT) == (1193, COMM_SUCCESS, 0)
        assert ph.read2ByteTxRx(port, 1, t.ADDR_PRESENT_CURRENT) == (1193, COMM_SUCCESS, 0)
        torque_nm = bus.state()["torque_nm"][0]
    assert torque_nm == pytest.approx(1193 * t.CURRENT_UNIT_A * t.XM430_W350.torque_constant_nm_per_a)


def test_the_driver_start_up_turns_the_torque_on_at_goal_current_0_after_its_mode_switch(sdk):
    # factory EEPROM (position mode): the driver's Operating Mode(11) write is a switch
    cfg = inertia_cfg(
        [{"id": i, "model": "XM430-W350", "joint": f"j{i}"} for i in (1, 2)],
        [{"name": f"j{i}", "inertia_kg_m2": 0.01, "viscous_nm_s_per_rad": 0.1} for i in (1, 2)],
    )
    joints = tuple(DynamixelJoint(f"j{i}", i, "XM430-W350", current_limit=400) for i in (1, 2))
    with start_bus(cfg) as bus:
        # A loaded machine that leaves the emulator unscheduled for a few reads must not end the start.
        chain = DynamixelChainConfig(bus.port, joints, bus_watchdog_s=1.0, read_timeout_s=0.05,
                                     max_consecutive_comm_errors=20)  # fmt: skip
        with DynamixelDriver(chain) as drv:
            first = drv.start()  # returns with the torque on
            torque_nm = bus.state()["torque_nm"]
        port, ph = sdk(bus)  # the driver closed the port
        goal_pwm = [s16(ph.read2ByteTxRx(port, i, t.ADDR_GOAL_PWM)[0]) for i in (1, 2)]
    np.testing.assert_array_equal(first.tau_nm, [0.0, 0.0])  # Present Current 0 at torque on
    assert torque_nm == [0.0, 0.0]
    # Goal PWM, which the driver never writes, holds what the switch left: PWM Limit(36)
    assert goal_pwm == [885, 885]


def test_status_return_level_zero_answers_only_ping(sdk):
    with start_bus(one_servo()) as bus:
        port, ph = sdk(bus)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_STATUS_RETURN_LEVEL, 0) == (COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, 1, t.ADDR_LED, 1)[0] == COMM_RX_TIMEOUT
        assert ph.read1ByteTxRx(port, 1, t.ADDR_LED)[1] == COMM_RX_TIMEOUT
        assert ph.ping(port, 1)[1] == COMM_SUCCESS


def test_lockstep_runs_are_identical(sdk):
    def run():
        cfg = BusConfig.from_dict(
            {
                "time": {"mode": "lockstep", "lockstep_dt_s": 0.002},
                "physics": {"kind": "mujoco", "hand": {"speed_m_per_s": 0.1, "distance_m": 0.05}},
                "servos": [
                    {"id": i + 1, "model": m, "joint": j, "registers": FAST}
                    for i, (m, j) in enumerate(
                        [("XM540-W270", "base_yaw"), ("XM540-W270", "shoulder"), ("XM430-W350", "elbow")]
                    )
                ],
            }
        )
        with start_bus(cfg) as bus:
            port, ph = sdk(bus)
            gsw = GroupSyncWrite(port, ph, t.ADDR_GOAL_CURRENT, 2)
            for i in (1, 2, 3):
                ph.write1ByteTxRx(port, i, t.ADDR_TORQUE_ENABLE, 1)
                gsw.addParam(i, [30, 0])
            for _ in range(50):
                gsw.txPacket()
            return bus.state()["q_rad"]

    first = run()
    assert first == run()
    assert first != [0.0, 0.0, 0.0]


@pytest.mark.parametrize(
    "entry", [["-m", "haptic_teleop.emulators.dynamixel"], ["-m", "haptic_teleop.cli", "emulate", "dynamixel"]]
)
def test_bad_config_is_one_line_and_exit_2(tmp_path, entry):
    bad = tmp_path / "bus.json"
    bad.write_text(json.dumps({"servos": [{"id": 1, "model": "XM430-W350", "joint": "elbow", "sign": 2}]}))
    r = subprocess.run([sys.executable, *entry, "--config", str(bad)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "servos[0].sign" in r.stderr and "Traceback" not in r.stderr


def test_the_emulator_dies_with_its_parent(tmp_path):
    script = textwrap.dedent(
        f"""
        import os, signal, sys
        sys.path.insert(0, {os.getcwd()!r})
        from haptic_teleop.emulators.dynamixel.config import BusConfig
        from haptic_teleop.emulators.dynamixel.process import start_bus
        bus = start_bus(BusConfig.from_json({one_servo().to_json()!r}))
        print(bus.pid, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert r.returncode == -signal.SIGKILL
    pid = int(r.stdout.split()[0])
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    os.kill(pid, signal.SIGKILL)
    pytest.fail(f"the emulator {pid} outlived its killed parent")


def test_the_emulator_runs_at_the_priority_of_hardware_where_permitted():
    # a servo never waits for the host's scheduler: the emulator asks for HARDWARE_NICE (root or
    # CAP_SYS_NICE); elsewhere it keeps the niceness it was started with
    from haptic_teleop.lifetime import HARDWARE_NICE

    mine = os.getpriority(os.PRIO_PROCESS, 0)
    with start_bus(one_servo()) as bus:
        nice = os.getpriority(os.PRIO_PROCESS, bus.pid)
    # permitted here? (asked in a child, so this process keeps its own niceness)
    probe = [sys.executable, "-c", f"import os; os.setpriority(os.PRIO_PROCESS, 0, {HARDWARE_NICE})"]
    permitted = subprocess.run(probe, capture_output=True).returncode == 0
    assert nice == (min(HARDWARE_NICE, mine) if permitted else mine)
