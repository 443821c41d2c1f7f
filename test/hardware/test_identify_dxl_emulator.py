"""Friction identification through the unmodified dynamixel_sdk: the Dynamixel driver
(plants/dynamixel/driver.py) against the bus emulator (emulators/dynamixel, its own process on a
pseudo-terminal) running the MuJoCo Dynamixel arm with a chosen true friction; the excitation
(engine/excitation.py) recovers it within 10 % (docs/identify.md)."""

from __future__ import annotations

import math

import pytest

from haptic_teleop.core.friction import Excitation
from haptic_teleop.emulators.dynamixel.config import BusConfig
from haptic_teleop.emulators.dynamixel.process import start_bus
from haptic_teleop.engine.excitation import Identifier
from haptic_teleop.plants.dynamixel.chain import DynamixelChainConfig, DynamixelJoint
from haptic_teleop.plants.dynamixel.driver import DynamixelDriver
from haptic_teleop.plants.kinematics import ArmKinematics

ARM = (("base_yaw", "XM540-W270"), ("shoulder", "XM540-W270"), ("elbow", "XM430-W350"))
SIGNS = (1, -1, 1)
START_Q = (0.0, 0.6, -1.2)  # the touch_dynamixel_wall slave's start
TRUE_B = (0.08, 0.12, 0.05)  # N m s/rad, not the model's
TRUE_C = (0.2, 0.1, 0.04)  # N m


def _bus() -> BusConfig:
    return BusConfig.from_dict(
        {
            "servos": [
                {"id": k + 1, "model": model, "joint": name, "sign": SIGNS[k]} for k, (name, model) in enumerate(ARM)
            ],
            "baud_bps": 1_000_000,
            "time": {"mode": "lockstep", "lockstep_dt_s": 0.001},
            "physics": {
                "kind": "mujoco",
                "model": "dxl_arm.xml",
                "start_q_rad": list(START_Q),
                "damping_nm_s_per_rad": list(TRUE_B),
                "frictionloss_nm": list(TRUE_C),
            },
        }
    )


def test_identifies_the_emulators_true_friction() -> None:
    """Every joint's viscous and Coulomb friction within 10 % of the emulator's; the safe damping
    below the true one. The servo quantizes what the driver sees: position to 4096 counts a turn,
    velocity to 0.229 rpm, the torque to the current unit (2.69 mA)."""
    bus = start_bus(_bus())
    try:
        joints = tuple(
            DynamixelJoint(name, k + 1, model, sign=SIGNS[k], zero_offset_rad=math.pi)
            for k, (name, model) in enumerate(ARM)
        )
        driver = DynamixelDriver(DynamixelChainConfig(bus.port, joints, read_timeout_s=0.5, bus_watchdog_s=2.0))
        kin = ArmKinematics("dxl_arm.xml", driver.joints, "tool")
        exc = Excitation(speeds_rad_per_s=(0.3, 0.6, 1.0, 1.5), repeats=1, measure_s=0.4)
        # lockstep emulator: its time advances with each write, so the loop is not paced
        result = Identifier(driver, kin, 0.001, excitation=exc, paced=False).run()
        assert driver.stopped
    finally:
        bus.stop()
    for k, ji in enumerate(result.joints):
        f = ji.fit
        assert f is not None, ji.error
        assert f.viscous_nm_s_per_rad == pytest.approx(TRUE_B[k], rel=0.10), ji.joint
        assert f.coulomb_nm == pytest.approx(TRUE_C[k], rel=0.10), ji.joint
        assert 0.0 < f.safe_damping_nm_s_per_rad < TRUE_B[k], ji.joint


def test_identify_emulate_identifies_the_scenes_emulated_arm_and_writes_a_scene_without_the_port(tmp_path) -> None:
    """`haptic-teleop identify SCENE --side slave --set slave.backend=dynamixel --emulate`: the
    command starts the scene's emulator (its true viscous friction is the damping the scene assumes,
    assembly/emulation.py), excites the joint through the unmodified SDK and writes a scene whose
    safe damping is positive and below that truth; the written scene names no emulator port."""
    import subprocess
    import sys

    import yaml

    out = tmp_path / "identified.yaml"
    r = subprocess.run(
        [sys.executable, "-m", "haptic_teleop.cli", "identify", "touch_dynamixel_wall", "--side", "slave",
         "--set", "slave.backend=dynamixel", "--emulate", "--joint", "elbow", "--speeds", "0.3,0.6,1.0",
         "--repeats", "1", "--quiet", "--write", str(out)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    written = yaml.safe_load(out.read_text())
    truth = 0.04  # touch_dynamixel_wall's slave.damping_nm_s_per_rad for the elbow: the emulator's friction
    elbow = written["slave"]["damping_nm_s_per_rad"][2]
    print(f"elbow: safe damping {elbow:.4f} N m s/rad, the emulator's {truth}")
    assert 0.0 < elbow < truth
    assert "/dev/pts" not in out.read_text() and written["slave"]["hardware"]["port"] is None
