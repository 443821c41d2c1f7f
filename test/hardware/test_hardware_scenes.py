"""Scenes with a side on real servos (`<side>.backend: dynamixel`, `<side>.hardware`): every bad key
is refused before anything runs with the file or flag, the key path, the value and what is
allowed; `--set` reaches every hardware key; and the hardware arm plant on a simulated joint-level
driver (plants/sim_driver.py: real MuJoCo, no SDK) behaves as the tick expects (docs/hardware.md)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.errors import ConfigError, PlantError
from haptic_teleop.scene.load import find_scene, load_scene

ROOT = Path(__file__).resolve().parents[2]
ON_SERVOS = ["slave.backend=dynamixel", "slave.hardware.port=/dev/ttyUSB0"]


def _load(*sets: str, name: str = "touch_dynamixel_wall") -> object:
    return load_scene(find_scene(name), list(sets))


def test_set_reaches_every_hardware_key_and_the_resolved_scene_keeps_them() -> None:
    scene = _load(
        *ON_SERVOS,
        "slave.hardware.baud_bps=1000000",
        "slave.hardware.ids=[4, 5, 6]",
        "slave.hardware.signs=[1, -1, 1]",
        "slave.hardware.torque_constants_nm_per_a=[2.2, 2.2, 1.7]",
        "slave.hardware.bus_watchdog_s=0.2",
        "slave.hardware.ramp_in_s=1.0",
        "slave.slew_nm_per_s=[50, 50, 20]",
    )
    hw = scene.config.slave.hardware  # type: ignore[attr-defined]
    assert (hw.port, hw.baud_bps, hw.ids, hw.signs) == ("/dev/ttyUSB0", 1000000, (4, 5, 6), (1, -1, 1))
    assert hw.torque_constants_nm_per_a == (2.2, 2.2, 1.7) and hw.ramp_in_s == 1.0
    assert "hardware:" in scene.to_yaml() and "port: /dev/ttyUSB0" in scene.to_yaml()  # type: ignore[attr-defined]
    # A one-axis scene's resolved YAML has no hardware or slew keys (its bags keep their bytes).
    assert "hardware" not in _load(name="wall_contact").to_yaml()  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("sets", "key", "allowed"),
    [
        (["slave.backend=dynamixel"], "slave.hardware.port", "or run with --emulate"),
        ([*ON_SERVOS, "slave.hardware.ids=[1, 2]"], "slave.hardware.ids", "3 values, one per joint"),
        ([*ON_SERVOS, "slave.hardware.ids=[1, 1, 2]"], "slave.hardware", "ids must be distinct"),
        ([*ON_SERVOS, "slave.hardware.ids=[1, 2, 300]"], "slave.hardware.ids[2]", "<= 252"),
        (
            [*ON_SERVOS, "slave.hardware.models=[XM540-W270, XM540-W270, AX-12]"],
            "slave.hardware.models[2]",
            "XM430-W350",
        ),
        ([*ON_SERVOS, "slave.hardware.signs=[1, 0, 1]"], "slave.hardware", "+1 or -1"),
        ([*ON_SERVOS, "slave.hardware.baud_bps=4500000"], "slave.hardware.baud_bps", "4000000"),
        ([*ON_SERVOS, "slave.hardware.zero_offsets_rad=[0, 0]"], "slave.hardware.zero_offsets_rad", "one per joint"),
        ([*ON_SERVOS, "slave.hardware.latency=1"], "slave.hardware.latency", "unknown key"),
        ([*ON_SERVOS, "slave.backend=ur5"], "slave.backend", "mujoco, dynamixel"),
        ([*ON_SERVOS, "slave.damping_nm_s_per_rad=null"], "slave.damping_nm_s_per_rad", "haptic-teleop identify"),
        ([*ON_SERVOS, "slave.start_q_rad=null"], "slave.start_q_rad", "start-up check"),
        (["slave.hardware=null", "slave.backend=dynamixel"], "slave.hardware", "port, ids, models"),
        (["slave.slew_nm_per_s=[1, 2]"], "slave.slew_nm_per_s", "one per joint"),
    ],
)
def test_a_bad_hardware_key_is_one_error_naming_key_value_and_what_is_allowed(
    sets: list[str], key: str, allowed: str
) -> None:
    with pytest.raises(ConfigError) as exc:
        _load(*sets)
    assert exc.value.key_path == key, str(exc.value)
    assert allowed in str(exc.value)
    assert "--set" in exc.value.source or exc.value.source.endswith("touch_dynamixel_wall.yaml")


def test_a_ur_side_without_its_host_names_the_key_and_the_emulator() -> None:
    with pytest.raises(ConfigError) as exc:
        _load("slave.backend=ur", name="touch_ur5e_wall")
    assert exc.value.key_path == "slave.hardware.host", str(exc.value)
    assert "or run with --emulate" in str(exc.value)


def test_a_real_device_in_a_one_axis_scene_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"slave\.backend = 'dynamixel': a real device drives an arm"):
        _load("slave.backend=dynamixel", name="wall_contact")


SET_BACKEND = ("--set", "slave.backend=dynamixel")


def test_the_command_line_says_it_in_one_line_and_exits_2(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.cli", "run", "touch_dynamixel_wall", *SET_BACKEND, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "slave.hardware.port" in proc.stderr
    assert not out.exists()


# ------------------------------------------------------------------------- the plant


def _plant(role: str = "slave", start: tuple[float, ...] = (0.0, 0.6, -1.2), **kw: object) -> object:
    from haptic_teleop.plants.hardware_arm import HardwareArm
    from haptic_teleop.plants.kinematics import ArmKinematics
    from haptic_teleop.plants.sim_driver import MujocoJointDriver

    site = "tool" if role == "slave" else "handle"
    driver = MujocoJointDriver("dxl_arm.xml", site, start_q_rad=[0.0, 0.6, -1.2])
    return HardwareArm(
        driver,
        ArmKinematics("dxl_arm.xml", None, site),
        (0.1, 0.1, 0.04),
        start,
        0.001,
        role,
        **kw,  # type: ignore[arg-type]
    )


def test_the_plant_holds_the_arm_against_gravity_and_books_what_the_driver_applied() -> None:
    arm = _plant(ramp_in_s=0.0)
    q0, _ = arm.read()  # type: ignore[attr-defined]
    for _ in range(300):
        arm.read()  # type: ignore[attr-defined]
        applied = arm.step(np.zeros(3))  # type: ignore[attr-defined]
    q, _ = arm.read()  # type: ignore[attr-defined]
    assert np.abs(q - q0).max() < 0.01  # gravity compensated: the arm stays (it would fall without)
    assert np.allclose(applied, 0.0, atol=1e-9)
    # A torque beyond the motor's room is clipped to it, and the clipped torque is what step returns.
    lo, hi = arm.torque_room()  # type: ignore[attr-defined]
    out = arm.step(np.array([100.0, -100.0, 0.0]))  # type: ignore[attr-defined]
    assert out[0] == pytest.approx(hi[0]) and out[1] == pytest.approx(lo[1])
    arm.close()  # type: ignore[attr-defined]


def test_the_plant_refuses_a_commanded_hand_force_and_a_start_too_far() -> None:
    arm = _plant(role="master")
    with pytest.raises(PlantError, match="real hand"):
        arm.step(np.zeros(3), hand_force_n=[1.0, 0.0, 0.0])  # type: ignore[attr-defined]
    assert arm.contact_wrench()[0].tolist() == [0.0, 0.0, 0.0]  # type: ignore[attr-defined]
    arm.close()  # type: ignore[attr-defined]
    far = _plant(start=(0.0, 0.8, -1.2), start_tolerance_rad=0.05)
    with pytest.raises(PlantError, match=r"shoulder -0\.200 rad"):
        far.read()  # type: ignore[attr-defined]


def test_the_ramp_in_shrinks_the_torque_before_the_bound_and_reaches_one() -> None:
    arm = _plant(ramp_in_s=0.1)
    arm.read()  # type: ignore[attr-defined]
    tau = np.array([0.0, 0.5, 0.2])
    first = arm.safe_torque(tau)  # type: ignore[attr-defined]
    assert np.all(np.abs(first) < np.abs(tau) + 1e-12) and np.allclose(first, 0.0)
    for _ in range(120):
        arm.read()  # type: ignore[attr-defined]
        arm.step(np.zeros(3))  # type: ignore[attr-defined]
    arm.read()  # type: ignore[attr-defined]
    assert np.allclose(arm.safe_torque(tau), tau)  # type: ignore[attr-defined]
    arm.close()  # type: ignore[attr-defined]


def test_identify_builds_the_runs_dynamixel_driver_and_refuses_a_ur_side(tmp_path: Path) -> None:
    """`haptic-teleop identify` on a side on servos: the driver the run would use (ids, models,
    signs, offsets, Current Limit at the torque limit) from the scene, damping not yet required;
    here started against the emulator, read at the scene's start pose, stopped with torque off."""
    import dynamixel_sdk as sdk

    from haptic_teleop.assembly.emulation import bus_config
    from haptic_teleop.cli.identify import joint_driver_for
    from haptic_teleop.emulators.dynamixel.process import start_bus
    from haptic_teleop.errors import InputError

    sets = ["slave.backend=dynamixel", "slave.damping_nm_s_per_rad=null"]
    first = load_scene(find_scene("touch_dynamixel_wall"), sets, emulate=True, identify=True)
    with start_bus(bus_config(first.config, "slave")) as bus:
        scene = load_scene(
            find_scene("touch_dynamixel_wall"), [*sets, f"slave.hardware.port={bus.port}"], identify=True
        )
        driver, truth = joint_driver_for(scene.config, "slave", 0)
        assert truth is None and driver.joints == ("base_yaw", "shoulder", "elbow")
        np.testing.assert_allclose(driver.torque_limit_nm, [7.7765, 7.7765, 3.0689], rtol=2e-3)
        sample = driver.start()
        np.testing.assert_allclose(sample.q_rad, [0.0, 0.6, -1.2], atol=2e-3)
        driver.stop()
        port = sdk.PortHandler(bus.port)
        assert port.openPort() and port.setBaudRate(4_000_000)
        packet = sdk.PacketHandler(2.0)
        assert [packet.read1ByteTxRx(port, i, 64)[0] for i in (1, 2, 3)] == [0, 0, 0]
        port.closePort()
    ur = load_scene(
        find_scene("touch_ur5e_wall"),
        ["slave.backend=ur", "slave.hardware.host=127.0.0.1", "slave.hardware.control_mode=torque"],
        identify=True,
    )
    with pytest.raises(InputError, match="allowed: mujoco, dynamixel"):
        joint_driver_for(ur.config, "slave", 0)


def test_a_hardware_backend_without_its_sdk_is_refused_in_one_line_before_anything_runs(tmp_path):
    """Without dynamixel_sdk (made unimportable in the child), `run --set slave.backend=dynamixel`
    names the package to install, exit 2, no traceback, no output directory."""
    import subprocess
    import sys

    out = tmp_path / "run"
    code = (
        "import sys; sys.modules['dynamixel_sdk'] = None; "  # absent: its import raises ImportError
        "from haptic_teleop.cli.main import main; "
        "sys.exit(main(['run', 'touch_dynamixel_wall', '--set', 'slave.backend=dynamixel', '--emulate', "
        f"'--out', {str(out)!r}]))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "dynamixel_sdk" in lines[0] and "pip install 'dynamixel-sdk>=" in lines[0], lines[0]
    assert not out.exists()
