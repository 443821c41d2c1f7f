"""The compiled tick loop for arm scenes (numba), imported only by `haptic_teleop.engine.compiled.arm_host`.

The tick is `engine/loop.py`'s, in the same order, composed of each side's compiled stage
(assembly/side_kernel.py: `point`, `side_torque`, `guarded`, `plant_step`, inlined) and the
operator's profile (core/operator.py, compiled from its one definition). Importing this module
needs numba and links MuJoCo's C functions (plants/mujoco_native.py). numba caches the compiled
loop beside this file; `compiling.load` drops that cache when any source it is built from changed.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from haptic_teleop.assembly.side_kernel import (
    F_B_HAND,
    F_FORCE_SCALE,
    F_K_HAND,
    F_SCALE,
    I_DATA,
    I_MODEL,
    I_N,
    I_NV,
    I_ROTATIONAL,
    S_ENERGY,
    S_EXTRA,
    T_F,
    T_FORCE,
    T_HELD,
    T_I,
    T_OFFSET,
    T_ROT,
    T_S,
    T_WRENCH,
    W_FELT,
    carries_energy,
    detach,
    detach_work,
    guarded,
    jacobian,
    map_point,
    map_vector,
    map_vector_back,
    plant_step,
    point,
    read_joints,
    sample_velocity,
    side_torque,
    unmap_point,
    work,
)
from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import operator as op
from haptic_teleop.engine.compiled import driver
from haptic_teleop.plants.mujoco_native import borrowed, mj_step, mj_step1, mj_step2

jit = numba.njit(cache=True, nogil=True)
# The tick's own helpers take the side tuples: inlined (numba IR), so a call does not copy the
# tuples (36 and 17 array structs, by value) onto the stack.
inline = numba.njit(cache=True, nogil=True, inline="always")
# The tick loops without numba's reference counting (NRT): they allocate nothing (the host makes
# every array), and the views and arguments of the tick's parts would otherwise be counted in and
# out with atomic operations every tick (as the 1-DoF kernel's `loop_jit`).
loop_jit = numba.njit(cache=True, nogil=True, _nrt=False)
push1 = compile_tree(op.push1)
sinusoid1 = compile_tree(op.sinusoid1)


# The operator, in OP: profile code (axis_host.PROFILE_CODES), x0, start, speed, t_end, x_end,
# amplitude, omega, origin (3), direction (3), period.
O_PROFILE, O_X0, O_START, O_SPEED, O_T_END, O_X_END, O_AMP, O_W, O_ORIGIN, O_DIR, O_PERIOD = (
    0, 1, 2, 3, 4, 5, 6, 7, 8, 11, 14,
)  # fmt: skip
O_SIZE = 15
# Row columns, in COLS: the first column of each group, in this order.
GROUPS = (
    "op_x_m", "op_v_m_per_s", "op_force_n",
    "m_q", "m_qd", "m_tau_nm", "m_x_m", "m_v_m_per_s", "m_force_n", "m_force_desired_n", "m_energy_j",
    "s_q", "s_qd", "s_tau_nm", "s_x_m", "s_v_m_per_s", "s_force_n", "s_force_desired_n", "s_energy_j",
    "s_contact_n", "s_contact_torque_nm", "fwd_rx_seq", "bwd_rx_seq", "fwd_occupancy", "bwd_occupancy",
)  # fmt: skip
(
    C_OP_X, C_OP_V, C_OP_F,
    C_M_Q, C_M_QD, C_M_TAU, C_M_X, C_M_V, C_M_F, C_M_FD, C_M_E,
    C_S_Q, C_S_QD, C_S_TAU, C_S_X, C_S_V, C_S_F, C_S_FD, C_S_E,
    C_S_CF, C_S_CT, C_FRX, C_BRX, C_FOCC, C_BOCC,
) = range(len(GROUPS))  # fmt: skip
assert len(GROUPS) == 25, "column_starts lists 25 group starts"


# The tick's vectors (`tick_vectors`), in this order: joints, torques and points of both sides,
# the wall's force and torque, the operator's target (task and device frames), the hand force.
(
    V_QM, V_QDM, V_QS, V_QDS, V_TAU_M, V_TAU_S, V_APP_M, V_APP_S,
    V_XM_DEV, V_VM_DEV, V_XM, V_VM, V_XS, V_VS, V_F_ENV, V_T_ENV,
    V_XD_T, V_VD_T, V_XD, V_VD, V_F_HAND, V_OP_F,
) = range(22)  # fmt: skip
V_SIZE = 22


@inline  # type: ignore[misc]
def tick_vectors(own: np.ndarray, nm: int, ns: int) -> Any:
    """The tick's vectors: `borrowed` views of the rows of `own` (V_SIZE rows, at least 3 and
    each side's joint count wide), which the caller keeps alive while they are used."""
    return (
        borrowed(own[V_QM, :nm]),
        borrowed(own[V_QDM, :nm]),
        borrowed(own[V_QS, :ns]),
        borrowed(own[V_QDS, :ns]),
        borrowed(own[V_TAU_M, :nm]),
        borrowed(own[V_TAU_S, :ns]),
        borrowed(own[V_APP_M, :nm]),
        borrowed(own[V_APP_S, :ns]),
        borrowed(own[V_XM_DEV, :3]),
        borrowed(own[V_VM_DEV, :3]),
        borrowed(own[V_XM, :3]),
        borrowed(own[V_VM, :3]),
        borrowed(own[V_XS, :3]),
        borrowed(own[V_VS, :3]),
        borrowed(own[V_F_ENV, :3]),
        borrowed(own[V_T_ENV, :3]),
        borrowed(own[V_XD_T, :3]),
        borrowed(own[V_VD_T, :3]),
        borrowed(own[V_XD, :3]),
        borrowed(own[V_VD, :3]),
        borrowed(own[V_F_HAND, :3]),
        borrowed(own[V_OP_F, :3]),
    )


# The run's constants the tick reads (`run_constants`), in this order.
K_SCALE, K_K_HAND, K_B_HAND, K_PERIOD, K_NM, K_NS, K_INV_SCALE, K_INV_FORCE_SCALE = range(8)


@inline  # type: ignore[misc]
def column_starts(cols: np.ndarray) -> Any:
    """The row's group starts (GROUPS, in COLS) as a tuple, read once a call: values, not loads
    that each store into the row would make the compiler repeat (the row and `cols` may alias)."""
    return (
        cols[0], cols[1], cols[2], cols[3], cols[4], cols[5], cols[6], cols[7], cols[8], cols[9], cols[10],
        cols[11], cols[12], cols[13], cols[14], cols[15], cols[16], cols[17], cols[18], cols[19], cols[20],
        cols[21], cols[22], cols[23], cols[24],
    )  # fmt: skip


@inline  # type: ignore[misc]
def run_constants(ms: Any, ss: Any, ov: np.ndarray) -> Any:
    """What the tick reads of the parameters, read once before the loop: the mapping's scales, the
    hand's stiffness and damping, the period, both sides' joint counts, the scales' inverses."""
    MF = ms[T_F]
    scale = MF[F_SCALE]
    return (
        scale, MF[F_K_HAND], MF[F_B_HAND], ov[O_PERIOD], ms[T_I][I_N], ss[T_I][I_N],
        1.0 / scale, 1.0 / MF[F_FORCE_SCALE],
    )  # fmt: skip


@inline  # type: ignore[misc]
def sense(ms: Any, ss: Any, mw: Any, sw: Any, v: Any, c: Any) -> None:
    """Step 1 of the tick: both arms (mj_step1: the state, kinematics and gravity torques of this
    instant), the wall's wrench of the last period, the master's point in the task frame."""
    MI, SI = ms[T_I], ss[T_I]
    xm_dev, vm_dev = v[V_XM_DEV], v[V_VM_DEV]
    f_env, t_env, s_wrench = v[V_F_ENV], v[V_T_ENV], ss[T_WRENCH]
    mj_step1(MI[I_MODEL], MI[I_DATA])
    read_joints(ms, v[V_QM], v[V_QDM])
    point(ms, v[V_QDM], xm_dev, vm_dev, mw)
    mj_step1(SI[I_MODEL], SI[I_DATA])
    read_joints(ss, v[V_QS], v[V_QDS])
    point(ss, v[V_QDS], v[V_XS], v[V_VS], sw)
    for k in range(3):
        f_env[k] = s_wrench[k]
        t_env[k] = s_wrench[3 + k]
    map_point(v[V_XM], ms[T_ROT], c[K_SCALE], ms[T_OFFSET], xm_dev)
    map_vector(v[V_VM], ms[T_ROT], c[K_SCALE], vm_dev)


@inline  # type: ignore[misc]
def forward_sample(out: np.ndarray, v: Any, ms: Any) -> None:
    """The forward packet's payload: the master's x, v in the task frame; with TDPA its pooled
    input energy last (ArmSideStage.tick)."""
    x, vel = v[V_XM], v[V_VM]
    for k in range(3):
        out[k] = x[k]
        out[3 + k] = sample_velocity(ms, vel, k)
    if carries_energy(ms):
        out[6] = ms[T_S][S_EXTRA + 4]


@inline  # type: ignore[misc]
def backward_sample(out: np.ndarray, v: Any, ss: Any) -> None:
    """The backward packet's payload: the slave's x, v and the wall's force; with TDPA its pooled
    input energy last."""
    x, vel, f = v[V_XS], v[V_VS], v[V_F_ENV]
    for k in range(3):
        out[k] = x[k]
        out[3 + k] = sample_velocity(ss, vel, k)
        out[6 + k] = f[k]
    if carries_energy(ss):
        out[9] = ss[T_S][S_EXTRA + 4]


@inline  # type: ignore[misc]
def released(side: Any, seq: int, hist: np.ndarray, mask: int) -> int:
    """The schedule's release at this tick (`seq`, -1: none) from the sender's ring, through the
    receiving side's guard; returns `seq` (the row's `received` column)."""
    if seq >= 0:
        guarded(side, hist[seq & mask])
    return seq


@inline  # type: ignore[misc]
def finish_tick(
    n: int, ms: Any, ss: Any, mw: Any, sw: Any, ov: np.ndarray, cols: Any, v: Any, c: Any,
    row: np.ndarray, frx: float, brx: float, focc: float, bocc: float,
) -> None:  # fmt: skip
    """Step 6 of the tick, after both sides' torques and the network: the operator, both plants'
    steps (the hand force on the master), the held torques, the tick's row. `cols`: the row's
    group starts as a tuple (`column_starts`)."""
    rot, offset = ms[T_ROT], ms[T_OFFSET]
    scale, k_h, b_h, nm, ns = c[K_SCALE], c[K_K_HAND], c[K_B_HAND], c[K_NM], c[K_NS]
    qm, qdm, qs, qds = v[V_QM], v[V_QDM], v[V_QS], v[V_QDS]
    app_m, app_s = v[V_APP_M], v[V_APP_S]
    xm_dev, vm_dev, x_m, v_m, xs, vs = v[V_XM_DEV], v[V_VM_DEV], v[V_XM], v[V_VM], v[V_XS], v[V_VS]
    f_env, t_env, f_hand, op_f = v[V_F_ENV], v[V_T_ENV], v[V_F_HAND], v[V_OP_F]
    xd_t, vd_t, xd, vd = v[V_XD_T], v[V_VD_T], v[V_XD], v[V_VD]
    m_S, s_S = ms[T_S], ss[T_S]
    m_force, s_force = ms[T_FORCE], ss[T_FORCE]
    m_felt, s_felt = mw[W_FELT], sw[W_FELT]  # ratio x desired, or the task force of the applied torque
    t = n * c[K_PERIOD] - ov[O_START]
    profile = ov[O_PROFILE]
    if profile == 0.0:
        xd1, vd1 = push1(t, ov[O_X0], ov[O_SPEED], ov[O_T_END], ov[O_X_END])
    elif profile == 1.0:
        xd1, vd1 = sinusoid1(t, ov[O_X0], ov[O_AMP], ov[O_W])
    else:
        xd1, vd1 = ov[O_X0], 0.0
    s1 = xd1 - ov[O_X0]
    for k in range(3):
        xd_t[k] = ov[O_ORIGIN + k] + s1 * ov[O_DIR + k]
        vd_t[k] = vd1 * ov[O_DIR + k]
    unmap_point(xd, rot, scale, offset, xd_t)
    map_vector_back(vd, rot, c[K_INV_SCALE], vd_t)
    for k in range(3):
        f_hand[k] = k_h * (xd[k] - xm_dev[k]) + b_h * (vd[k] - vm_dev[k])
    plant_step(ms, v[V_TAU_M], f_hand, app_m, mw)
    plant_step(ss, v[V_TAU_S], f_hand, app_s, sw)
    held_m, held_s = ms[T_HELD], ss[T_HELD]
    for i in range(nm):
        held_m[i] = app_m[i]
    for i in range(ns):
        held_s[i] = app_s[i]
    map_vector(op_f, rot, c[K_INV_FORCE_SCALE], f_hand)
    for k in range(3):
        row[cols[C_OP_X] + k] = xd_t[k]
        row[cols[C_OP_V] + k] = vd_t[k]
        row[cols[C_OP_F] + k] = op_f[k]
        row[cols[C_M_X] + k] = x_m[k]
        row[cols[C_M_V] + k] = v_m[k]
        row[cols[C_M_F] + k] = m_felt[k]
        row[cols[C_M_FD] + k] = m_force[k]
        row[cols[C_S_X] + k] = xs[k]
        row[cols[C_S_V] + k] = vs[k]
        row[cols[C_S_F] + k] = s_felt[k]
        row[cols[C_S_FD] + k] = s_force[k]
        row[cols[C_S_CF] + k] = f_env[k]
        row[cols[C_S_CT] + k] = t_env[k]
    for i in range(nm):
        row[cols[C_M_Q] + i] = qm[i]
        row[cols[C_M_QD] + i] = qdm[i]
        row[cols[C_M_TAU] + i] = app_m[i]
    for i in range(ns):
        row[cols[C_S_Q] + i] = qs[i]
        row[cols[C_S_QD] + i] = qds[i]
        row[cols[C_S_TAU] + i] = app_s[i]
    row[cols[C_M_E]] = m_S[S_ENERGY]
    row[cols[C_S_E]] = s_S[S_ENERGY]
    row[cols[C_FRX]] = frx
    row[cols[C_BRX]] = brx
    row[cols[C_FOCC]] = focc
    row[cols[C_BOCC]] = bocc


# The stages of the compiled tick (engine/compiled/driver.py) for two arms. `world` is the sides'
# tuples (side_kernel.side_tuple), their work tuples, the operator, the row's columns, the block
# (from tick d0 on) and `own` (V_SIZE rows, each side's joint count and 3 wide: the tick's
# vectors, which the entry point allocates and keeps alive); `run` is every array of it as a
# `borrowed` view (no reference counting in the loop), with the tick's vectors and the run's
# constants. The tick's values live in those vectors: the stages hand on nothing (0).


@inline  # type: ignore[misc]
def arm_begin(world: Any) -> Any:
    ms_own, ss_own, mw_own, sw_own, ov, cols, data, d0, own = world
    ms, ss = detach(ms_own), detach(ss_own)
    ovb = borrowed(ov)
    v = tick_vectors(own, ms[T_I][I_N], ss[T_I][I_N])
    return (
        ms,
        ss,
        detach_work(mw_own),
        detach_work(sw_own),
        ovb,
        column_starts(cols),
        borrowed(data),
        d0,
        v,
        run_constants(ms, ss, ovb),
    )


@inline  # type: ignore[misc]
def arm_schedule_open(net: Any) -> Any:
    # a direction on its schedule: its window of releases and occupancies (from tick w0 on) and the
    # sender's ring of payloads (a power of two deep, indexed by seq), as `borrowed` views
    rel, occ, hist, w0 = net
    return borrowed(rel), borrowed(occ), borrowed(hist), hist.shape[0] - 1, w0


@inline  # type: ignore[misc]
def arm_sense(run: Any, n: int) -> int:
    sense(run[0], run[1], run[2], run[3], run[8], run[9])  # both arms
    return 0


@inline  # type: ignore[misc]
def arm_master(run: Any, t: int) -> int:
    v = run[8]
    side_torque(run[0], v[V_QM], v[V_QDM], v[V_XM], v[V_VM], v[V_TAU_M], run[2])
    return t


@inline  # type: ignore[misc]
def arm_slave(run: Any, t: int) -> int:
    v = run[8]
    side_torque(run[1], v[V_QS], v[V_QDS], v[V_XS], v[V_VS], v[V_TAU_S], run[3])
    return t


@inline  # type: ignore[misc]
def arm_schedule_forward(run: Any, f: Any, t: int, n: int, n1: int) -> tuple[int, float]:
    rel, occ, hist, mask, w0 = f
    forward_sample(hist[n & mask], run[8], run[0])
    return released(run[1], rel[n - w0], hist, mask), occ[n - w0]


@inline  # type: ignore[misc]
def arm_schedule_backward(run: Any, b: Any, t: int, n: int, n1: int) -> tuple[int, float]:
    rel, occ, hist, mask, w0 = b
    backward_sample(hist[n & mask], run[8], run[1])
    return released(run[0], rel[n - w0], hist, mask), occ[n - w0]


@inline  # type: ignore[misc]
def arm_finish(run: Any, t: int, n: int, frx: float, brx: float, focc: float, bocc: float) -> None:
    ms, ss, mw, sw, ov, cols, data, d0, v, c = run
    finish_tick(n, ms, ss, mw, sw, ov, cols, v, c, data[n - d0], frx, brx, focc, bocc)


@inline  # type: ignore[misc]
def arm_end(run: Any) -> None:
    pass


ARM_SIDES = {
    "begin": arm_begin, "sense": arm_sense, "master": arm_master, "slave": arm_slave,
    "finish": arm_finish, "end": arm_end,
}  # fmt: skip
# The tick on the schedule both ways (arm_codec_kernel composes the same sides with its channels)
drive_arm = driver.compose(
    **ARM_SIDES,
    open_forward=arm_schedule_open,
    open_backward=arm_schedule_open,
    forward=arm_schedule_forward,
    backward=arm_schedule_backward,
)


def tick_array(ms: Any, ss: Any) -> np.ndarray:
    """The tick's vectors (`arm_begin`'s V_* rows), made by the host once and handed to every call:
    the loop allocates nothing, so it runs without numba's reference counting (`loop_jit`)."""
    return np.zeros((V_SIZE, max(ms[T_I][I_N], ss[T_I][I_N], 3)))


@loop_jit  # type: ignore[misc]
def run_ticks(
    n0: int,
    n1: int,
    ms_own: Any,
    ss_own: Any,
    mw_own: Any,
    sw_own: Any,
    ov: np.ndarray,
    cols: np.ndarray,
    own: np.ndarray,
    fwd_rel: np.ndarray,
    fwd_occ: np.ndarray,
    bwd_rel: np.ndarray,
    bwd_occ: np.ndarray,
    fwd_hist: np.ndarray,
    bwd_hist: np.ndarray,
    data: np.ndarray,
    w0: int,
    d0: int,
) -> int:
    """Ticks [n0, n1) of an arm scene, the composed tick. `own`: the tick's vectors
    (`tick_array`); fwd_rel, fwd_occ, bwd_rel, bwd_occ hold the window of ticks from w0 on; data
    the block of ticks from d0 on; the histories are rings (a power of two deep) of the packets'
    payloads, indexed by seq."""
    world = (ms_own, ss_own, mw_own, sw_own, ov, cols, data, d0, own)
    return drive_arm(n0, n1, world, (fwd_rel, fwd_occ, fwd_hist, w0), (bwd_rel, bwd_occ, bwd_hist, w0))  # type: ignore[no-any-return]


@jit  # type: ignore[misc]
def bare_steps(models: np.ndarray, steps: int) -> None:
    """`steps` mj_steps of the master model then the slave's, nothing else (`bench speed`)."""
    for _ in range(steps):
        mj_step(models[0], models[1])
        mj_step(models[2], models[3])


@jit  # type: ignore[misc]
def mujoco_steps(ms: Any, ss: Any, steps: int) -> None:
    """`steps` of what a tick asks of MuJoCo, nothing else: mj_step1, mj_jacSite, mj_step2 of the
    master then the slave, with the controls left as they are (`bench speed`: the tick's MuJoCo
    part against a bare mj_step)."""
    mw = work(ms[T_I][I_N], ms[T_I][I_NV], 6 if ms[T_I][I_ROTATIONAL] != 0 else 3)
    sw = work(ss[T_I][I_N], ss[T_I][I_NV], 6 if ss[T_I][I_ROTATIONAL] != 0 else 3)
    for _ in range(steps):
        mj_step1(ms[T_I][I_MODEL], ms[T_I][I_DATA])
        jacobian(ms, mw[2], mw[3], mw[4], False)
        mj_step2(ms[T_I][I_MODEL], ms[T_I][I_DATA])
        mj_step1(ss[T_I][I_MODEL], ss[T_I][I_DATA])
        jacobian(ss, sw[2], sw[3], sw[4], ss[T_I][I_ROTATIONAL] != 0)
        mj_step2(ss[T_I][I_MODEL], ss[T_I][I_DATA])
