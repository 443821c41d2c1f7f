"""The compiled arm loop (haptic_teleop/arm_host.py) gives the Python arm loop's run, bit for bit.

Each case runs an arm scene in both loops and compares what each hands its sink, call by call
(every block of columns, every batch of packet records, at the same points of the run), and the
sides' final state (energies, guard counts, motor-limit counts, the plants' MuJoCo state). The
cases cover both arm scenes, delay with loss through the vectorized schedule and bursty loss
with jitter through the ticked one, the hard case (stiff wall, motors at their limits, EBA off
and on), substeps, an oblique wall, guards that reject, and a stop in the middle of a run.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from compiled_identity import Calls, assert_same_arm_sides, assert_same_calls

from haptic_teleop.assembly import compiled_side
from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.errors import HapticTeleopError
from haptic_teleop.record.streams import BLOCK_TICKS
from haptic_teleop.scene.load import find_scene, load_scene

FWD = "network.forward"
BWD = "network.backward"
GE_10 = "{model: gilbert_elliott, p: 0.02, r: 0.16, one_minus_h: 0.9, one_minus_k: 0.0}"
HARD = (
    "operator.start_s=0.2",
    "operator.speed_m_per_s=0.5",
    "operator.distance_m=0.06",
    "slave.wall.stiffness_n_per_m=2e4",
    "slave.torque_limit_nm=[2.0, 2.0, 1.0]",
    "controllers.master.stiffness_n_per_m=1000",
    "controllers.slave.stiffness_n_per_m=3000",
    *(f"network.{d}.effects.delay.delay_s=0.1" for d in ("forward", "backward")),
    *(f"network.{d}.effects.loss={GE_10}" for d in ("forward", "backward")),
)
EBA_OFF = ("controllers.master.eba.enabled=false", "controllers.slave.eba.enabled=false")
TDPA_ZOH = tuple(f"controllers.{s}.eba.{k}" for s in ("master", "slave") for k in ("law=tdpa", "tdpa_controller=zoh"))
TDPA_VELOCITY = tuple(
    f"controllers.{s}.eba.{k}" for s in ("master", "slave") for k in ("law=tdpa", "tdpa_controller=velocity")
)
TWO_CONDITION = tuple(f"controllers.{s}.eba.law=two_condition" for s in ("master", "slave"))
WAVE = tuple(f"controllers.{s}.eba.law=wave" for s in ("master", "slave"))
WAVE_MATCHED = (
    *WAVE,
    "controllers.slave.eba.wave_matched=true",
    *(f"controllers.{s}.eba.wave_filter_hz=50" for s in ("master", "slave")),
    "controllers.slave.eba.wave_drift_gain_per_s=5",
)

CASES: dict[str, tuple[str, tuple[str, ...]]] = {
    # constant delay with uncorrelated loss: the vectorized schedule
    "ur5e_delay_loss": (
        "touch_ur5e_wall",
        (f"{FWD}.effects.loss.probability=0.1", f"{BWD}.effects.loss.probability=0.05"),
    ),
    # bursty loss and jitter: the ticked schedule (the Python Link and PlayoutBuffer objects)
    "ur5e_bursty_jitter": (
        "touch_ur5e_wall",
        (f"{FWD}.effects.loss={GE_10}", f"{BWD}.effects.delay.jitter_s=0.005", f"{BWD}.buffer.policy=fixed"),
    ),
    "dynamixel_delay_loss": ("touch_dynamixel_wall", (f"{FWD}.effects.loss.probability=0.1",)),
    "dynamixel_hard": ("touch_dynamixel_wall", HARD),
    "dynamixel_hard_eba_off": ("touch_dynamixel_wall", (*HARD, *EBA_OFF)),
    "ur5e_substeps": ("touch_ur5e_wall", ("simulation.substeps=2",)),
    "oblique": ("touch_ur5e_oblique_wall", ()),
    # TDPA's pooled step with the zoh controller (core/tdpa_coupled.coupled_tdpa), each sample
    # carrying its sender's energy, over delay and loss; and keeping half its input
    "ur5e_tdpa_zoh": (
        "touch_ur5e_wall",
        (*TDPA_ZOH, f"{FWD}.effects.loss.probability=0.1", f"{BWD}.effects.delay.delay_s=0.05"),
    ),
    # TDPA's admittance placement on both sides: each coupling's reference slips (the Dynamixel scene's
    # slave's controller binds in most ticks)
    "dynamixel_tdpa_zoh_admittance_hard": (
        "touch_dynamixel_wall",
        (
            *HARD,
            *TDPA_ZOH,
            *(
                f"controllers.{s}.eba.{k}"
                for s in ("master", "slave")
                for k in ("tdpa_placement=admittance", "tdpa_drift_gain_per_s=2")
            ),
        ),
    ),
    "dynamixel_tdpa_zoh_reflect_hard": (
        "touch_dynamixel_wall",
        (*HARD, *TDPA_ZOH, *(f"controllers.{s}.eba.tdpa_reflection=0.5" for s in ("master", "slave"))),
    ),
    # TDPA's field controller (velocity): its damper along the motion, the felt force the task force
    # of the applied torque (core/taskspace.task_force_of); the UR5e's 6-row Jacobian and the Touch's
    "ur5e_tdpa_velocity": (
        "touch_ur5e_wall",
        (*TDPA_VELOCITY, f"{FWD}.effects.loss.probability=0.1", f"{BWD}.effects.delay.delay_s=0.05"),
    ),
    "dynamixel_tdpa_velocity_hard": ("touch_dynamixel_wall", (*HARD, *TDPA_VELOCITY)),
    # the two conditions joint by joint (core/eba_two_condition_coupled.coupled_two_condition): a
    # ledger per joint in the kernel's state, each joint within its room, the felt force the task
    # force of the applied torque; the Dynamixel's small rooms with gravity compensation
    "ur5e_two_condition": (
        "touch_ur5e_wall",
        (*TWO_CONDITION, f"{FWD}.effects.loss.probability=0.1", f"{BWD}.effects.delay.delay_s=0.05"),
    ),
    "dynamixel_two_condition_hard": ("touch_dynamixel_wall", (*HARD, *TWO_CONDITION)),
    # wave variables' ports per task axis (core/wave_coupled.py): the waves in the samples' velocity
    # slots, used once, cut to the force the limits let through; matched, filtered and drift-corrected
    "ur5e_wave": (
        "touch_ur5e_wall",
        (*WAVE, f"{FWD}.effects.loss.probability=0.1", f"{BWD}.effects.delay.delay_s=0.05"),
    ),
    "dynamixel_wave_matched_hard": ("touch_dynamixel_wall", (*HARD, *WAVE_MATCHED)),
    # the master's Jacobian mapped into the task frame by a rotation that is not the identity
    "rotated_scaled_mapping": (
        "touch_dynamixel_wall",
        ("mapping={scale: 0.5, rotation_rpy_deg: [0, 0, 30], force_scale: 0.8}",),
    ),
}


def _scene(name: str, overrides: tuple[str, ...], duration_s: float = 2.0) -> Any:
    return load_scene(find_scene(name), overrides=[f"scene.duration_s={duration_s}", *overrides])


def _run(e: Engine, stop_at: int | None = None) -> tuple[Any, Calls]:
    sink = Calls()

    def progress(n: int) -> None:
        if stop_at is not None and n >= stop_at:
            e.request_stop()

    r = e.run(handle_sigint=False, progress=progress, sink=sink)
    return r, sink


def _both(scene: Any, stop_at: int | None = None, tweak: Any = None) -> list[tuple[Engine, Any, Calls]]:
    out = []
    for loop in ("compiled", "python"):
        e = Engine(scene, loop=loop)
        assert e.loop_kind == loop
        if tweak is not None:
            tweak(e)  # after the engine is built: the compiled loop takes its arrays when it runs
        out.append((e, *_run(e, stop_at)))
    return out


def _assert_same_run(runs: list[tuple[Engine, Any, Calls]]) -> None:
    (ec, rc, sc), (ep, rp, sp) = runs
    assert rc.ticks == rp.ticks
    assert_same_calls(sc.calls, sp.calls)
    assert_same_arm_sides(ec, ep)


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_arm_loop_equals_python_loop(case: str) -> None:
    name, overrides = CASES[case]
    runs = _both(_scene(name, overrides))
    _assert_same_run(runs)
    e, _, sink = runs[0]
    data = sink.data()
    schema = e.schema
    # Not vacuous: the tool moved, touched the wall, and samples crossed the network both ways.
    assert np.ptp(data[:, schema.group("s_x_m")], axis=0).max() > 5e-3
    assert np.abs(data[:, schema.group("s_contact_n")]).max() > 0.1
    for col in ("fwd_rx_seq", "bwd_rx_seq"):
        assert np.count_nonzero(data[:, schema.group(col)] >= 0) > 100
    # Blocks and packet records were handed over while the run went on, not only at its end.
    kinds = [k for k, _ in sink.calls]
    assert kinds[0] == "rows" and {"forward", "backward"} & set(kinds[: kinds.index("rows", 1)])


def test_the_hard_case_reaches_the_motor_limits_in_both_loops() -> None:
    name, overrides = CASES["dynamixel_hard"]
    runs = _both(_scene(name, overrides, duration_s=1.5))
    _assert_same_run(runs)
    assert runs[0][0].joint_limit_ticks["slave"] > 0


def test_a_stopped_compiled_run_leaves_the_python_loops_records() -> None:
    """Stopped at the same tick, both loops leave the same columns and packet records (the ticked
    schedule is decided one chunk of the loop at a time, so it never runs ahead of a stop)."""
    name, overrides = CASES["ur5e_bursty_jitter"]
    runs = _both(_scene(name, overrides), stop_at=700)
    assert runs[0][1].interrupted and runs[0][1].ticks == 700
    _assert_same_run(runs)


def test_guard_rejections_are_the_same_in_both_loops() -> None:
    """Limits below what the scene produces make the guards reject real samples: the compiled
    loop rejects the same ones, keeps the previous sample, and counts them."""

    def tweak(e: Engine) -> None:
        # z above 0.43 m (0.42 m) is "absurd": handle and tool start 0.438 m up, the table is at 0.408 m
        e.arm.slave.guard.limits = (0.6, 0.6, 0.43, 1.0, 1.0, 1.0)
        e.arm.master.guard.limits = (0.6, 0.6, 0.42, 1.0, 1.0, 1.0, 50.0, 50.0, 50.0)

    runs = _both(_scene("touch_ur5e_wall", ()), tweak=tweak)
    _assert_same_run(runs)
    e = runs[0][0]
    assert e.arm.slave.rejected_samples > 10 and e.arm.master.rejected_samples > 10


def test_the_split_step_is_mj_step() -> None:
    """mj_step1 then mj_step2 (what both arm loops call) gives mj_step's state, bit for bit, with
    the scenes' integrator (implicitfast) and Euler; RK4 is not split (MuJoCo's mj_step2 then
    integrates with Euler), which this test shows too."""
    import mujoco

    e = Engine(_scene("touch_ur5e_wall", ()), loop="python")
    m = e.arm.slave.plant.model
    for integrator, same in (("IMPLICITFAST", True), ("EULER", True), ("RK4", False)):
        m.opt.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator}")
        a, b = mujoco.MjData(m), mujoco.MjData(m)
        for d in (a, b):
            d.qpos[:] = e.arm.slave.plant.data.qpos
            d.ctrl[:] = 5.0
        for _ in range(200):
            mujoco.mj_step(m, a)
            mujoco.mj_step1(m, b)
            mujoco.mj_step2(m, b)
        assert np.array_equal(a.qpos, b.qpos) == same, integrator
        assert np.array_equal(a.qvel, b.qvel) == same, integrator


def test_the_contact_layout_reads_what_the_bindings_read() -> None:
    """The offsets the kernel reads mjData's contacts with (found through the bindings) read a
    real arm's contact as the bindings do."""
    import ctypes

    import mujoco

    from haptic_teleop.plants.mujoco_native import contact_layout

    layout = contact_layout()
    assert not isinstance(layout, str), layout
    ncon_off, contact_off, stride, pos, frame, g1, g2, efc = layout
    e = Engine(_scene("touch_ur5e_wall", ()), loop="python")
    plant = e.arm.slave.plant
    m, d = plant.model, mujoco.MjData(plant.model)
    d.qpos[:] = plant.data.qpos
    d.qpos[1] += 0.2  # shoulder down: the tool goes through the table
    mujoco.mj_forward(m, d)
    assert d.ncon >= 1
    assert ctypes.c_int32.from_address(d._address + ncon_off).value == d.ncon
    base = ctypes.c_uint64.from_address(d._address + contact_off).value
    for i in range(d.ncon):
        c = base + i * stride
        assert ctypes.c_int32.from_address(c + g1).value == d.contact.geom1[i]
        assert ctypes.c_int32.from_address(c + g2).value == d.contact.geom2[i]
        assert ctypes.c_int32.from_address(c + efc).value == d.contact.efc_address[i]
        got = np.frombuffer((ctypes.c_double * 3).from_address(c + pos), dtype=np.float64)
        assert np.array_equal(got, d.contact.pos[i])
        got = np.frombuffer((ctypes.c_double * 9).from_address(c + frame), dtype=np.float64)
        assert np.array_equal(got, d.contact.frame[i])


def test_arm_scenes_run_compiled_unless_they_cannot() -> None:
    scene = _scene("touch_ur5e_wall", ())
    e = Engine(scene)
    assert e.loop_kind == "compiled" and e.compiled_reason is None
    bad = _scene("touch_ur5e_wall", (f"{FWD}.effects.corrupt.probability=0.01",))
    e = Engine(bad)
    assert e.loop_kind == "python" and "corrupts payloads" in (e.compiled_reason or "")
    with pytest.raises(HapticTeleopError, match="corrupts payloads"):
        Engine(bad, loop="compiled")
    e = Engine(scene, loop="python")
    assert e.loop_kind == "python"


def test_both_arm_loops_record_the_same_bag_bytes(tmp_path: Any) -> None:
    """The loops hand the recorder the same blocks and packet records at the same points, so an
    arm scene's bag is the same file from either loop."""
    from haptic_teleop.engine.run import record_run

    name, overrides = CASES["ur5e_delay_loss"]
    scene = _scene(name, overrides, duration_s=1.5)
    bags = {}
    for loop in ("compiled", "python"):
        engine, _ = record_run(scene, tmp_path / loop / "bag", parallel=False, handle_sigint=False, loop=loop)
        assert engine.loop_kind == loop
        bags[loop] = (tmp_path / loop / "bag" / "bag.mcap").read_bytes()
    assert bags["compiled"] == bags["python"]


class Discard:
    """A sink that keeps nothing, noting the longest array it was given."""

    def __init__(self) -> None:
        self.longest = 0
        self.ticks = 0

    def append(self, rows: np.ndarray) -> None:
        self.longest = max(self.longest, len(rows))
        self.ticks += len(rows)

    def append_packets(self, direction: str, rows: np.ndarray) -> None:
        self.longest = max(self.longest, len(rows))


@pytest.mark.parametrize("case", ["ur5e_delay_loss", "ur5e_bursty_jitter"])
def test_compiled_arm_loop_memory_does_not_grow_with_duration(case: str) -> None:
    """What the compiled arm loop holds (tracemalloc: numpy's arrays and every Python object)
    peaks at the same size for a run four times as long, with either kind of network schedule;
    no array handed to the sink is longer than a block."""
    import tracemalloc

    name, overrides = CASES[case]
    # the network's windows are 10 s long (jitter's too: buffer_schedule.py): at least two of them
    # in the shorter run
    duration = 25.0
    peaks = []
    for d in (duration, 4 * duration):
        engine = Engine(_scene(name, overrides, duration_s=d), loop="compiled")
        sink = Discard()
        tracemalloc.start()
        try:
            engine.run(handle_sigint=False, sink=sink)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
        assert sink.ticks == engine.ticks and sink.longest <= BLOCK_TICKS + 200
    # Whole-run arrays would add 3 x 3000 ticks x 72 columns x 8 B = 5 MB or more.
    assert peaks[1] <= 1.1 * peaks[0] + 64_000, peaks


def _step_side(
    name: str, role: str, compiled: str, ticks: int = 400, overrides: tuple[str, ...] = ()
) -> dict[str, Any]:
    """One side of an arm scene stepped alone as a live node steps it (nodes/arm_side.py): its own
    plant, remote samples through its guard, the watchdog's gain on the force limit, the ledger's
    restart at scene time 0, the torques the plant applied back into the ledger. `compiled`: "" (the
    Python SideTick and plant), "law" (CompiledSideTick.torque after the plant's read and point),
    "tick" (CompiledSideTick's read_point, torque and step: the whole side tick compiled)."""
    from haptic_teleop.assembly.parts import build_arm_parts
    from haptic_teleop.assembly.side import side_ticks

    scene = _scene(name, overrides)
    parts = build_arm_parts(scene.config)
    mt, st = side_ticks(parts)
    master = role == "master"
    side = parts.master if master else parts.slave
    tick: Any = mt if master else st
    if compiled:
        tick, why = compiled_side.side_tick(side, parts, master, tick)
        assert why is None and isinstance(tick, compiled_side.CompiledSideTick)
    plant: Any = side.plant
    limit0 = tick.limit
    other = parts.slave if master else parts.master
    x0 = np.asarray(other.plant.point()[0] if master else parts.operator_origin_m)
    direction = np.asarray(parts.operator_direction)
    remote: tuple[float, ...] | None = None
    out: dict[str, list[Any]] = {k: [] for k in ("tau", "applied", "force", "ratio", "energy", "q", "qd", "contact")}
    for n in range(ticks):
        if compiled == "tick":
            q, qd, x_dev, v_dev = tick.read_point()
        else:
            q, qd = plant.read()
            x_dev, v_dev = plant.point()
        x, v = (parts.maps.to_task_x(x_dev), parts.maps.to_task_v(v_dev)) if master else (x_dev, v_dev)
        if n % 3 == 0:  # a new remote sample every third tick: the point 6 cm along the push, and on
            s = 0.06 * min(1.0, n / 200)
            vel = 0.3 if n < 200 else 0.0
            payload = (*(x0 + s * direction), *(vel * direction), *((0.0, 0.0, 4.0) if master else ()))
            if n == 150:
                payload = (float("nan"), *payload[1:])  # one the guard rejects
            if side.guard.accept(payload):
                remote = payload
                if "controllers.master.eba.law=wave" in overrides:  # its waves, used once (the node's `receive`)
                    tick.bound.receive(payload)
        if n == 50:  # scene time 0: the ledger restarts
            e = min(tick.bound.energy_j, tick.bound.params.initial_energy_j)
            tick.bound.restart(e)
        tick.limit = limit0 * (0.5 if 250 <= n < 300 else 1.0)  # the watchdog's gain
        tau = tick.torque(x, v, remote)
        hand = np.array([0.0, 0.0, -1.5]) if master else None
        applied = tick.step(tau, hand) if compiled == "tick" else plant.step(tau, hand)
        tick.bound.held[:] = applied
        out["tau"].append(np.array(tau))
        out["applied"].append(np.array(applied))
        out["force"].append(np.array(tick.force))
        out["ratio"].append(tick.ratio)
        out["energy"].append(tick.bound.energy_j)
        out["q"].append(np.array(q))
        out["qd"].append(np.array(qd))
        out["contact"].append(np.concatenate(plant.contact_wrench()))
    res = {k: np.array(v) for k, v in out.items()}
    res["limited"] = tick.limited_ticks
    res["rejected"] = side.guard.rejected
    return res


@pytest.mark.parametrize(
    ("name", "role", "law"),
    [
        ("touch_ur5e_wall", "master", ()),
        ("touch_ur5e_wall", "slave", ()),
        ("touch_dynamixel_wall", "slave", ()),
        ("touch_dynamixel_wall", "slave", TWO_CONDITION),
        ("touch_ur5e_wall", "master", WAVE_MATCHED),
        ("touch_dynamixel_wall", "slave", WAVE_MATCHED),
    ],
)
def test_the_live_nodes_compiled_side_tick_is_the_python_side_tick(name: str, role: str, law: tuple[str, ...]) -> None:
    """A side stepped alone (the live nodes' per-side tick) gives the same torques, forces,
    reservoirs, joints and wall wrenches, bit for bit, with `CompiledSideTick` (the law alone, or the
    whole side tick with the plant's read, point and step) as with `SideTick` and the Python plant;
    with the two-condition law too (its restart: each joint's ledger)."""
    p = _step_side(name, role, "", overrides=law)
    for mode in ("law", "tick"):
        c = _step_side(name, role, mode, overrides=law)
        for key in c:
            assert np.array_equal(c[key], p[key]), (mode, key)
    assert c["rejected"] == 1
    assert np.any(c["force"] != 0.0) and np.any(c["energy"] != c["energy"][0])
    if role == "slave" and law != WAVE_MATCHED:  # (the waves of this drive are too small to reach it)
        assert np.any(c["contact"][:, :3] != 0.0)  # the tool reached its wall


def test_a_side_the_kernel_does_not_compile_keeps_the_python_side_tick() -> None:
    """A plant other than the bare MujocoArm (here a subclass, as plant effects wrap it): the live
    node gets its Python SideTick back, with the reason it logs."""
    from haptic_teleop.assembly.parts import build_arm_parts
    from haptic_teleop.assembly.side import side_ticks
    from haptic_teleop.plants.arm import MujocoArm

    class Wrapped(MujocoArm):
        pass

    parts = build_arm_parts(_scene("touch_ur5e_wall", ()).config)
    _, st = side_ticks(parts)
    parts.slave.plant.__class__ = Wrapped
    tick, why = compiled_side.side_tick(parts.slave, parts, False, st)
    assert tick is st
    assert why is not None and "MuJoCo" in why
