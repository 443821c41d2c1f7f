"""A per-joint torque slew limit on an arm side (`<side>.slew_nm_per_s`): inside the pooled energy
bound's accounting (core/eba.py, the slew-aware bound; docs/eba_many_joints.md "Slew limit"), the same in the
compiled and the Python arm loop, and checked against the joints like every per-joint list."""

from __future__ import annotations

import numpy as np
import pytest

from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.load import find_scene, load_scene

SLEW = (4.0, 4.0, 2.0)  # N m/s: a step of 4 and 2 mN m per 1 ms tick
SETS = [
    "scene.duration_s=2.0",
    f"slave.slew_nm_per_s=[{', '.join(map(str, SLEW))}]",
    "controllers.slave.stiffness_n_per_m=3000",
]


def _run(loop: str, sets: list[str]) -> Engine:
    e = Engine(load_scene(find_scene("touch_dynamixel_wall"), sets), loop=loop)
    assert e.loop_kind == loop
    e.run(handle_sigint=False)
    return e


def test_the_slew_limit_holds_on_every_tick_in_both_loops_bit_for_bit() -> None:
    compiled, python = _run("compiled", SETS), _run("python", SETS)
    assert np.array_equal(compiled.data, python.data, equal_nan=True)
    tau = python.data[:, python.schema.group("s_tau_nm")]
    step = np.abs(np.diff(tau, axis=0))
    limit = np.array(SLEW) * python.period_s
    assert (step <= limit * (1 + 1e-9) + 1e-12).all()
    assert (step >= limit * 0.999).any()  # it binds: without it the torque would jump further
    free = _run("python", SETS[:1] + SETS[2:])
    free_step = np.abs(np.diff(free.data[:, free.schema.group("s_tau_nm")], axis=0))
    assert (free_step > limit * 1.5).any()
    # The ledger on the applied torques never went below zero with the limit in its accounting.
    assert python.data[:, python.schema.group("s_energy_j")].min() >= 0.0


def test_a_slew_list_of_the_wrong_length_names_the_joints() -> None:
    joints = r"3 values, one per joint \(base_yaw, shoulder, elbow\)"
    with pytest.raises(ConfigError, match=r"slave.slew_nm_per_s.*" + joints):
        load_scene(find_scene("touch_dynamixel_wall"), ["slave.slew_nm_per_s=[1.0, 2.0]"])
    with pytest.raises(ConfigError, match=r"master.slew_nm_per_s\[1\].*> 0"):
        load_scene(find_scene("touch_dynamixel_wall"), ["master.slew_nm_per_s=[1.0, 0.0, 1.0]"])
