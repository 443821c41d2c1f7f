"""Arm scenes end to end: each bundled arm scene runs to a bag and a summary; the tool stops at the
wall, pushed back along the wall's normal; every side's energy margin, from the bag's joint
positions and applied torques with the damping the simulator has, stays >= 0; the same scene and
seed give the same bag bytes; and a hard case (stiff wall, 200 ms round trip with 10 % bursty
loss, a fast operator, motor torque limits reached) goes negative without EBA and not with it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from haptic_teleop.analysis.stream import summarize_bag
from haptic_teleop.cli.main import main
from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.engine.run import record_run
from haptic_teleop.scene.load import find_scene, load_scene

ARM_SCENES = ("touch_ur5e_wall", "touch_dynamixel_wall", "touch_ur5e_oblique_wall")
SHORT = ("scene.duration_s=3.0",)
SIDES = ("master", "slave")


def _record(tmp: Path, name: str, *overrides: str) -> tuple[Engine, dict[str, Any], Path]:
    scene = load_scene(find_scene(name), list(overrides))
    bag = tmp / "bag"
    engine, _ = record_run(scene, bag, parallel=False, handle_sigint=False, keep=True)
    return engine, summarize_bag(bag), bag


@pytest.fixture(scope="module", params=ARM_SCENES)
def arm_run(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, ...]:
    name = request.param
    engine, summary, bag = _record(tmp_path_factory.mktemp(name), name, *SHORT)
    return name, engine, summary, bag


def test_arm_scene_runs_from_the_command_line_to_a_summary_bag_and_plots(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert main(["run", "touch_dynamixel_wall", "--set", "scene.duration_s=1.0", "--out", str(out), "--quiet"]) == 0
    assert list((out / "bag").glob("*.mcap"))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["slave_joint_damping_simulator"] == [0.1, 0.1, 0.04]  # dxl_arm.xml's joint damping
    assert {p.name for p in (out / "plots").glob("*.png")}
    assert "compiled" in (out / "timing.json").read_text()  # arm scenes run in the compiled loop (arm_host.py)


def test_the_tool_stops_at_the_wall(arm_run: tuple[Any, ...]) -> None:
    name, engine, summary, _ = arm_run
    c = engine.scene.config
    s = engine.schema
    x = engine.data[:, s.group("s_x_m")]
    v = engine.data[:, s.group("s_v_m_per_s")]
    n = np.array(c.slave.wall.normal)
    depth = (np.array(c.slave.wall.point_m) - x) @ n
    assert 0.0 < summary["penetration_max_m"] < 0.005, name  # pressed in, a few mm at most
    assert summary["penetration_max_m"] == pytest.approx(depth.max(), rel=1e-9)
    assert depth[-1] > 0.0, name  # still in contact at the end
    assert abs(v[-200:] @ n).max() < 0.01, name  # at rest along the normal over the last 0.2 s


def test_the_contact_force_points_along_the_wall_normal(arm_run: tuple[Any, ...]) -> None:
    name, engine, _, _ = arm_run
    c = engine.scene.config
    f = engine.data[-1, engine.schema.group("s_contact_n")]
    n = np.array(c.slave.wall.normal)
    assert np.linalg.norm(f) > 1.0, name
    assert f @ n > 0.999 * np.linalg.norm(f), name  # pushes out of the wall, along its normal only


def test_every_port_keeps_a_nonnegative_energy_margin_with_the_simulators_damping(arm_run: tuple[Any, ...]) -> None:
    """The summary's margins come from the bag: recorded q, the applied torques, dof_damping."""
    name, engine, summary, _ = arm_run
    for side, plant in zip(SIDES, (engine.master, engine.slave), strict=True):
        assert summary[f"{side}_joint_damping_simulator"] == plant.joint_damping()
        assert summary[f"{side}_energy_margin_simulator_min_j"] >= 0.0, (name, side)
        # the same ledger from the engine's own columns
        s = engine.schema
        q = engine.data[:, s.group(f"{side[0]}_q")]
        tau = engine.data[:, s.group(f"{side[0]}_tau_nm")]
        dq = np.diff(q, axis=0)
        step = (np.array(plant.joint_damping()) / engine.period_s * dq * dq - tau[:-1] * dq).sum(axis=1)
        e0 = getattr(engine.scene.config.controllers, side).eba.initial_energy_j
        assert e0 + np.cumsum(step).min() >= 0.0, (name, side)


def test_the_operator_feels_the_contact_scaled_and_the_summary_compares_in_the_task_frame(
    arm_run: tuple[Any, ...],
) -> None:
    """The scenes scale the felt force into the Touch's range (mapping.force_scale < 1) with the
    slave's gains on the master: the device's motors apply J^T (force_scale R^T F) for the recorded
    task-frame force F (the NDOF rule: the rendered force is recorded mapped back with the force
    scale), so at rest F equals the contact force while the hand feels force_scale of it."""
    import mujoco

    name, engine, summary, _ = arm_run
    s = engine.schema
    d = engine.data
    mapping = engine.arm.mapping
    assert 0.0 < mapping.force_scale < 1.0, name
    model = engine.master.model
    data = mujoco.MjData(model)
    jac = np.zeros((3, model.nv))
    for k in range(1000, d.shape[0], 250):  # the device's torques realise force_scale R^T F
        data.qpos[:] = d[k, s.group("m_q")]
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        mujoco.mj_jacSite(model, data, jac, None, model.site("handle").id)
        f_device = mapping.force_scale * mapping.matrix.T @ d[k, s.group("m_force_n")]
        np.testing.assert_allclose(d[k, s.group("m_tau_nm")], jac.T @ f_device, rtol=1e-6, atol=1e-9)
    last = slice(-500, None)  # in contact at the end: the task-frame force felt is the contact force
    # (10 %: on the oblique wall the tool still slides down the slope, 100 ms behind the hand)
    felt = d[last, s.group("m_force_n")]
    contact = d[last, s.group("s_contact_n")]
    err = np.linalg.norm(felt - contact, axis=1)
    assert err.max() < 0.1 * np.linalg.norm(contact, axis=1).min(), name
    assert summary["force_rms_error_n"] < 0.5 * summary["contact_force_max_n"], name


def test_same_scene_and_seed_give_the_same_bag_bytes(tmp_path: Path) -> None:
    bags = []
    for run in ("a", "b"):
        _, _, bag = _record(tmp_path / run, "touch_dynamixel_wall", "scene.duration_s=1.0")
        bags.append(next(bag.glob("*.mcap")).read_bytes())
    assert bags[0] == bags[1]


# The hard case: a stiff wall, 100 ms each way with 10 % loss in bursts (Gilbert-Elliott: 1/9 of
# the time in a state losing 90 %), the operator ten times faster than the scene's, stiff
# couplings, and the slave's motors limited to a fraction of their torque (reached).
GE_10 = "{model: gilbert_elliott, p: 0.02, r: 0.16, one_minus_h: 0.9, one_minus_k: 0.0}"
HARD = (
    "scene.duration_s=3.0",
    "operator.start_s=0.2",
    "operator.speed_m_per_s=0.5",
    "operator.distance_m=0.06",
    "controllers.master.stiffness_n_per_m=1000",
    "controllers.master.damping_n_s_per_m=5",
    *(f"network.{d}.effects.delay.delay_s=0.1" for d in ("forward", "backward")),
    *(f"network.{d}.effects.loss={GE_10}" for d in ("forward", "backward")),
)
HARD_SLAVE = {
    "touch_dynamixel_wall": (
        "slave.wall.stiffness_n_per_m=2e4",
        "slave.torque_limit_nm=[2.0, 2.0, 1.0]",
        "controllers.slave.stiffness_n_per_m=3000",
        "controllers.slave.damping_n_s_per_m=10",
    ),
    "touch_ur5e_wall": (
        "slave.wall.stiffness_n_per_m=1e5",
        "slave.torque_limit_nm=[30, 30, 30, 3, 3, 3]",
        "controllers.slave.stiffness_n_per_m=20000",
        "controllers.slave.damping_n_s_per_m=50",
    ),
}
UNPROTECTED = ("controllers.master.eba.enabled=false", "controllers.slave.eba.enabled=false")


@pytest.mark.parametrize("name", sorted(HARD_SLAVE))
@pytest.mark.parametrize("protected", [True, False])
def test_hard_case_negative_without_eba_and_not_with_it(tmp_path: Path, name: str, protected: bool) -> None:
    overrides = (*HARD, *HARD_SLAVE[name], *(() if protected else UNPROTECTED))
    engine, summary, _ = _record(tmp_path, name, *overrides)
    assert summary["loss_rate_forward"] > 0.05 and summary["loss_rate_backward"] > 0.05
    assert engine.joint_limit_ticks["slave"] > 0  # the motors' limits were reached
    margins = [summary[f"{side}_energy_margin_simulator_min_j"] for side in SIDES]
    if protected:
        assert min(margins) >= 0.0, margins
    else:
        assert min(margins) < -0.1, margins


def test_a_rotated_scaled_mapping_still_couples_handle_and_tool(tmp_path: Path) -> None:
    """Master device turned 90 degrees about z and scaled by 0.5: the handle's start maps onto the
    tool's (the default offset), the operator still pushes the tool into the wall along the task
    direction, and the master moves along its own -y to do it (R^T of +x)."""
    sets = ("scene.duration_s=3.0", "mapping={scale: 0.5, rotation_rpy_deg: [0, 0, 90]}")
    engine, summary, _ = _record(tmp_path, "touch_dynamixel_wall", *sets)
    s = engine.schema
    d = engine.data
    np.testing.assert_allclose(d[0, s.group("m_x_m")], d[0, s.group("s_x_m")], atol=1e-12)
    assert summary["penetration_max_m"] > 0.0
    assert summary["master_energy_margin_simulator_min_j"] >= 0.0
    handle = engine.master.point()[0]  # device frame, at the end
    start = np.array(engine.arm.mapping.position_to_master(d[0, s.group("m_x_m")]))
    moved = handle - start
    assert moved[1] < -0.02 and abs(moved[0]) < 0.5 * abs(moved[1])  # task +x is the device's -y


def test_vector_payloads_through_an_extrapolating_buffer_and_the_guards(tmp_path: Path) -> None:
    """Arm packets (6 and 9 floats) through lossy links into buffers that extrapolate the gaps:
    samples are made up per value, pass the guards, and the run stays finite and passive."""
    sets = (
        "scene.duration_s=2.0",
        *(f"network.{d}.effects.loss.probability=0.2" for d in ("forward", "backward")),
        *(f"network.{d}.buffer={{policy: fixed, gap: extrapolate}}" for d in ("forward", "backward")),
    )
    engine, summary, _ = _record(tmp_path, "touch_dynamixel_wall", *sets)
    assert engine.forward_buffer.extrapolated > 0 and engine.backward_buffer.extrapolated > 0
    assert engine.master_ctrl.rejected_samples == engine.slave_ctrl.rejected_samples == 0
    assert summary["all_finite"] and summary["penetration_max_m"] > 0.0
    assert min(summary[f"{side}_energy_margin_simulator_min_j"] for side in SIDES) >= 0.0


def test_a_stop_request_ends_the_run_with_a_readable_bag(tmp_path: Path) -> None:
    """Ctrl-C's path (Engine.request_stop): the loop ends after the current tick and the bag is
    closed with every tick that finished, and analyses."""
    scene = load_scene(find_scene("touch_dynamixel_wall"), ["scene.duration_s=2.0"])
    holder: dict[str, Engine] = {}

    def progress(done: int) -> None:
        if done == 700:
            holder["engine"].request_stop()

    engine, timing = record_run(
        scene,
        tmp_path / "bag",
        progress=progress,
        parallel=False,
        handle_sigint=False,
        keep=True,
        on_engine=lambda e: holder.setdefault("engine", e),
    )
    assert timing.interrupted and engine.ticks_done == 700
    summary = summarize_bag(tmp_path / "bag")
    assert summary["ticks"] == 700 and summary["all_finite"]
