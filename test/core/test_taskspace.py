"""Task-space teleoperation: workspace mapping, coupling laws on vectors, J.T F, null-space damping."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.core.eba import coupling1
from haptic_teleop.core.taskspace import (
    TaskCouplingParams,
    TaskSpaceLaw,
    WorkspaceMapping,
    coupling,
    force_feedback,
    jacobian_times,
    jacobian_transpose,
    null_space_damping,
    orientation_coupling,
    orientation_error,
    rotation_from_rpy,
    task_force_of,
    tick_scratch,
)

angles = st.floats(-math.pi, math.pi)
seeds = st.integers(0, 2**32 - 1)


def _rodrigues(axis, angle):
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


@settings(max_examples=100, deadline=None)
@given(roll=angles, pitch=angles, yaw=angles, seed=seeds)
def test_mapping_formulas_and_inverses(roll, pitch, yaw, seed):
    rng = np.random.default_rng(seed)
    rot = rotation_from_rpy(roll, pitch, yaw)
    wm = WorkspaceMapping(scale=2.5, rotation=rot, offset_m=(0.4, -0.1, 0.3), force_scale=0.2)
    r = np.array(rot)
    x, v, f = rng.normal(size=(3, 3))
    assert wm.position_to_task(x) == pytest.approx(2.5 * r @ x + [0.4, -0.1, 0.3], abs=1e-12)
    assert wm.velocity_to_task(v) == pytest.approx(2.5 * r @ v, abs=1e-12)
    assert wm.force_to_master(f) == pytest.approx(0.2 * r.T @ f, abs=1e-12)
    assert wm.position_to_master(wm.position_to_task(x)) == pytest.approx(x, abs=1e-12)
    assert wm.velocity_to_master(wm.velocity_to_task(v)) == pytest.approx(v, abs=1e-12)
    assert wm.force_to_task(wm.force_to_master(f)) == pytest.approx(f, abs=1e-12)
    # rpy: R = Rz(yaw) Ry(pitch) Rx(roll)
    expect = _rodrigues((0, 0, 1), yaw) @ _rodrigues((0, 1, 0), pitch) @ _rodrigues((1, 0, 0), roll)
    assert r == pytest.approx(expect, abs=1e-12)


def test_one_axis_mapping_is_the_identity():
    """The 1-DoF special case: every map returns its input's bits (the 1-DoF law is unchanged)."""
    wm = WorkspaceMapping.identity(1)
    for value in (0.0, 0.1, -3.7e-5, 12.25):
        x = np.array([value])
        for fn in (
            wm.position_to_task,
            wm.position_to_master,
            wm.velocity_to_task,
            wm.velocity_to_master,
            wm.force_to_master,
            wm.force_to_task,
        ):
            assert fn(x)[0] == value


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        (dict(scale=0.0), "scale must be finite and > 0"),
        (dict(force_scale=-1.0), "force_scale must be finite and > 0"),
        (dict(scale=math.nan), "scale must be finite"),
        (dict(rotation=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0))), "proper rotation"),  # reflection
        (dict(rotation=((1.0, 0.1, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))), "proper rotation"),  # shear
        (dict(rotation=((1.0, 0.0), (0.0, 1.0))), "3x3"),
        (dict(offset_m=(0.0, 0.0)), "offset_m must have 3 values"),
        (dict(offset_m=(0.0, math.inf, 0.0)), "offset_m must be finite"),
        (dict(rotation=((-1.0,),), offset_m=(0.0,)), "proper rotation"),
    ],
)
def test_bad_mapping_is_refused_with_the_reason(kwargs, words):
    with pytest.raises(ValueError, match=words):
        WorkspaceMapping(**kwargs)


@settings(max_examples=50, deadline=None)
@given(seed=seeds, d=st.sampled_from([1, 3]))
def test_coupling_is_coupling1_per_axis(seed, d):
    rng = np.random.default_rng(seed)
    c1, c2, rx, rv, x, v = rng.normal(size=(6, d))
    out = np.empty(d)
    coupling(out, c1, c2, rx, rv, x, v)
    for i in range(d):
        assert out[i] == coupling1(c1[i], c2[i], rx[i], rv[i], x[i], v[i])
    force_feedback(out, 0.5, rx)
    assert list(out) == [0.5 * r for r in rx]


@settings(max_examples=300, deadline=None)
@given(
    axis=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(lambda a: np.linalg.norm(a) > 1e-3),
    angle=st.one_of(
        st.floats(0.0, math.pi),
        st.sampled_from([0.0, 1e-12, 1e-7, math.pi - 1e-9, math.pi - 1e-5, 0.9 * math.pi, math.pi]),
    ),
    roll=angles,
    pitch=angles,
    yaw=angles,
)
def test_orientation_error_is_the_rotation_vector(axis, angle, roll, pitch, yaw):
    """R_hold = Rot(axis, angle) @ R_tool: the error is angle * axis (the log map), up to pi."""
    r_tool = np.array(rotation_from_rpy(roll, pitch, yaw))
    a = np.asarray(axis) / np.linalg.norm(axis)
    r_hold = _rodrigues(a, angle) @ r_tool
    e = np.empty(3)
    orientation_error(e, r_hold, r_tool, tick_scratch(3, 3))
    if angle > math.pi - 1e-6:  # at pi, axis and -axis are the same rotation
        assert np.linalg.norm(e) == pytest.approx(angle, abs=1e-6)
        assert abs(float(e @ a)) == pytest.approx(angle, abs=1e-5)
    else:
        assert e == pytest.approx(angle * a, abs=1e-9)


def test_orientation_coupling_turns_the_tool_towards_the_held_orientation():
    r_tool = np.eye(3)
    r_hold = _rodrigues((0, 0, 1), 0.1)  # held: 0.1 rad about +z from the tool
    m = np.empty(3)
    orientation_coupling(
        m, np.array([5.0, 5.0, 5.0]), np.array([0.5, 0.5, 0.5]), r_hold, r_tool, np.zeros(3), tick_scratch(3, 3)
    )
    assert m == pytest.approx([0.0, 0.0, 0.5], abs=1e-12)
    orientation_coupling(
        m, np.zeros(3), np.array([0.5, 0.5, 0.5]), r_tool, r_tool, np.array([1.0, -2.0, 0.0]), tick_scratch(3, 3)
    )
    assert m == pytest.approx([-0.5, 1.0, 0.0], abs=1e-12)


@settings(max_examples=50, deadline=None)
@given(seed=seeds, m=st.sampled_from([1, 3, 6]), n=st.integers(1, 7))
def test_jacobian_products_match_numpy(seed, m, n):
    rng = np.random.default_rng(seed)
    jac = rng.normal(size=(m, n))
    w, qd = rng.normal(size=m), rng.normal(size=n)
    tau, vel = np.empty(n), np.empty(m)
    jacobian_transpose(tau, jac, w)
    jacobian_times(vel, jac, qd)
    assert tau == pytest.approx(jac.T @ w, abs=1e-12)
    assert vel == pytest.approx(jac @ qd, abs=1e-12)


@settings(max_examples=300, deadline=None)
@given(
    seed=seeds,
    m=st.sampled_from([3, 6]),
    n=st.integers(1, 7),
    rank_drop=st.booleans(),
    spread=st.floats(0.0, 4.0),
    mu=st.sampled_from([1e-3, 0.01, 0.1]),
)
def test_null_space_damping_is_dissipative(seed, m, n, rank_drop, spread, mu):
    """qd.T tau_null <= 0 for any Jacobian (also singular ones) and any joint velocity, with
    per-joint damping spread over `spread` decades; and it is -N D N qd with N = mu^2 (J.T J + mu^2 I)^-1
    (worst error over 20,000 random cases: 8e-12 of max|d| max|qd|)."""
    rng = np.random.default_rng(seed)
    jac = rng.normal(scale=0.3, size=(m, n))
    if rank_drop and m > 1:
        jac[-1] = jac[0] * rng.normal()  # a singular configuration
    qd = rng.normal(size=n) * 10.0 ** rng.uniform(-3, 1)
    d = 10.0 ** rng.uniform(-spread / 2, spread / 2, size=n)
    tau = np.empty(n)
    null_space_damping(tau, jac, qd, d, mu, tick_scratch(m, n))
    power = float(qd @ tau)
    assert power <= 1e-12 * float(d @ (qd * qd))
    # N from the SVD (accurate however ill-conditioned J.T J + mu^2 I is): eigenvalues mu^2 / (s^2 + mu^2)
    _u, sv, vt = np.linalg.svd(jac, full_matrices=True)
    lam = np.ones(n)
    lam[: min(m, n)] = mu * mu / (sv[: min(m, n)] ** 2 + mu * mu)
    big_n = vt.T @ np.diag(lam) @ vt
    scale = float(np.abs(d).max() * np.abs(qd).max())
    assert tau == pytest.approx(-big_n @ (d * (big_n @ qd)), rel=1e-6, abs=1e-9 * scale)


@settings(max_examples=200, deadline=None)
@given(seed=seeds, m=st.sampled_from([3, 6]), n=st.integers(1, 7), rank_drop=st.booleans())
def test_task_force_of_is_the_least_squares_force_of_a_torque(seed, m, n, rank_drop):
    """F with J.T F closest to tau: the normal equations' J (J.T F - tau) = 0 up to the 1e-12
    regularization, for any Jacobian (a singular one too: finite, and the residual's projection
    small); with full row rank (m <= n) numpy's lstsq solution to 1e-6 relative."""
    rng = np.random.default_rng(seed)
    jac = rng.normal(scale=0.3, size=(m, n))
    if rank_drop and m > 1:
        jac[-1] = jac[0] * rng.normal()
    tau = rng.normal(size=n) * 10.0 ** rng.uniform(-2, 1)
    f = np.empty(m)
    task_force_of(f, jac, tau, tick_scratch(m, n))
    assert np.all(np.isfinite(f))
    scale = float(np.abs(tau).max()) * float(np.abs(jac).max()) + 1e-300
    sv = np.linalg.svd(jac, compute_uv=False)
    if m <= n and not rank_drop and sv.min() > 1e-3 * sv.max():
        want = np.linalg.lstsq(jac.T, tau, rcond=None)[0]
        assert f == pytest.approx(want, rel=1e-6, abs=1e-9 * float(np.abs(want).max()))
        assert np.abs(jac @ (jac.T @ f - tau)).max() <= 1e-8 * scale


def test_null_space_damping_damps_self_motion_only():
    """A 3x6 Jacobian of full rank: the null torque is a damper on the self-motion, and nearly
    nothing along the task (N's eigenvalue there is mu^2 / (sigma^2 + mu^2), applied twice)."""
    rng = np.random.default_rng(4)
    jac = rng.normal(scale=0.3, size=(3, 6))
    _u, s, vt = np.linalg.svd(jac)
    assert s.min() > 0.1
    self_motion = vt[3]  # a joint velocity in the null space of J
    task_motion = vt[0]
    d = np.full(6, 2.0)
    tau = np.empty(6)
    null_space_damping(tau, jac, self_motion, d, 0.01, tick_scratch(*jac.shape))
    assert tau == pytest.approx(-2.0 * self_motion, abs=1e-9)
    null_space_damping(tau, jac, task_motion, d, 0.01, tick_scratch(*jac.shape))
    leak = 0.01**2 / (s[0] ** 2 + 0.01**2)  # N's eigenvalue along a task direction
    assert leak < 1e-3
    assert tau == pytest.approx(-2.0 * leak**2 * task_motion, rel=1e-6, abs=1e-15)


def test_task_space_law_torques():
    rng = np.random.default_rng(7)
    jac = rng.normal(size=(3, 4))
    params = TaskCouplingParams(stiffness_n_per_m=(100.0, 200.0, 300.0), damping_n_s_per_m=(1.0, 2.0, 3.0))
    law = TaskSpaceLaw(params, 4)
    x, v, rx, rv = rng.normal(size=(4, 3))
    qd = rng.normal(size=4)
    assert law.torque(jac, qd, x, v, None, None) == pytest.approx(np.zeros(4))  # nothing received yet
    f = np.array([100.0, 200.0, 300.0]) * (rx - x) + np.array([1.0, 2.0, 3.0]) * (rv - v)
    assert law.torque(jac, qd, x, v, rx, rv) == pytest.approx(jac.T @ f, rel=1e-12)
    # force reflection
    law = TaskSpaceLaw(TaskCouplingParams(law="force", force_gain=0.5), 4)
    assert law.torque(jac, qd, x, v, None, None, remote_force=rx) == pytest.approx(jac.T @ (0.5 * rx), rel=1e-12)
    # null-space damping is added
    params = TaskCouplingParams(null_damping_nm_s_per_rad=(1.0, 1.0, 1.0, 1.0))
    law = TaskSpaceLaw(params, 4)
    tau_null = np.empty(4)
    null_space_damping(tau_null, jac, qd, np.ones(4), params.pinv_damping_m, tick_scratch(*jac.shape))
    assert law.torque(jac, qd, x, v, x, v) == pytest.approx(tau_null, abs=1e-12)


def test_task_space_law_holds_the_start_orientation():
    """Orientation 'hold': the first tick's tool orientation is held; turning away gives a moment back."""
    rng = np.random.default_rng(3)
    jac = rng.normal(size=(6, 6))
    params = TaskCouplingParams(
        stiffness_n_per_m=(0.0, 0.0, 0.0),
        damping_n_s_per_m=(0.0, 0.0, 0.0),
        orientation="hold",
        rot_stiffness_nm_per_rad=(10.0, 10.0, 10.0),
        rot_damping_nm_s_per_rad=(0.0, 0.0, 0.0),
    )
    law = TaskSpaceLaw(params, 6)
    z = np.zeros(3)
    start = np.array(rotation_from_rpy(0.3, -0.2, 1.0))
    assert law.torque(jac, np.zeros(6), z, z, z, z, r_tool=start) == pytest.approx(np.zeros(6), abs=1e-12)
    turned = _rodrigues((1, 0, 0), 0.05) @ start  # the tool turned +0.05 rad about x
    tau = law.torque(jac, np.zeros(6), z, z, z, z, r_tool=turned)
    assert law.wrench[3:] == pytest.approx([-0.5, 0.0, 0.0], abs=1e-12)
    assert tau == pytest.approx(jac.T @ law.wrench, abs=1e-12)
    with pytest.raises(ValueError, match="r_tool"):
        law.torque(jac, np.zeros(6), z, z, z, z)


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        (dict(law="spring"), "law must be one of"),
        (dict(orientation="fixed"), "orientation must be one of"),
        (dict(stiffness_n_per_m=(1.0, 2.0)), "1 or 3 values"),
        (dict(damping_n_s_per_m=(1.0,)), "damping_n_s_per_m must have 3 values"),
        (dict(stiffness_n_per_m=(-1.0, 0.0, 0.0)), "stiffness_n_per_m must be finite and >= 0"),
        (dict(pinv_damping_m=0.0), "pinv_damping_m must be finite and > 0"),
        (dict(null_damping_nm_s_per_rad=(1.0, math.nan)), "null_damping"),
    ],
)
def test_bad_task_params_are_refused(kwargs, words):
    with pytest.raises(ValueError, match=words):
        TaskCouplingParams(**kwargs)


def test_kernels_compile_with_numba_and_give_the_interpreted_results():
    """Every per-tick array function compiles with numba as it is, with the functions it calls
    (`assembly.parts.arm_kernels`: compiling.compile_tree), and gives what the interpreted function
    gives on the same inputs (n = 1, 3, 6)."""
    pytest.importorskip("numba")
    from haptic_teleop.assembly.parts import arm_kernels
    from haptic_teleop.core import eba_coupled
    from haptic_teleop.core import taskspace as ts

    k = arm_kernels()
    # the laws' steps too (run through the arm loops: test_compiled_arm.py's cases, compiled = Python)
    laws = {"coupled_tdpa", "coupled_two_condition", "room_within", "wave_ports_begin", "wave_ports_end"}
    assert k is not None and set(k) == {fn.__name__ for fn in ts.KERNEL_FUNCTIONS} | laws
    rng = np.random.default_rng(11)
    rot = np.array(rotation_from_rpy(0.3, -1.0, 2.0))
    near_pi = _rodrigues((1.0, 2.0, -0.5), math.pi - 1e-7) @ rot
    turned = _rodrigues((0, 1, 0), 0.4) @ rot
    for n in (1, 3, 6):
        d = 10.0 ** rng.uniform(-2, 1, size=n)
        bg, gain = 4.0 * d / 1e-3, d / 1e-3
        tau, held, dq = rng.normal(size=n) * 30.0, rng.normal(size=n), rng.normal(size=n) * 1e-3
        step, low, high = np.full(n, 0.3), -np.full(n, 5.0), np.full(n, 4.0)
        jac3, jac6 = rng.normal(size=(3, n)), rng.normal(size=(6, n))
        x3, v3, w3, w6 = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3), rng.normal(size=6)
        calls = [
            ("coupled_reservoir", (0.2, gain, held, dq), None),
            ("coupled_descent_cost", (tau, step, bg), None),
            ("task_demand", (jac3, w3, bg), None),
            ("coupled_bounded", (np.zeros(n), tau, 0.05, bg), 0),
            ("slew_bounded", (np.zeros(n), tau, held, 0.05, step, bg), 0),
            ("joint_limited", (np.zeros(n), tau, low, high, True), 0),
            ("joint_limited", (np.zeros(n), tau, low, high, False), 0),
            ("jacobian_transpose", (np.zeros(n), jac6, w6), 0),
            ("jacobian_times", (np.zeros(3), jac3, tau), 0),
            ("null_space_damping", (np.zeros(n), jac3, dq, d, 0.01, tick_scratch(3, n)), 0),
            ("null_space_damping", (np.zeros(n), jac6, dq, d, 0.01, tick_scratch(6, n)), 0),
            ("task_force_of", (np.zeros(3), jac3, tau, tick_scratch(3, n)), 0),
            ("task_force_of", (np.zeros(6), jac6, tau, tick_scratch(6, n)), 0),
            ("map_point", (np.zeros(3), rot, 2.0, w3, x3), 0),
            ("unmap_point", (np.zeros(3), rot, 2.0, w3, x3), 0),
            ("map_vector_back", (np.zeros(3), rot, 0.5, x3), 0),
            ("coupling", (np.zeros(3), w3, v3, x3, v3 * 2, w3 * 3, x3), 0),
            ("orientation_coupling", (np.zeros(3), w3, v3, rot, near_pi, x3, tick_scratch(3, 3)), 0),
            (
                "orientation_coupling",
                (np.zeros(3), w3, v3, rot, turned, x3, tick_scratch(3, 3)),
                0,
            ),
        ]
        for name, args, out_index in calls:
            fn = getattr(ts, name, None) or getattr(eba_coupled, name)
            py_args = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
            nb_args = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
            r_py = fn(*py_args)
            r_nb = k[name](*nb_args)
            if out_index is None:
                assert r_nb == pytest.approx(r_py, rel=1e-12, abs=1e-300), name
            else:
                assert nb_args[out_index] == pytest.approx(py_args[out_index], rel=1e-12, abs=1e-12), name
    # the per-side objects with the compiled functions: the same results as interpreted
    from haptic_teleop.core.eba_coupled import CoupledEnergyBound, CoupledEnergyBoundParams

    for slew in ((), (300.0,) * 6):
        params = CoupledEnergyBoundParams(1e-3, tuple(10.0 ** rng.uniform(-2, 0, size=6)), 0.05, slew_nm_per_s=slew)
        plain, fast = CoupledEnergyBound(params), CoupledEnergyBound(params, k)
        q = np.zeros(6)
        for _ in range(50):
            tau_d = rng.normal(size=6) * 20.0
            assert fast.step(q, tau_d) == pytest.approx(plain.step(q, tau_d), rel=1e-9, abs=1e-12)
            assert fast.energy_j == pytest.approx(plain.energy_j, rel=1e-9, abs=1e-12)
            q = q + rng.normal(size=6) * 1e-3
    params = TaskCouplingParams(
        orientation="hold", rot_stiffness_nm_per_rad=(3.0, 3.0, 3.0), null_damping_nm_s_per_rad=(0.5,) * 6
    )
    plain_law, fast_law = TaskSpaceLaw(params, 6), TaskSpaceLaw(params, 6, k)
    for _ in range(5):
        jac, qd = rng.normal(size=(6, 6)), rng.normal(size=6)
        x, v, rx, rv = rng.normal(size=(4, 3))
        r_tool = _rodrigues(rng.normal(size=3), rng.uniform(0, 1)) @ rot
        expect = plain_law.torque(jac, qd, x, v, rx, rv, r_tool=r_tool).copy()
        assert fast_law.torque(jac, qd, x, v, rx, rv, r_tool=r_tool) == pytest.approx(expect, rel=1e-9, abs=1e-12)


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-1.0, 1.0),
    v=st.floats(-1.0, 1.0),
    rx=st.floats(-1.0, 1.0),
    rv=st.floats(-1.0, 1.0),
    rf=st.floats(-50.0, 50.0),
    c1=st.floats(0.0, 1e4),
    c2=st.floats(0.0, 100.0),
)
def test_one_axis_task_law_is_the_one_dof_law(x, v, rx, rv, rf, c1, c2):
    """One axis, one joint, J = [[1]], identity mapping: the task-space law gives the bits of the
    1-DoF controller's law (position on both sides, force reflection on the master)."""
    from haptic_teleop.core.controller import ControllerParams, TeleopController
    from haptic_teleop.core.eba_state import EnergyBoundParams

    bound = EnergyBoundParams(1e-3, (1.0,), enabled=False)
    wm = WorkspaceMapping.identity(1)
    jac = np.array([[1.0]])
    a = lambda value: np.array([value])  # noqa: E731
    slave = TeleopController(ControllerParams(role="slave", stiffness_n_per_m=c1, damping_n_s_per_m=c2), bound)
    slave.set_remote((rx, rv))
    law = TaskSpaceLaw(TaskCouplingParams(stiffness_n_per_m=(c1,), damping_n_s_per_m=(c2,)), 1)
    tau = law.torque(jac, a(v), a(x), a(v), wm.position_to_task(a(rx)), wm.velocity_to_task(a(rv)))
    assert tau[0] == slave.desired_force([x], [v])[0]
    master = TeleopController(ControllerParams(role="master", law="force", force_gain=0.7), bound)
    master.set_remote((rf, rx, rv))
    law = TaskSpaceLaw(
        TaskCouplingParams(law="force", force_gain=0.7, stiffness_n_per_m=(c1,), damping_n_s_per_m=(c2,)), 1
    )
    tau = law.torque(jac, a(v), a(x), a(v), None, None, remote_force=wm.force_to_master(a(rf)))
    assert tau[0] == master.desired_force([x], [v])[0]
