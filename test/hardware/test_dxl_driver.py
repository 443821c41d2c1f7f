"""The Dynamixel driver through the unmodified `dynamixel_sdk` against the bus emulator (its own
process on a pseudo-terminal): start/read/write/stop with the units checked against the
emulator's physics, torque off on every exit path, and every emulated fault turning into one
clear HardwareError with the torque off. No SDK object is mocked or patched; the tests read the
servos' registers back through the SDK themselves."""

import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from haptic_teleop.emulators.dynamixel.config import BusConfig
from haptic_teleop.emulators.dynamixel.process import start_bus
from haptic_teleop.plants.dynamixel import tables as T
from haptic_teleop.plants.dynamixel.chain import DynamixelChainConfig, DynamixelJoint
from haptic_teleop.plants.dynamixel.driver import DynamixelDriver
from haptic_teleop.plants.hardware import HardwareError

ARM = (("base_yaw", "XM540-W270"), ("shoulder", "XM540-W270"), ("elbow", "XM430-W350"))
INERTIA = 0.01  # kg m^2
VISCOUS = 0.1  # N m s/rad: the time constant I/b is 0.1 s
START_Q = (0.3, -0.2, 0.1)
SIGNS = (1, -1, 1)
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def bus_dict(lockstep=True, firmware=(46, 46, 46), models=None, faults=(), coulomb=0.0):
    models = models or [m for _, m in ARM]
    return {
        "servos": [
            {
                "id": k + 1,
                "model": models[k],
                "joint": name,
                "sign": SIGNS[k],
                "firmware_version": firmware[k],
            }
            for k, (name, _) in enumerate(ARM)
        ],
        "baud_bps": 1_000_000,
        "time": {"mode": "lockstep" if lockstep else "realtime", "lockstep_dt_s": 0.001},
        "physics": {
            "kind": "inertia",
            "joints": [
                {
                    "name": name,
                    "inertia_kg_m2": INERTIA,
                    "viscous_nm_s_per_rad": VISCOUS,
                    "coulomb_nm": coulomb,
                    "start_q_rad": START_Q[k],
                }
                for k, (name, _) in enumerate(ARM)
            ],
        },
        "faults": list(faults),
    }


@pytest.fixture
def emulator():
    started = []

    def start(**kw):
        bus = start_bus(BusConfig.from_dict(bus_dict(**kw)))
        started.append(bus)
        return bus

    yield start
    for bus in started:
        bus.stop()


def chain(port, ids=(1, 2, 3), **kw):
    joints = tuple(
        DynamixelJoint(ARM[i - 1][0] if i <= 3 else f"extra{i}", i, ARM[(i - 1) % 3][1], sign=SIGNS[(i - 1) % 3],
                       zero_offset_rad=math.pi, current_limit=400)
        for i in ids
    )  # fmt: skip
    kw.setdefault("read_timeout_s", 0.05)
    kw.setdefault("bus_watchdog_s", 1.0)
    return DynamixelChainConfig(port, joints, **kw)


def registers(port, address, size, ids=(1, 2, 3), tries=5):
    """Read a register of every servo through the SDK (after the driver closed the port). A read
    whose reply misses the SDK's timeout (about 35 ms: the emulator's process was not scheduled in
    time on a busy machine, seen once in CI beside other jobs) is tried again, the port cleared
    first, up to `tries` times: what the callers assert is the value, not how fast it came."""
    import dynamixel_sdk as sdk

    p = sdk.PortHandler(port)
    assert p.openPort() and p.setBaudRate(1_000_000)
    ph = sdk.PacketHandler(2.0)
    out = []
    try:
        for i in ids:
            for _ in range(tries):
                data, result, _ = ph.readTxRx(p, i, address, size)
                if result != sdk.COMM_RX_TIMEOUT:
                    break
                p.clearPort()
            assert result == sdk.COMM_SUCCESS, ph.getTxRxResult(result)
            out.append(int.from_bytes(bytes(data[:size]), "little", signed=size > 1 or address == 98))
    finally:
        p.closePort()
    return out


def one_unit_nm(k):
    return T.CURRENT_UNIT_A * T.model(ARM[k][1]).torque_constant_nm_per_a


# ---------------------------------------------------------------- round trip and units


@pytest.mark.parametrize("fast", [False, True], ids=["sync-read", "fast-sync-read"])
def test_round_trip_settles_at_tau_over_b_and_stops_with_torque_off(emulator, fast):
    bus = emulator()
    # The physics and the units are under test here, not the fault detection: a loaded machine
    # that leaves the emulator process unscheduled for 3 reads (150 ms) must not end the run.
    drv = DynamixelDriver(chain(bus.port, fast_sync_read=fast, max_consecutive_comm_errors=20))
    first = drv.start()
    assert drv.fast_sync_read_used is fast
    assert first.stale == 0
    # positions in the joint frame (sign and zero offset undone) match the physics' start, within one tick
    np.testing.assert_allclose(first.q_rad, START_Q, atol=T.POSITION_UNIT_RAD)
    tau = np.array([0.3, 0.2, -0.1])
    applied = drv.write(tau)
    assert np.all(np.abs(applied - tau) <= 0.5 * np.array([one_unit_nm(k) for k in range(3)]) + 1e-12)
    ticks = 1500  # lockstep: each Goal Current write advances the physics 1 ms; 15 time constants
    for _ in range(ticks - 1):
        drv.read()
        drv.write(tau)
    s = drv.read()
    state = bus.state()
    v_ss = applied / VISCOUS
    np.testing.assert_allclose(s.qd_rad_per_s, v_ss, atol=1.5 * T.VELOCITY_UNIT_RAD_PER_S)
    np.testing.assert_allclose(s.q_rad, state["q_rad"], atol=T.POSITION_UNIT_RAD)
    np.testing.assert_allclose(s.tau_nm, applied, rtol=1e-9)
    np.testing.assert_allclose(state["torque_nm"], applied, rtol=1e-9)
    tc = INERTIA / VISCOUS
    T_s = ticks * 0.001
    travel = v_ss * (T_s - tc * (1 - math.exp(-T_s / tc)))
    np.testing.assert_allclose(s.q_rad - np.array(START_Q), travel, rtol=0.02, atol=2 * T.POSITION_UNIT_RAD)
    # A read whose reply missed the driver's timeout (the emulator process not scheduled in time on a
    # loaded machine: wall-clock, not protocol) is stale; a protocol fault would make most reads so.
    assert drv.stale_reads <= ticks // 100
    drv.stop()
    drv.stop()  # idempotent
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]
    assert registers(bus.port, T.ADDR_GOAL_CURRENT, 2) == [0, 0, 0]


def test_start_configures_current_mode_limit_return_delay_and_watchdog(emulator):
    bus = emulator()
    drv = DynamixelDriver(chain(bus.port, bus_watchdog_s=1.01, return_delay_time_s=0.0))
    drv.start()
    drv.stop()
    assert registers(bus.port, T.ADDR_OPERATING_MODE, 1) == [0, 0, 0]  # factory: 3 (position)
    assert registers(bus.port, T.ADDR_CURRENT_LIMIT, 2) == [400, 400, 400]
    assert registers(bus.port, T.ADDR_RETURN_DELAY_TIME, 1) == [0, 0, 0]  # factory: 250
    assert registers(bus.port, T.ADDR_BUS_WATCHDOG, 1) == [51, 51, 51]  # 1.01 s -> 51 x 20 ms


def test_write_rounds_clips_to_the_current_limit_and_zeroes_nan(emulator):
    bus = emulator()
    with DynamixelDriver(chain(bus.port)) as drv:
        drv.start()
        applied = drv.write(np.array([math.nan, 1e6, -math.inf]))
        limit = drv.torque_limit_nm
        np.testing.assert_allclose(applied, [0.0, limit[1], -limit[2]])
        np.testing.assert_allclose(limit, [400 * one_unit_nm(k) for k in range(3)])
        np.testing.assert_allclose(bus.state()["torque_nm"], applied, rtol=1e-9)
        with pytest.raises(ValueError, match="takes 3 torques"):
            drv.write(np.zeros(2))


# ---------------------------------------------------------------- exit paths


def test_torque_off_when_the_loop_raises(emulator):
    bus = emulator()
    with pytest.raises(RuntimeError, match="bug in the loop"), DynamixelDriver(chain(bus.port)) as drv:
        drv.start()
        for _ in range(5):
            drv.read()
            drv.write(np.array([0.5, 0.5, 0.5]))
        raise RuntimeError("bug in the loop")
    assert drv.stopped
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]
    with pytest.raises(HardwareError, match=r"read\(\) on a driver that is stopped \(torque off\)"):
        drv.read()


CHILD = """
import math, sys
import numpy as np
from haptic_teleop.interrupt import Interrupted
from haptic_teleop.plants.dynamixel.chain import DynamixelChainConfig, DynamixelJoint
from haptic_teleop.plants.dynamixel.driver import DynamixelDriver
port, guarded = sys.argv[1], sys.argv[2] in ("guarded", "cli")
if sys.argv[2] == "cli":  # the command line's handlers own the signals
    from haptic_teleop import interrupt
    interrupt.install()
arm = (("base_yaw", "XM540-W270"), ("shoulder", "XM540-W270"), ("elbow", "XM430-W350"))
joints = tuple(DynamixelJoint(n, k + 1, m, zero_offset_rad=math.pi, current_limit=400) for k, (n, m) in enumerate(arm))
cfg = DynamixelChainConfig(port, joints, bus_watchdog_s=1.0 if guarded else 0.3, read_timeout_s=0.5)
tau = np.array([0.2, 0.2, 0.1])
def loop(drv):
    drv.start()
    i = 0
    while True:
        drv.read()
        drv.write(tau)
        i += 1
        if i == 20:
            print("running", flush=True)
if guarded:
    try:
        with DynamixelDriver(cfg) as drv:
            loop(drv)
    except Interrupted as e:
        sys.exit(e.exit_code)
else:
    loop(DynamixelDriver(cfg))
"""


def run_child(port, mode):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([ROOT, os.environ.get("PYTHONPATH", "")])}
    env["PYTHONFAULTHANDLER"] = "1"  # SIGABRT prints every thread's stack (`_end`: a child that hangs)
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, port, mode],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    line = proc.stdout.readline()  # the child prints "running" after 20 ticks
    if line.strip() != "running":
        proc.kill()
        raise AssertionError(f"the child did not start its loop: {line!r} {proc.communicate()[1][-2000:]}")
    return proc


def _end(proc: subprocess.Popen, timeout_s: float = 60.0) -> str:
    """The child's stderr once it has ended; one that has not ended `timeout_s` after the signal
    (a generous bound, not a timing) is made to print its stacks and fails the test with them."""
    try:
        return proc.communicate(timeout=timeout_s)[1]
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        err = proc.communicate(timeout=30)[1]
        pytest.fail(f"the child did not end within {timeout_s:.0f} s of the signal; its stacks:\n{err[-6000:]}")


@pytest.mark.parametrize("mode", ["guarded", "cli"], ids=["with-driver", "cli-handlers"])
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_to_a_process_running_the_driver_ends_with_torque_off(emulator, sig, mode):
    """`with driver:` in a plain process, and in one whose handlers are the command line's
    (`interrupt.install()`)."""
    bus = emulator(lockstep=False)
    proc = run_child(bus.port, mode)
    assert bus.state()["torque_nm"][0] != 0.0  # the loop is driving the servos
    proc.send_signal(sig)
    err = _end(proc)
    assert proc.returncode == {signal.SIGTERM: 143, signal.SIGINT: 130}[sig], err
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]
    assert bus.state()["torque_nm"] == [0.0, 0.0, 0.0]


def test_sigkill_leaves_the_bus_watchdog_to_stop_the_servos(emulator):
    bus = emulator(lockstep=False)
    proc = run_child(bus.port, "bare")
    proc.kill()
    proc.communicate(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    deadline = time.monotonic() + 30.0
    while True:  # silence longer than the watchdog (0.3 s), then look; reading feeds the watchdog
        time.sleep(0.8)
        watchdog = registers(bus.port, T.ADDR_BUS_WATCHDOG, 1)
        if watchdog == [-1, -1, -1] or time.monotonic() > deadline:
            break
    assert watchdog == [-1, -1, -1]
    # nobody turned the torque off: the watchdog alone stopped the motors
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [1, 1, 1]
    assert registers(bus.port, T.ADDR_PRESENT_CURRENT, 2) == [0, 0, 0]
    assert bus.state()["torque_nm"] == [0.0, 0.0, 0.0]


def test_a_host_stall_longer_than_the_watchdog_is_one_clear_error(emulator):
    bus = emulator(lockstep=False)
    drv = DynamixelDriver(chain(bus.port, bus_watchdog_s=0.3))
    drv.start()
    drv.write(np.array([0.2, 0.2, 0.1]))
    time.sleep(1.0)  # the host hangs
    with pytest.raises(HardwareError) as e:
        drv.read()
    msg = str(e.value)
    assert "servo 1 (base_yaw)" in msg and "Bus Watchdog(98) tripped" in msg and "the watchdog is 300 ms" in msg
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]


def test_a_lockstep_emulator_keeps_the_watchdog_on_its_own_time(emulator):
    """In lockstep the servos' time advances with the host's writes only: a host (or an emulator
    process) starved of the CPU for longer than the watchdog trips nothing; the same stall on a
    real-time bus trips it (the test above)."""
    bus = emulator(lockstep=True)
    drv = DynamixelDriver(chain(bus.port, bus_watchdog_s=0.3))
    drv.start()
    drv.write(np.array([0.2, 0.2, 0.1]))
    time.sleep(1.0)  # wall time only
    for _ in range(3):
        assert drv.read().stale == 0
        drv.write(np.array([0.2, 0.2, 0.1]))
    drv.stop()
    assert bus.counters()["watchdog_trips"] == 0


# ---------------------------------------------------------------- faults


@pytest.mark.parametrize("bit", T.HARDWARE_ERROR_BITS, ids=lambda b: b.name.replace(" ", "-"))
@pytest.mark.parametrize("fast", [False, True], ids=["sync-read", "fast-sync-read"])
def test_each_hardware_error_bit_is_decoded_and_torque_goes_off(emulator, bit, fast):
    bus = emulator()
    drv = DynamixelDriver(chain(bus.port, fast_sync_read=fast))
    drv.start()
    drv.write(np.array([0.2, 0.2, 0.1]))
    drv.read()
    bus.inject(servo_id=2, kind="hardware_error", bits=1 << bit.bit)
    with pytest.raises(HardwareError) as e:
        drv.read()
    msg = str(e.value)
    assert msg.startswith(f"servo 2 (shoulder) on {bus.port} reports a hardware error")
    assert f"0x{1 << bit.bit:02x}" in msg and bit.name in msg and bit.action in msg and "REBOOT" in msg
    others = [b.name for b in T.HARDWARE_ERROR_BITS if b is not bit]
    assert not any(o in msg for o in others)
    assert drv.stopped
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]


def test_a_hardware_error_present_at_start_names_every_bit(emulator):
    bus = emulator()
    bus.inject(servo_id=3, kind="hardware_error", bits=0b100001)  # input voltage + overload
    with pytest.raises(HardwareError) as e:
        DynamixelDriver(chain(bus.port)).start()
    msg = str(e.value)
    assert "servo 3 (elbow)" in msg and "0x21" in msg and "input voltage error" in msg and "overload error" in msg
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]


FAULTY = {False: (3, "elbow"), True: (3, "elbow")}  # the last servo of the sync read


@pytest.mark.parametrize("kind", ["drop_replies", "corrupt_crc", "slow_replies"])
@pytest.mark.parametrize("fast", [False, True], ids=["sync-read", "fast-sync-read"])
def test_one_bad_reply_is_a_stale_sample_not_an_error(emulator, kind, fast):
    bus = emulator()
    drv = DynamixelDriver(chain(bus.port, fast_sync_read=fast))
    drv.start()
    drv.write(np.array([0.3, 0.3, 0.3]))
    good = drv.read()
    # slow: 0.2 s, later than the 50 ms read timeout
    bus.inject(servo_id=FAULTY[fast][0], kind=kind, count=1, extra_delay_s=0.2)
    drv.write(np.array([0.3, 0.3, 0.3]))
    stale = drv.read()
    assert stale.stale == 1 and drv.stale_reads == 1
    np.testing.assert_array_equal(stale.q_rad, good.q_rad)
    assert stale.t_s == good.t_s
    if kind == "slow_replies":
        time.sleep(0.3)  # the late reply is on the line before the next read clears it
    for _ in range(3):
        drv.write(np.array([0.3, 0.3, 0.3]))
        fresh = drv.read()
    assert fresh.stale == 0 and fresh.t_s > good.t_s and drv.stale_reads == 1
    assert bus.counters()[{"drop_replies": "dropped_replies", "corrupt_crc": "corrupted_replies",
                           "slow_replies": "slowed_replies"}[kind]] == 1  # fmt: skip
    drv.stop()


@pytest.mark.parametrize(
    ("kind", "why"),
    [("drop_replies", "there is no status packet"), ("corrupt_crc", "incorrect status packet"), ("slow_replies", "")],
)
@pytest.mark.parametrize("fast", [False, True], ids=["sync-read", "fast-sync-read"])
def test_n_bad_replies_in_a_row_are_one_error_and_torque_off(emulator, kind, why, fast):
    bus = emulator()
    drv = DynamixelDriver(chain(bus.port, max_consecutive_comm_errors=3, fast_sync_read=fast))
    drv.start()
    sid, name = FAULTY[fast]
    bus.inject(servo_id=sid, kind=kind, count=3, extra_delay_s=0.2)
    drv.write(np.zeros(3))
    assert drv.read().stale == 1
    drv.write(np.zeros(3))
    assert drv.read().stale == 2
    with pytest.raises(HardwareError) as e:
        drv.read()
    msg = str(e.value)
    who = bus.port if fast else f"servo {sid} ({name}) on {bus.port}"  # one fast packet: no servo to blame
    if fast and kind == "drop_replies":
        why = "incorrect status packet"  # the packet ends short where the silent servo's part belongs
    assert msg.startswith(f"{who}: 3 reads in a row failed")
    assert why in msg and "1000000 bps" in msg and "every servo answers a ping" in msg
    # each fault named as what it is (a fast packet cut short where the silent servo's part belongs
    # is a corrupt packet)
    named = {"drop_replies": "go missing", "corrupt_crc": "come corrupted", "slow_replies": "come late"}[kind]
    if fast and kind == "drop_replies":
        named = "come corrupted"
    assert f"the replies {named}" in msg, msg
    time.sleep(0.3)
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]


@pytest.mark.parametrize(
    ("kind", "cause"),
    [("watchdog_trip", "its Bus Watchdog(98) tripped"), ("torque_off", "its Torque Enable(64) is 0")],
)
@pytest.mark.parametrize("fast", [False, True], ids=["sync-read", "fast-sync-read"])
def test_a_servo_that_stops_applying_its_goal_current_stops_the_driver_naming_it_and_why(emulator, kind, cause, fast):
    """What the driver would record as applied must be what the servo applies: a servo whose Bus
    Watchdog trips (a starved bus under load) or whose torque another program turns off reports
    Present Current 0 against its Goal Current; within `applied_mismatch_reads` reads the driver
    reads back why, turns the torque off and raises one line naming the servo and the cause."""
    bus = emulator()
    drv = DynamixelDriver(chain(bus.port, fast_sync_read=fast, applied_mismatch_reads=5))
    drv.start()
    tau = np.array([0.3, 0.3, 0.3])
    for _ in range(3):
        drv.write(tau)
        assert drv.read().stale == 0  # a healthy servo applies what it was told: no error
    bus.inject(servo_id=2, kind=kind)
    reads = 0
    with pytest.raises(HardwareError) as e:
        for _ in range(50):
            drv.write(tau)
            drv.read()
            reads += 1
    assert reads == 4  # the 5th read after the fault raises
    msg = str(e.value)
    assert msg.startswith(f"servo 2 (shoulder) on {bus.port} is not applying the commanded torque: Present Current 0")
    assert cause in msg and msg.endswith("torque is off") and "\n" not in msg
    time.sleep(0.2)
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]


def test_a_servo_off_its_goal_current_for_fewer_reads_than_allowed_is_no_fault(emulator):
    bus = emulator()
    drv = DynamixelDriver(chain(bus.port, applied_mismatch_reads=5))
    drv.start()
    drv.write(np.array([0.3, 0.3, 0.3]))
    drv.read()
    bus.inject(servo_id=2, kind="torque_off")
    for _ in range(4):
        drv.write(np.array([0.3, 0.3, 0.3]))
        drv.read()
    drv.write(np.zeros(3))  # Goal Current 0: Present Current 0 applies it
    for _ in range(10):
        drv.write(np.zeros(3))
        assert drv.read().stale == 0
    drv.stop()


@pytest.mark.parametrize("at", [1, 2, 3, 4, 5, 6])
def test_a_late_reply_at_start_is_never_taken_as_another_requests_answer(emulator, at):
    """One reply 150 ms late during start-up (the driver's start-up timeout is 0.1 s): the PING or
    READ it answers is tried again, and the late reply, when it comes, is skipped or dropped as
    late; it is never read as Firmware Version or Hardware Error Status (where a PING reply's
    bytes once read as an invented overheating, encoder and overload fault)."""
    bus = emulator(
        faults=[{"servo_id": 1, "kind": "slow_replies", "at_transaction": at, "count": 1, "extra_delay_s": 0.15}]
    )
    drv = DynamixelDriver(chain(bus.port))
    sample = drv.start()
    assert sample.stale == 0 and drv.fast_sync_read_used
    assert bus.counters()["slowed_replies"] == 1
    drv.stop()
    time.sleep(0.2)
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]


def test_a_slow_reply_within_the_timeout_is_no_miss(emulator):
    bus = emulator()
    drv = DynamixelDriver(chain(bus.port, read_timeout_s=0.2))
    drv.start()
    bus.inject(servo_id=1, kind="slow_replies", count=2, extra_delay_s=0.02)
    for _ in range(3):
        drv.write(np.zeros(3))
        assert drv.read().stale == 0
    drv.stop()


@pytest.mark.parametrize("fast", [False, True], ids=["sync-read", "fast-sync-read"])
def test_a_vanished_servo_is_named_and_the_others_stop(emulator, fast):
    bus = emulator()
    drv = DynamixelDriver(chain(bus.port, fast_sync_read=fast))
    drv.start()
    drv.write(np.array([0.3, 0.3, 0.3]))
    drv.read()
    bus.inject(servo_id=3, kind="vanish")
    with pytest.raises(HardwareError) as e:
        for _ in range(10):
            drv.write(np.array([0.3, 0.3, 0.3]))
            drv.read()
    msg = str(e.value)
    assert msg.startswith(f"servo 3 (elbow) on {bus.port} stopped answering: 3 reads in a row failed")
    assert "1000000 bps" in msg and "does not answer a ping" in msg and "power" in msg
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1, ids=(1, 2)) == [0, 0]
    assert bus.state()["torque_nm"][:2] == [0.0, 0.0]


def test_wrong_model_number_is_refused(emulator):
    bus = emulator(models=["XM540-W270", "XM540-W270", "XM540-W270"])
    with pytest.raises(HardwareError) as e:
        DynamixelDriver(chain(bus.port)).start()
    msg = str(e.value)
    assert f"servo 3 (elbow) on {bus.port} is a XM540-W270 (model number 1120)" in msg
    assert "configuration says XM430-W350 (model number 1020)" in msg


def test_a_missing_servo_at_start_is_named_with_port_and_baud(emulator):
    bus = emulator()
    with pytest.raises(HardwareError) as e:
        DynamixelDriver(chain(bus.port, ids=(1, 2, 3, 4))).start()
    msg = str(e.value)
    assert msg.startswith(f"servo 4 (extra4) does not answer on {bus.port} at 1000000 bps")
    assert "powered" in msg and "ID(7) is 4" in msg and "Baud Rate(8)" in msg and "cables" in msg
    assert registers(bus.port, T.ADDR_TORQUE_ENABLE, 1) == [0, 0, 0]


def test_fast_sync_read_follows_the_firmware(emulator):
    bus = emulator(firmware=(46, 44, 46))
    drv = DynamixelDriver(chain(bus.port))
    drv.start()
    assert not drv.fast_sync_read_used  # auto: one servo is older than v45
    drv.stop()
    with pytest.raises(HardwareError) as e:
        DynamixelDriver(chain(bus.port, fast_sync_read=True)).start()
    assert "servo 2 (shoulder)" in str(e.value) and "firmware v44" in str(e.value) and "v45+" in str(e.value)
    bus2 = emulator(firmware=(46, 46, 46))
    drv2 = DynamixelDriver(chain(bus2.port))
    drv2.start()
    assert drv2.fast_sync_read_used
    drv2.stop()
