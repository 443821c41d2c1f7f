"""One side of an arm scene's tick, compiled (numba): the stage both the engine's compiled arm loop
(engine/compiled/arm_kernel.py inlines `side_torque`, `point`, `plant_step` for each side) and the
live nodes (`side_tick`, `side_begin`, `side_law`, `side_end`, through compiled_side.py) run.

Every formula comes from `core` (taskspace, eba) and is compiled here from its one definition
(`compiling.compile_tree`: a function and the plain functions it calls); this module holds the
side's order, which is side.py's `SideTick.torque`, and the plant's arithmetic around MuJoCo
(`plants/arm.py`'s `read`, `point`, `torque_room`, `step`, `_contact`), line for line. Importing
it needs numba and links MuJoCo's C functions (plants/mujoco_native.py).
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import eba_coupled, eba_two_condition_coupled, taskspace, tdpa, tdpa_coupled, wave_coupled
from haptic_teleop.core.wave_coupled import W_SENT, WAVE_ARM_SIZE
from haptic_teleop.plants.mujoco_native import (
    borrowed,
    load_f64,
    load_i32,
    load_i64,
    mj_contactForce,
    mj_jacSite,
    mj_step,
    mj_step1,
    mj_step2,
)

jit = numba.njit(cache=True, nogil=True)
# The tick's own helpers take the side tuples: inlined (numba IR), so a call does not copy the
# tuples (36 and 17 array structs, by value) onto the stack.
inline = numba.njit(cache=True, nogil=True, inline="always")

# The tick's small array functions are inlined where they are called (a call between separately
# compiled functions passes every array's fields by value); the larger ones (the null-space
# damping, the orientation hold, the felt force, the slew bound, TDPA's step) are compiled once
# and called.
small = {"inline": True}
map_point = compile_tree(taskspace.map_point, **small)
unmap_point = compile_tree(taskspace.unmap_point, **small)
map_vector = compile_tree(taskspace.map_vector, **small)
map_vector_back = compile_tree(taskspace.map_vector_back, **small)
coupling = compile_tree(taskspace.coupling, **small)
orientation_coupling = compile_tree(taskspace.orientation_coupling)
jacobian_times = compile_tree(taskspace.jacobian_times, **small)
jacobian_transpose = compile_tree(taskspace.jacobian_transpose, **small)
null_space_damping = compile_tree(taskspace.null_space_damping)
task_force_of = compile_tree(taskspace.task_force_of)
add_into = compile_tree(taskspace.add_into, **small)
dot = compile_tree(taskspace.dot, **small)
matrix_times = compile_tree(taskspace.matrix_times, **small)
cross = compile_tree(taskspace.cross, **small)
rendered_ratio = compile_tree(taskspace.rendered_ratio, **small)
coupled_reservoir = compile_tree(eba_coupled.coupled_reservoir, **small)
coupled_bounded = compile_tree(eba_coupled.coupled_bounded, **small)
slew_bounded = compile_tree(eba_coupled.slew_bounded)
joint_limited = compile_tree(eba_coupled.joint_limited, **small)
coupled_tdpa = compile_tree(tdpa_coupled.coupled_tdpa)
coupled_two_condition = compile_tree(eba_two_condition_coupled.coupled_two_condition)
room_within = compile_tree(eba_two_condition_coupled.room_within, **small)
wave_ports_begin = compile_tree(wave_coupled.wave_ports_begin)
wave_ports_end = compile_tree(wave_coupled.wave_ports_end)
wave_receive = compile_tree(wave_coupled.wave_receive, **small)
received1 = compile_tree(tdpa.received1, **small)
slipped1 = compile_tree(tdpa.slipped1, **small)

# The side tuple (compiled_side.side_tuple builds it; the kernel unpacks it in this order):
#   I (int64 scalars, the I_* positions below), qadr, dadr, act (int64, per joint),
#   F (float64 scalars, F_*), c1, c2, k_rot, d_rot (3), null_d, gain, bound_gain, step,
#   bound_low, bound_high, torque_lo, torque_hi (per joint), hand_support (3), jac_scale (3, 3),
#   guard limits (payload length), map (3, 3) rotation, map offset (3),
#   qpos, qvel, ctrl, qfrc_applied, qfrc_gravcomp, site_xpos (nsite, 3), site_xmat (nsite, 9)
#   (views of the plant's MjData), state S (S_*), last_q, held (per joint), remote (payload),
#   r_hold (3, 3), force (3), wrench6 (6: the wall's force and torque over the last period).
# Positions in the side tuple (see above).
T_I = 0
T_QADR = 1
T_DADR = 2
T_ACT = 3
T_F = 4
T_C1 = 5
T_C2 = 6
T_KROT = 7
T_DROT = 8
T_NULLD = 9
T_GAIN = 10
T_BGAIN = 11
T_STEP = 12
T_BLOW = 13
T_BHIGH = 14
T_TLO = 15
T_THI = 16
T_SUPPORT = 17
T_JSCALE = 18
T_LIMITS = 19
T_ROT = 20
T_OFFSET = 21
T_QPOS = 22
T_QVEL = 23
T_CTRL = 24
T_QFRC_APPLIED = 25
T_GRAVCOMP = 26
T_XPOS = 27
T_XMAT = 28
T_S = 29
T_LAST_Q = 30
T_HELD = 31
T_REMOTE = 32
T_RHOLD = 33
T_FORCE = 34
T_WRENCH = 35
T_SIZE = 36
I_MODEL, I_DATA, I_N, I_SITE, I_SUBSTEPS, I_GRAVITY, I_ROTATIONAL, I_NULL, I_ENABLED = 0, 1, 2, 3, 4, 5, 6, 7, 8
I_KEEP_DIRECTION, I_SLEW, I_WALL, I_GEOM1, I_GEOM2, I_NCON, I_CONTACT, I_STRIDE = 9, 10, 11, 12, 13, 14, 15, 16
I_POS, I_FRAME, I_G1, I_G2, I_EFC, I_HAND, I_JAC_SCALE, I_NV = 17, 18, 19, 20, 21, 22, 23, 24
# I_LAW: the side's stabilizer, LAW_EBA (the pooled reservoir bound), TDPA's pooled step with its
# controller (core/tdpa_coupled.py: `coupled_tdpa`; its energy rides last on the side's samples) or
# the two conditions joint by joint (core/eba_two_condition_coupled.py: `coupled_two_condition`), or
# wave variables' ports per task axis (core/wave_coupled.py; its waves ride where the velocities were).
I_LAW = 25
I_SIZE = 26
LAW_EBA, LAW_TDPA_VELOCITY, LAW_TDPA_ZOH, LAW_TWO_CONDITION, LAW_WAVE = 0, 1, 2, 3, 4
F_LIMIT, F_MU, F_SCALE, F_FORCE_SCALE, F_K_HAND, F_B_HAND, F_E0, F_REFLECT = 0, 1, 2, 3, 4, 5, 6, 7
F_ADMIT, F_RECOVER = 8, 9  # TDPA's admittance placement (1: on) and its drift gain times T
# wave variables (CoupledWaveBound's): the impedance b, s = sqrt(2 b), the filter's pole, the drift
# gain, matched (1: on), the master's port (1) or the slave's (0), the side's period T
F_WAVE_B, F_WAVE_S, F_WAVE_POLE, F_WAVE_DRIFT, F_WAVE_MATCHED, F_WAVE_MASTER, F_PERIOD = 10, 11, 12, 13, 14, 15, 16
F_SIZE = 17
S_ENERGY, S_HAS_LAST, S_HAS_REMOTE, S_HAS_HOLD, S_RATIO, S_REJECTED, S_SCALE, S_LIMITED = 0, 1, 2, 3, 4, 5, 6, 7
# TDPA's state (core/tdpa_coupled.TDPA_EXTRA, in its order: the admittance placement's slip per
# task axis last, from S_SLIP) from S_EXTRA on; the two-condition law's: each joint's ledger; wave
# variables': the port state (core/wave_coupled.py's W_* layout; S is S_SIZE long, or as long as
# the law's state needs: compiled_side.side_tuple)
S_EXTRA = 8
S_SLIP = S_EXTRA + 5
S_SIZE = 16
# The work tuple's (`work_arrays`) felt force: what the row records as the side's task force
W_FELT = 17


@inline  # type: ignore[misc]
def carries_energy(side: Any) -> bool:
    """TDPA: the side's pooled input energy rides last on its samples (CoupledTdpaBound.receive)."""
    law = side[T_I][I_LAW]
    return law == LAW_TDPA_VELOCITY or law == LAW_TDPA_ZOH  # type: ignore[no-any-return]  # noqa: PLR1714


@inline  # type: ignore[misc]
def read_joints(side: Any, q: np.ndarray, qd: np.ndarray) -> None:
    """MujocoArm.read after mj_step1: joint positions and velocities."""
    iv, qadr, dadr = side[T_I], side[T_QADR], side[T_DADR]
    qpos, qvel = side[T_QPOS], side[T_QVEL]
    for i in range(iv[I_N]):
        q[i] = qpos[qadr[i]]
        qd[i] = qvel[dadr[i]]


@inline  # type: ignore[misc]
def jacobian(side: Any, jacp: np.ndarray, jacr: np.ndarray, jac: np.ndarray, rotational: bool) -> None:
    """MujocoArm.jacobian: mj_jacSite, then the joints' columns (rotational rows under the
    positional ones)."""
    iv, dadr = side[T_I], side[T_DADR]
    jr = jacr.ctypes.data if rotational else 0  # NULL: MuJoCo skips the rotational rows
    mj_jacSite(iv[I_MODEL], iv[I_DATA], jacp.ctypes.data, jr, np.int32(iv[I_SITE]))
    n = iv[I_N]
    for j in range(n):
        a = dadr[j]
        for i in range(3):
            jac[i, j] = jacp[i, a]
        if rotational:
            for i in range(3):
                jac[3 + i, j] = jacr[i, a]


@inline  # type: ignore[misc]
def torque_room(side: Any, lo: np.ndarray, hi: np.ndarray) -> None:
    """MujocoArm.torque_room: each motor's limit minus the gravity compensation it carries."""
    iv, dadr = side[T_I], side[T_DADR]
    tlo, thi, grav = side[T_TLO], side[T_THI], side[T_GRAVCOMP]
    for i in range(iv[I_N]):
        g = grav[dadr[i]] if iv[I_GRAVITY] != 0 else 0.0
        lo[i] = tlo[i] - g
        hi[i] = thi[i] - g


@inline  # type: ignore[misc]
def contact(side: Any, out: np.ndarray, f6: np.ndarray, f: np.ndarray, r: np.ndarray, m: np.ndarray) -> None:
    """MujocoArm._contact added into `out`: the wall's force and its torque about the tool point
    in the step just made, read from mjData's contact array."""
    iv = side[T_I]
    if iv[I_WALL] == 0:
        return
    d = iv[I_DATA]
    x = side[T_XPOS][iv[I_SITE]]
    ncon = load_i32(d + iv[I_NCON])
    base = load_i64(d + iv[I_CONTACT])
    for i in range(ncon):
        c = base + i * iv[I_STRIDE]
        if load_i32(c + iv[I_G1]) != iv[I_GEOM1] or load_i32(c + iv[I_G2]) != iv[I_GEOM2]:
            continue
        if load_i32(c + iv[I_EFC]) < 0:
            continue
        mj_contactForce(iv[I_MODEL], d, np.int32(i), f6.ctypes.data)
        for k in range(9):
            m[k // 3, k % 3] = load_f64(c + iv[I_FRAME] + 8 * k)
        jacobian_transpose(f, m, f6)  # frame.T @ f6[:3]
        for k in range(3):
            out[k] += f[k]
            r[k] = load_f64(c + iv[I_POS] + 8 * k) - x[k]
        cross(f6, r, f)  # f6 is free again: the torque
        for k in range(3):
            out[3 + k] += f6[k]


@inline  # type: ignore[misc]
def plant_step(side: Any, tau: np.ndarray, hand: np.ndarray, applied: np.ndarray, w: Any) -> None:
    """MujocoArm.step: the port torques within each motor's room (NaN -> 0) into ctrl, the hand
    force as J^T f, mj_step2, further substeps with mj_step; the wall's wrench averaged."""
    iv, dadr, act = side[T_I], side[T_DADR], side[T_ACT]
    ctrl, qfrc_applied = side[T_CTRL], side[T_QFRC_APPLIED]
    wrench6 = side[T_WRENCH]
    lo, hi, f6, f, r, m, fh, tmp = w[0], w[1], w[5], w[6], w[7], w[8], w[9], w[10]
    n = iv[I_N]
    torque_room(side, lo, hi)
    for i in range(n):
        t = tau[i]
        if math.isnan(t):
            t = 0.0
        t = min(max(t, lo[i]), hi[i])
        applied[i] = t
        ctrl[act[i]] = t
    if iv[I_HAND] != 0:
        support = side[T_SUPPORT]
        for k in range(3):
            fh[k] = hand[k] + support[k]
        jacobian_transpose(tmp, w[15], fh)  # j3: this tick's Jacobian (the state has not moved)
        for i in range(n):
            qfrc_applied[dadr[i]] = tmp[i]
    mj_step2(iv[I_MODEL], iv[I_DATA])
    for k in range(6):
        wrench6[k] = 0.0
    contact(side, wrench6, f6, f, r, m)
    for _ in range(iv[I_SUBSTEPS] - 1):
        mj_step(iv[I_MODEL], iv[I_DATA])
        contact(side, wrench6, f6, f, r, m)
    if iv[I_SUBSTEPS] != 1:  # (x / 1 is x: one substep, no divisions)
        for k in range(6):
            wrench6[k] = wrench6[k] / iv[I_SUBSTEPS]


@inline  # type: ignore[misc]
def side_torque(
    side: Any, q: np.ndarray, qd: np.ndarray, x: np.ndarray, v: np.ndarray, out: np.ndarray, w: Any
) -> None:
    """side.SideTick.torque: the task-space law on the newest remote sample, J^T F, the
    null-space damping, the force limit on the task force's norm, the motors' room (direction
    kept), the pooled joint bound. `out`: the torque to apply; S_RATIO, force: for the row."""
    iv, F = side[T_I], side[T_F]
    c1, c2, k_rot, d_rot, null_d = side[T_C1], side[T_C2], side[T_KROT], side[T_DROT], side[T_NULLD]
    gain, bound_gain, step, blow, bhigh = side[T_GAIN], side[T_BGAIN], side[T_STEP], side[T_BLOW], side[T_BHIGH]
    jac_scale = side[T_JSCALE]
    S, last_q, held, remote, r_hold, force = (
        side[T_S],
        side[T_LAST_Q],
        side[T_HELD],
        side[T_REMOTE],
        side[T_RHOLD],
        side[T_FORCE],
    )
    site_xmat = side[T_XMAT]
    lo, hi, jac, m, tmp = w[0], w[1], w[4], w[8], w[10]
    wrench, tau, limited, omega, j3, dq, felt, scratch = w[11:]
    n = iv[I_N]
    rotational = iv[I_ROTATIONAL] != 0
    # jac: this tick's Jacobian, from `point` (the state has not moved since)
    for k in range(3):
        for j in range(n):
            j3[k, j] = jac[k, j]
    if iv[I_JAC_SCALE] != 0:
        matrix_times(jac[:3], jac_scale, j3)
    # TaskSpaceLaw.torque
    if iv[I_LAW] == LAW_WAVE:  # CoupledWaveBound.begin: the ports make the task force
        wave_ports_begin(
            S[S_EXTRA : S_EXTRA + WAVE_ARM_SIZE], wrench, x, v, F[F_WAVE_MASTER] != 0.0, F[F_WAVE_S], F[F_WAVE_B],
            c1, c2, F[F_WAVE_POLE], F[F_WAVE_DRIFT], F[F_WAVE_MATCHED] != 0.0, F[F_PERIOD],
        )  # fmt: skip
    elif S[S_HAS_REMOTE] == 0.0:
        for k in range(3):
            wrench[k] = 0.0
    elif F[F_ADMIT] != 0.0:  # TDPA's admittance placement: the received point offset by the slip
        for k in range(3):
            felt[k] = remote[k] + S[S_SLIP + k]  # (felt is free until the end of the tick)
        coupling(wrench, c1, c2, felt, remote[3:6], x, v)
    else:
        coupling(wrench, c1, c2, remote[0:3], remote[3:6], x, v)
    if rotational:
        if S[S_HAS_HOLD] == 0.0:
            for k in range(9):
                r_hold[k // 3, k % 3] = site_xmat[iv[I_SITE], k]
            S[S_HAS_HOLD] = 1.0
        for k in range(9):
            m[k // 3, k % 3] = site_xmat[iv[I_SITE], k]
        jacobian_times(omega, jac[3:6], qd)
        orientation_coupling(wrench[3:6], k_rot, d_rot, r_hold, m, omega, scratch)
    jacobian_transpose(tau, jac, wrench)
    if iv[I_NULL] != 0:
        null_space_damping(tmp, jac, qd, null_d, F[F_MU], scratch)
        add_into(tau, tmp)
    # the force limit, the motors' room, the bound
    for k in range(3):
        force[k] = wrench[k]
    norm = np.sqrt(dot(force, force))
    limit = F[F_LIMIT]
    if norm > limit:
        s = limit / norm
        for i in range(n):
            tau[i] = tau[i] * s
    torque_room(side, lo, hi)
    joint_limited(limited, tau, lo, hi, True)
    for i in range(n):
        if limited[i] != tau[i]:
            S[S_LIMITED] += 1.0
            break
    if iv[I_LAW] == LAW_WAVE:  # CoupledWaveBound.step (the torque limits), then its `end` with the ratio
        joint_limited(out, limited, blow, bhigh, True)
        for i in range(n):
            held[i] = out[i]
            last_q[i] = q[i]
        S[S_HAS_LAST] = 1.0
        S[S_RATIO] = rendered_ratio(out, tau, limit, norm)
        S[S_ENERGY] = wave_ports_end(
            S[S_EXTRA : S_EXTRA + WAVE_ARM_SIZE], S[S_RATIO], F[F_WAVE_MASTER] != 0.0, F[F_WAVE_B],
            F[F_WAVE_MATCHED] != 0.0, F[F_PERIOD],
        )  # fmt: skip
        for k in range(3):
            felt[k] = S[S_RATIO] * force[k]
        return
    if iv[I_LAW] == LAW_TWO_CONDITION:  # CoupledTwoConditionBound.step: the room within the limits, per joint
        room_within(lo, hi, blow, bhigh)
        joint_limited(tmp, limited, lo, hi, True)
        S[S_ENERGY] = coupled_two_condition(
            out, tmp, q, last_q, held, S[S_EXTRA : S_EXTRA + n], S[S_HAS_LAST] != 0.0,
            gain, bound_gain, lo, hi, iv[I_ENABLED] != 0,
        )  # fmt: skip
        S[S_HAS_LAST] = 1.0
        S[S_RATIO] = rendered_ratio(out, tau, limit, norm)
        if iv[I_ENABLED] != 0:  # each joint cut alone: the felt force is the applied torque's (SideTick.rendered)
            task_force_of(wrench, jac, out, scratch)
            for k in range(3):
                felt[k] = wrench[k]
        else:
            for k in range(3):
                felt[k] = S[S_RATIO] * force[k]
        return
    if iv[I_LAW] != LAW_EBA:  # CoupledTdpaBound.step: the bound's range, then `coupled_tdpa`
        joint_limited(lo, limited, blow, bhigh, True)
        for i in range(n):
            tmp[i] = 0.0
        X = S_EXTRA
        S[X], S[X + 1], S[X + 3], S[S_ENERGY], S[X + 4], S[S_SCALE] = coupled_tdpa(
            out, lo, q, last_q, held, dq, tmp, S[X], S[X + 1], S[X + 2], S[X + 3], S[S_HAS_LAST] != 0.0,
            gain, bound_gain, F[F_E0], F[F_REFLECT], iv[I_LAW] == LAW_TDPA_ZOH, iv[I_ENABLED] != 0, blow, bhigh,
        )  # fmt: skip
        S[S_HAS_LAST] = 1.0
        S[S_RATIO] = rendered_ratio(out, tau, limit, norm)
        if F[F_ADMIT] != 0.0:  # the task force into the bound against the one out of it (SideTick.torque)
            before = rendered_ratio(limited, tau, limit, norm)
            for k in range(3):
                S[S_SLIP + k] = slipped1(S[S_SLIP + k], before * force[k], S[S_RATIO] * force[k], c1[k], F[F_RECOVER])
        if iv[I_LAW] == LAW_TDPA_VELOCITY and iv[I_ENABLED] != 0:
            # its damper along the motion: the applied torque is no scaled copy of the desired one,
            # so the felt force is the task force of the applied torque (SideTick.rendered)
            task_force_of(wrench, jac, out, scratch)  # wrench is free again (the desired one is in `force`)
            for k in range(3):
                felt[k] = wrench[k]
        else:
            for k in range(3):
                felt[k] = S[S_RATIO] * force[k]
        return
    # CoupledEnergyBound.step
    if S[S_HAS_LAST] != 0.0:
        for i in range(n):
            dq[i] = q[i] - last_q[i]
        S[S_ENERGY] = coupled_reservoir(S[S_ENERGY], gain, held, dq)
    else:
        S[S_HAS_LAST] = 1.0
    for i in range(n):
        last_q[i] = q[i]
    joint_limited(lo, limited, blow, bhigh, iv[I_KEEP_DIRECTION] != 0)  # lo: the bound's limited
    if iv[I_ENABLED] == 0:
        if iv[I_SLEW] == 0:
            for i in range(n):
                out[i] = lo[i]
        else:
            for i in range(n):
                out[i] = min(max(lo[i], held[i] - step[i]), held[i] + step[i])
        S[S_SCALE] = 1.0
    elif iv[I_SLEW] == 0:
        S[S_SCALE] = coupled_bounded(out, lo, S[S_ENERGY], bound_gain)
    else:
        S[S_SCALE] = slew_bounded(out, lo, held, S[S_ENERGY], step, bound_gain)
    for i in range(n):
        held[i] = out[i]
    S[S_RATIO] = rendered_ratio(out, tau, limit, norm)
    for k in range(3):
        felt[k] = S[S_RATIO] * force[k]


@inline  # type: ignore[misc]
def point(side: Any, qd: np.ndarray, x: np.ndarray, v: np.ndarray, w: Any) -> None:
    """MujocoArm.point: the site's position and its velocity J qd."""
    iv = side[T_I]
    jacp, jacr, jac = w[2], w[3], w[4]
    xpos = side[T_XPOS][iv[I_SITE]]
    for k in range(3):
        x[k] = xpos[k]
    jacobian(side, jacp, jacr, jac, iv[I_ROTATIONAL] != 0)
    jacobian_times(v, jac[:3], qd)


@inline  # type: ignore[misc]
def guarded(side: Any, sample: np.ndarray) -> None:
    """SampleGuard.accept on a released (or decoded) sample: taken as the remote sample, or counted."""
    lim, S, remote = side[T_LIMITS], side[T_S], side[T_REMOTE]
    for i in range(lim.shape[0]):
        if not abs(sample[i]) <= lim[i]:
            S[S_REJECTED] += 1.0
            return
    for i in range(lim.shape[0]):
        remote[i] = sample[i]
    S[S_HAS_REMOTE] = 1.0
    if carries_energy(side):  # TDPA: the remote side's input energy, last (CoupledTdpaBound.receive)
        S[S_EXTRA + 2] = received1(S[S_EXTRA + 2], sample[lim.shape[0] - 1])
    elif side[T_I][I_LAW] == LAW_WAVE:  # its waves, to be used once (CoupledWaveBound.receive)
        wave_receive(S[S_EXTRA : S_EXTRA + WAVE_ARM_SIZE], sample)


@inline  # type: ignore[misc]
def sample_velocity(side: Any, v: np.ndarray, k: int) -> float:
    """What a side's sample carries in its velocities' place on axis k: the velocity, or with wave
    variables the wave the side sends (ArmSideStage.tick)."""
    if side[T_I][I_LAW] == LAW_WAVE:
        return side[T_S][S_EXTRA + W_SENT + k]  # type: ignore[no-any-return]
    return v[k]  # type: ignore[no-any-return]


def work_arrays(n: int, nv: int, rows: int) -> tuple[np.ndarray, ...]:
    """One side's scratch arrays for the kernel (`work` compiled): n joints, nv dofs, rows of its Jacobian."""
    return (
        np.zeros(n),  # lo
        np.zeros(n),  # hi
        np.zeros((3, nv)),  # jacp
        np.zeros((3, nv)),  # jacr
        np.zeros((rows, n)),  # jac
        np.zeros(6),  # f6
        np.zeros(3),  # f
        np.zeros(3),  # r
        np.zeros((3, 3)),  # m
        np.zeros(3),  # fh
        np.zeros(n),  # tmp
        np.zeros(rows),  # wrench
        np.zeros(n),  # tau
        np.zeros(n),  # limited
        np.zeros(3),  # omega
        np.zeros((3, n)),  # j3
        np.zeros(n),  # dq
        np.zeros(3),  # felt: the task force the applied torque renders (the row's m/s_force_n)
        np.zeros((max(rows, n, 3) + 2, max(rows, n, 3))),  # scratch: taskspace.tick_scratch's shape
    )


work = jit(work_arrays)


@jit  # type: ignore[misc]
def detach(t: Any) -> Any:
    """A side tuple of `borrowed` views (the caller holds the arrays)."""
    return (
        borrowed(t[0]),
        borrowed(t[1]),
        borrowed(t[2]),
        borrowed(t[3]),
        borrowed(t[4]),
        borrowed(t[5]),
        borrowed(t[6]),
        borrowed(t[7]),
        borrowed(t[8]),
        borrowed(t[9]),
        borrowed(t[10]),
        borrowed(t[11]),
        borrowed(t[12]),
        borrowed(t[13]),
        borrowed(t[14]),
        borrowed(t[15]),
        borrowed(t[16]),
        borrowed(t[17]),
        borrowed(t[18]),
        borrowed(t[19]),
        borrowed(t[20]),
        borrowed(t[21]),
        borrowed(t[22]),
        borrowed(t[23]),
        borrowed(t[24]),
        borrowed(t[25]),
        borrowed(t[26]),
        borrowed(t[27]),
        borrowed(t[28]),
        borrowed(t[29]),
        borrowed(t[30]),
        borrowed(t[31]),
        borrowed(t[32]),
        borrowed(t[33]),
        borrowed(t[34]),
        borrowed(t[35]),
    )


@jit  # type: ignore[misc]
def detach_work(w: Any) -> Any:
    """A work tuple (`work`) of `borrowed` views (the caller holds the arrays)."""
    return (
        borrowed(w[0]),
        borrowed(w[1]),
        borrowed(w[2]),
        borrowed(w[3]),
        borrowed(w[4]),
        borrowed(w[5]),
        borrowed(w[6]),
        borrowed(w[7]),
        borrowed(w[8]),
        borrowed(w[9]),
        borrowed(w[10]),
        borrowed(w[11]),
        borrowed(w[12]),
        borrowed(w[13]),
        borrowed(w[14]),
        borrowed(w[15]),
        borrowed(w[16]),
        borrowed(w[17]),
        borrowed(w[18]),
    )


@jit  # type: ignore[misc]
def side_tick(
    side_own: Any, work_own: Any, q: np.ndarray, qd: np.ndarray, x: np.ndarray, v: np.ndarray, out: np.ndarray
) -> None:
    """One side's tick alone (the live nodes: nodes/arm_side.py), on its plant after mj_step1:
    the joints, the Jacobian, then `side_torque`, the very function `run_ticks` inlines for each
    side. x, v: the point in the task frame; q, qd, out (the torque to apply) are written."""
    side, w = detach(side_own), detach_work(work_own)
    read_joints(side, q, qd)
    jacobian(side, w[2], w[3], w[4], side[T_I][I_ROTATIONAL] != 0)
    side_torque(side, q, qd, x, v, out, w)


@jit  # type: ignore[misc]
def side_begin(side_own: Any, work_own: Any, q: np.ndarray, qd: np.ndarray, x: np.ndarray, v: np.ndarray) -> None:
    """One side's tick starts (the live nodes): mj_step1, then its joints and its point (MujocoArm's
    `read` and `point`: x, v in the world frame), as `run_ticks` step 1 for each side."""
    side, w = detach(side_own), detach_work(work_own)
    mj_step1(side[T_I][I_MODEL], side[T_I][I_DATA])
    read_joints(side, q, qd)
    point(side, qd, x, v, w)


@jit  # type: ignore[misc]
def side_law(
    side_own: Any, work_own: Any, q: np.ndarray, qd: np.ndarray, x: np.ndarray, v: np.ndarray, out: np.ndarray
) -> None:
    """`side_torque` after `side_begin` (its Jacobian is this tick's): x, v in the task frame."""
    side_torque(detach(side_own), q, qd, x, v, out, detach_work(work_own))


@jit  # type: ignore[misc]
def side_end(side_own: Any, work_own: Any, tau: np.ndarray, hand: np.ndarray, applied: np.ndarray) -> None:
    """One side's tick ends: `plant_step` (the torques within the motors' room into ctrl, the hand
    force, mj_step2 and any substeps, the wall's wrench) after `side_law`; `applied` is written."""
    plant_step(detach(side_own), tau, hand, applied, detach_work(work_own))
