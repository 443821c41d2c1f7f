"""Arm scenes' configuration: the schema's arm keys, their validation against the model (one clear
line naming file, key, value and what is allowed), and one-axis scenes left as they were."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.load import find_scene, load_scene
from haptic_teleop.scene.schema import ARM_KEYS

ARM = find_scene("touch_ur5e_wall")


def _load(*overrides: str, path: Path = ARM):  # type: ignore[no-untyped-def]
    return load_scene(path, list(overrides))


def test_arm_scene_loads_with_its_models() -> None:
    c = _load().config
    assert c.is_arm
    assert c.slave.wall.normal == (0.0, 0.0, 1.0)
    assert c.operator.direction == (0.0, 0.0, -1.0)


def test_normal_and_direction_are_normalised() -> None:
    c = _load("slave.wall.normal=[0, 0, 2]", "operator.direction=[0, 3, -4]").config
    assert c.slave.wall.normal == (0.0, 0.0, 1.0)
    assert c.operator.direction == pytest.approx((0.0, 0.6, -0.8))


@pytest.mark.parametrize(
    ("override", "key", "allowed"),
    [
        ("slave.wall.normal=[0, 0, 0]", "slave.wall", "normal must be a nonzero vector"),
        ("slave.wall.normal=[0, 1]", "slave.wall", "normal needs 3 values"),
        ("operator.direction=[0, 0, 0]", "operator", "direction must be a nonzero vector"),
        ("slave.joints=[shoulder_pan, wrist_9]", "slave.joints[1]", "its joints: shoulder_pan, shoulder_lift"),
        ("slave.start_q_rad=[0, 1]", "slave.start_q_rad", "6 values, one per joint"),
        ("master.torque_limit_nm=[0.4, 0.4]", "master.torque_limit_nm", "3 values, one per joint"),
        ("master.damping_nm_s_per_rad=[0.0, 0.1, 0.1]", "master.damping_nm_s_per_rad[0]", "> 0.0"),
        ("slave.wall.stiffness_n_per_m=1e7", "slave.wall.stiffness_n_per_m", "simulation.substeps >="),
        ("slave.wall.point_m=[-0.49, -0.13, 0.5]", "slave", "inside the wall"),
        ("master.model=ur5e.xml", "master.model", "an arm MJCF with a site 'handle'"),
        ("controllers.slave.stiffness_axes_n_per_m=[1, 2]", "controllers.slave", "needs 3 values"),
        ("slave.effects.noise.position_std_m=0.001", "slave.effects", "not built for arms yet"),
    ],
)
def test_bad_arm_values_name_key_and_what_is_allowed(override: str, key: str, allowed: str) -> None:
    with pytest.raises(ConfigError) as err:
        _load(override)
    e = err.value
    assert e.key_path == key, str(e)
    assert allowed in str(e), str(e)
    assert "\n" not in str(e)


def test_a_one_axis_scene_refuses_arm_keys_and_arm_models() -> None:
    one = find_scene("wall_contact")
    with pytest.raises(ConfigError, match="only for arm models"):
        _load("master.joints=[yaw]", path=one)
    with pytest.raises(ConfigError, match="is an arm: its scene needs the wall's pose"):
        _load("slave.model=ur5e.xml", path=one)


def test_one_axis_scene_yaml_has_no_arm_keys() -> None:
    """The resolved YAML of a one-axis scene (written into its bag) is as before arms existed."""
    text = load_scene(find_scene("wall_contact")).to_yaml()

    def keys(d: object) -> set[str]:
        if isinstance(d, dict):
            return set(d) | {k for v in d.values() for k in keys(v)}
        return set()

    assert not keys(yaml.safe_load(text)) & ARM_KEYS


def test_arm_scene_yaml_round_trips(tmp_path: Path) -> None:
    """The resolved scene an arm run writes loads again to the same config."""
    s = _load()
    p = tmp_path / "scene.yaml"
    p.write_text(s.to_yaml())
    again = load_scene(p)
    assert again.config == s.config
    assert math.isclose(sum(c * c for c in again.config.slave.wall.normal or ()), 1.0)


@pytest.mark.parametrize(
    ("role", "limits", "joint"),
    [
        ("slave", "[5, 5, 5, 0.5, 0.5, 0.5]", "shoulder_lift"),  # gravity needs 20.3 N m there
        ("slave", "[150, 150, 5, 28, 28, 28]", "elbow"),
        ("slave", "[30, 30, 30, 1, 1, 1]", "wrist_1"),  # was the hard case ur5e_motor_below_gravity
    ],
)
def test_a_torque_limit_below_the_gravity_torque_at_the_start_is_refused(role: str, limits: str, joint: str) -> None:
    """A side that cannot hold its arm against gravity at its start pose would drop it (a UR5e with
    5 N m limits fell into the table at 142 N): refused before anything moves, naming the key, the
    joint and both torques."""
    from haptic_teleop.assembly.parts import build_arm_parts

    with pytest.raises(ConfigError) as e:
        build_arm_parts(_load(f"{role}.torque_limit_nm={limits}").config, compiled=False)
    msg = str(e.value)
    assert f"{role}.torque_limit_nm" in msg and f"joint {joint} needs" in msg and "N m" in msg
    assert "\n" not in msg


def test_torque_limits_that_hold_the_arm_are_accepted() -> None:
    from haptic_teleop.assembly.parts import build_arm_parts

    parts = build_arm_parts(_load("slave.torque_limit_nm=[150, 150, 150, 28, 28, 28]").config, compiled=False)
    assert parts is not None
    # without gravity compensation the motors hold nothing of gravity: nothing to check
    build_arm_parts(_load("slave.torque_limit_nm=[5, 5, 5, 0.5, 0.5, 0.5]", "slave.gravity_compensation=false").config,
                    compiled=False)  # fmt: skip
