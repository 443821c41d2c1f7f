"""The Dynamixel driver's configuration, the checks it makes before any servo answers (port,
USB latency timer), and the wire-time formula of `bench hardware`, through the real SDK on
pseudo-terminals this test holds (no emulator needed)."""

import os
import pty
import select

import numpy as np
import pytest

from haptic_teleop.errors import ConfigError
from haptic_teleop.plants.dynamixel.chain import (
    DynamixelChainConfig,
    DynamixelJoint,
    wire_bytes_per_tick,
    wire_limit_hz,
)
from haptic_teleop.plants.dynamixel.driver import DynamixelDriver
from haptic_teleop.plants.hardware import HardwareError


def joints(n=3):
    models = ["XM540-W270", "XM540-W270", "XM430-W350"] * 2
    return tuple(DynamixelJoint(f"j{k}", k + 1, models[k]) for k in range(n))


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"baud_bps": 4_500_000}, "baud_bps"),
        ({"baud_bps": 250_000}, "baud_bps"),
        ({"bus_watchdog_s": 0.0}, "bus_watchdog_s"),
        ({"bus_watchdog_s": 2.6}, "bus_watchdog_s"),
        ({"return_delay_time_s": 0.001}, "return_delay_time_s"),
        ({"max_consecutive_comm_errors": 0}, "max_consecutive_comm_errors"),
        ({"port": ""}, "port"),
        ({"joints": ()}, "joints"),
        ({"joints": (DynamixelJoint("a", 1, "XM430-W350"), DynamixelJoint("b", 1, "XM430-W350"))}, "joints[].id"),
        ({"joints": (DynamixelJoint("a", 1, "XM430-W350"), DynamixelJoint("a", 2, "XM430-W350"))}, "joints[].name"),
    ],
)
def test_bad_chain_config_names_the_key(kwargs, key):
    base = {"port": "/dev/ttyUSB0", "joints": joints()}
    with pytest.raises(ConfigError) as e:
        DynamixelChainConfig(**{**base, **kwargs})
    assert f": {key} = " in str(e.value) or f": {key}: " in str(e.value)
    assert "allowed" in str(e.value) or "once" in str(e.value)


@pytest.mark.parametrize(
    ("kwargs", "key"),
    [
        ({"id": 253}, "id"),
        ({"model": "XL330-M288"}, "model"),
        ({"sign": 0}, "sign"),
        ({"current_limit": 1194}, "current_limit"),  # XM430-W350's Current Limit(38) tops at 1193
        ({"current_limit_a": 3.3}, "current_limit_a"),
        ({"current_limit": 100, "current_limit_a": 0.2}, "current_limit"),
        ({"torque_constant_nm_per_a": 0.0}, "torque_constant_nm_per_a"),
    ],
)
def test_bad_joint_config_names_the_key(kwargs, key):
    with pytest.raises(ConfigError) as e:
        DynamixelJoint(**{"name": "elbow", "id": 3, "model": "XM430-W350", **kwargs})
    assert f"joints.elbow.{key}" in str(e.value)


def test_watchdog_rounds_up_to_20_ms_units_and_current_limit_in_amperes():
    c = DynamixelChainConfig("/dev/ttyUSB0", joints(), bus_watchdog_s=0.1)
    assert c.bus_watchdog_units == 5
    assert DynamixelChainConfig("/dev/ttyUSB0", joints(), bus_watchdog_s=0.101).bus_watchdog_units == 6
    assert DynamixelChainConfig("/dev/ttyUSB0", joints(), bus_watchdog_s=0.001).bus_watchdog_units == 1
    assert DynamixelChainConfig("/dev/ttyUSB0", joints(), bus_watchdog_s=2.54).bus_watchdog_units == 127
    j = DynamixelJoint("e", 3, "XM430-W350", current_limit_a=1.7216)
    assert j.current_limit_units == 640  # 1.7216 A / 2.69 mA
    assert DynamixelJoint("e", 3, "XM430-W350").current_limit_units == 1193  # the model's maximum
    # a limit between two units rounds down (toward safety): 1.7229 A is 640.5 units
    assert DynamixelJoint("e", 3, "XM430-W350", current_limit_a=1.7229).current_limit_units == 640
    assert DynamixelJoint("e", 3, "XM430-W350", current_limit_a=1.7242).current_limit_units == 640  # 640.97
    assert DynamixelJoint("e", 3, "XM430-W350", current_limit_a=0.001).current_limit_units == 1  # never 0
    d = DynamixelDriver(DynamixelChainConfig("/dev/ttyUSB0", (j,)))
    assert d.torque_limit_nm[0] == pytest.approx(640 * 2.69e-3 * 1.783)


def test_a_port_that_does_not_exist_is_one_clear_error(tmp_path):
    port = str(tmp_path / "ttyUSB9")
    d = DynamixelDriver(DynamixelChainConfig(port, joints()))
    with pytest.raises(HardwareError) as e:
        d.start()
    msg = str(e.value)
    assert port in msg and "does not exist" in msg and "/dev/serial/by-id" in msg
    d.stop()  # idempotent after a failed start


def test_permission_denied_says_dialout(tmp_path):
    """A user without access to the device (a child process dropped to `nobody`)."""
    import subprocess
    import sys

    master, slave = pty.openpty()
    try:
        path = os.ttyname(slave)
        os.chmod(path, 0o600)
        code = (
            "import sys\n"
            "from haptic_teleop.plants.dynamixel.chain import *\n"
            "from haptic_teleop.plants.dynamixel.driver import *\n"
            "from haptic_teleop.plants.hardware import HardwareError\n"
            f"d = DynamixelDriver(DynamixelChainConfig({path!r}, (DynamixelJoint('a', 1, 'XM430-W350'),)))\n"
            "try:\n    d.start()\nexcept HardwareError as e:\n    print(e)\n"
        )
        if os.geteuid() != 0:
            pytest.skip("needs root to run a child as another user")
        env = {**os.environ, "PYTHONPATH": os.getcwd()}
        try:
            r = subprocess.run(
                [sys.executable, "-c", code], user=65534, capture_output=True, text=True, env=env, timeout=60, cwd="/"
            )
        except PermissionError:
            pytest.skip("the user nobody cannot run this Python")
        if "Permission denied" in r.stderr and "haptic_teleop" in r.stderr:
            pytest.skip("the user nobody cannot read this worktree")
        assert "permission denied" in r.stdout and "dialout" in r.stdout, r.stdout + r.stderr
    finally:
        os.close(master)
        os.close(slave)


@pytest.fixture
def usb_named_pty(tmp_path):
    """A pseudo-terminal reached through a link named ttyUSB7 (how the driver finds the sysfs name)."""
    master, slave = pty.openpty()
    link = tmp_path / "dev" / "ttyUSB7"
    link.parent.mkdir()
    link.symlink_to(os.ttyname(slave))
    yield str(link), master
    os.close(master)
    os.close(slave)


def sysfs_with(tmp_path, value):
    d = tmp_path / "sys" / "ttyUSB7"
    d.mkdir(parents=True)
    (d / "latency_timer").write_text(f"{value}\n")
    return str(tmp_path / "sys")


def test_latency_timer_too_high_is_refused_with_the_fix(tmp_path, usb_named_pty):
    port, _ = usb_named_pty
    cfg = DynamixelChainConfig(port, joints(), sysfs_root=sysfs_with(tmp_path, 16))
    with pytest.raises(HardwareError) as e:
        DynamixelDriver(cfg).start()
    msg = str(e.value)
    assert "latency timer is 16 ms" in msg and "above 1 ms" in msg
    assert f"echo 1 | sudo tee {tmp_path}/sys/ttyUSB7/latency_timer" in msg


def test_latency_timer_at_one_ms_passes_on_to_the_servos(tmp_path, usb_named_pty):
    """With 1 ms the driver goes on and pings: nobody answers on this pty, so the error is about servo 1."""
    port, _ = usb_named_pty
    cfg = DynamixelChainConfig(port, joints(), sysfs_root=sysfs_with(tmp_path, 1))
    with pytest.raises(HardwareError) as e:
        DynamixelDriver(cfg).start()
    assert "servo 1 (j0) does not answer" in str(e.value) and "latency timer is" not in str(e.value)


def _drain(fd, quiet_s=0.2):
    out = b""
    while True:
        r, _, _ = select.select([fd], [], [], quiet_s)
        if not r:
            return out
        out += os.read(fd, 4096)


@pytest.mark.parametrize("n", [3, 6])
def test_wire_bytes_match_what_the_sdk_sends(n):
    """The instruction bytes of the formula are what the SDK puts on the wire (captured on a pty);
    the status packets' sizes are the protocol's (11 + data each; fast: one packet)."""
    import dynamixel_sdk as sdk

    master, slave = pty.openpty()
    try:
        port = sdk.PortHandler(os.ttyname(slave))
        assert port.openPort()
        ph = sdk.PacketHandler(2.0)
        w = sdk.GroupSyncWrite(port, ph, 102, 2)
        r = sdk.GroupSyncRead(port, ph, 126, 10)
        for i in range(1, n + 1):
            w.addParam(i, [0x10, 0x00])
            r.addParam(i)
        w.txPacket()
        write = _drain(master)
        r.txPacket()
        port.is_using = False
        read = _drain(master)
        r.fastSyncReadTxPacket()
        port.is_using = False
        fast = _drain(master)
        port.closePort()
    finally:
        os.close(master)
        os.close(slave)
    assert write[:4] == b"\xff\xff\xfd\x00" and read[7] == 0x82 and fast[7] == 0x8A
    replies = n * (11 + 10)
    assert wire_bytes_per_tick(n, fast=False) == len(write) + len(read) + replies
    fast_reply = 4 + 1 + 2 + 1 + n * (1 + 1 + 10 + 2)
    assert wire_bytes_per_tick(n, fast=True) == len(write) + len(fast) + fast_reply
    assert wire_limit_hz(n, 1_000_000, fast=False) == pytest.approx(1e5 / (len(write) + len(read) + replies))


def test_wire_limit_is_the_issues_figure():
    """About 560 Hz for 6 servos at 1 Mbps and 2.2 kHz at 4 Mbps (plain sync read)."""
    assert 540 < wire_limit_hz(6, 1_000_000, fast=False) < 580
    assert 2150 < wire_limit_hz(6, 4_000_000, fast=False) < 2300
    assert wire_limit_hz(6, 1_000_000, fast=True) > wire_limit_hz(6, 1_000_000, fast=False)


@pytest.mark.parametrize(
    ("argv", "allowed"),
    [
        (["--bauds", "250000"], "baud rates from"),
        (["--servos", "0"], "whole numbers 1..20"),
        (["--reads", "bulk"], "sync, fast"),
        (["--ticks", "0"], "> 0"),
    ],
)
def test_bench_hardware_refuses_bad_arguments_in_one_line(capsys, argv, allowed):
    from haptic_teleop.cli.main import main

    with pytest.raises(SystemExit) as e:
        main(["bench", "hardware", *argv])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "allowed:" in err and allowed in err and "Traceback" not in err


def test_read_or_write_before_start_is_one_clear_error():
    d = DynamixelDriver(DynamixelChainConfig("/dev/ttyUSB0", joints()))
    with pytest.raises(HardwareError, match=r"/dev/ttyUSB0: write\(\) on a driver that is not started"):
        d.write(np.zeros(3))
    with pytest.raises(HardwareError, match=r"read\(\) on a driver that is not started"):
        d.read()
