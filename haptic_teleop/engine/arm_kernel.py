"""The compiled tick loop for arm scenes (numba), imported only by `haptic_teleop.engine.compiled_arm_loop`.

Importing this module needs numba and links MuJoCo's `mj_step1`, `mj_step2`, `mj_step`,
`mj_jacSite` and `mj_contactForce` of the libmujoco the `mujoco` bindings loaded (the same
library as `axis_kernel`'s `mj_step`). Every formula comes from `core` (taskspace, eba, operator)
and is compiled here from its one definition (`compile_tree`: a function and the plain functions
it calls); this module holds only the tick's order, which is `arm_loop.run_arm_loop`'s, and the
plant's arithmetic around MuJoCo (`plants/arm.py`'s `read`, `point`, `torque_room`, `step`,
`_contact`), line for line.

numba caches the compiled loop next to this file and checks only this file's time stamp, while
the loop holds compiled copies of `core`'s functions: `compiled_arm_loop` drops this module's cache when one
of the sources it is built from changed (`compiled_arm_loop._drop_stale_cache`).
"""

from __future__ import annotations

import ctypes
import math
import types as pytypes
from collections.abc import Callable
from typing import Any

import llvmlite.binding as llvm
import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from numba.np.arrayobj import populate_array

from haptic_teleop.core import eba, taskspace
from haptic_teleop.core import operator as op
from haptic_teleop.engine.axis_kernel import libmujoco, mj_step

for _name in ("mj_step1", "mj_step2", "mj_jacSite", "mj_contactForce"):
    llvm.add_symbol(_name, ctypes.cast(getattr(libmujoco, _name), ctypes.c_void_p).value)
# void mj_step1(const mjModel* m, mjData* d); void mj_step2(...): the split step (mujoco.h)
mj_step1 = types.ExternalFunction("mj_step1", types.void(types.intp, types.intp))
mj_step2 = types.ExternalFunction("mj_step2", types.void(types.intp, types.intp))
# void mj_jacSite(const mjModel* m, const mjData* d, mjtNum* jacp, mjtNum* jacr, int site)
mj_jacSite = types.ExternalFunction(
    "mj_jacSite", types.void(types.intp, types.intp, types.intp, types.intp, types.int32)
)
# void mj_contactForce(const mjModel* m, const mjData* d, int id, mjtNum result[6])
mj_contactForce = types.ExternalFunction("mj_contactForce", types.void(types.intp, types.intp, types.int32, types.intp))

jit = numba.njit(cache=True, nogil=True)
# The tick's own helpers take the side tuples: inlined (numba IR), so a call does not copy the
# tuples (36 and 17 array structs, by value) onto the stack.
inline = numba.njit(cache=True, nogil=True, inline="always")


@intrinsic
def load_i32(typingctx: Any, addr: Any) -> Any:
    """The int32 at byte address `addr` (a field of MuJoCo's mjData or mjContact)."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.load(builder.inttoptr(args[0], ir.IntType(32).as_pointer()))

    return types.int32(types.intp), codegen


@intrinsic
def load_i64(typingctx: Any, addr: Any) -> Any:
    """The int64 (a pointer) at byte address `addr`."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.load(builder.inttoptr(args[0], ir.IntType(64).as_pointer()))

    return types.int64(types.intp), codegen


@intrinsic
def load_f64(typingctx: Any, addr: Any) -> Any:
    """The float64 at byte address `addr`."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        return builder.load(builder.inttoptr(args[0], ir.DoubleType().as_pointer()))

    return types.float64(types.intp), codegen


@intrinsic
def borrowed(typingctx: Any, arr: Any) -> Any:
    """`arr` without its reference count (a view with no owner): passing it around costs no
    atomic increments and decrements, which were about a sixth of a tick (docs/performance.md).
    The caller keeps the owner alive for as long as the view is used."""

    def codegen(context: Any, builder: Any, sig: Any, args: Any) -> Any:
        src = context.make_array(sig.args[0])(context, builder, args[0])
        out = context.make_array(sig.return_type)(context, builder)
        populate_array(out, src.data, src.shape, src.strides, src.itemsize, None)
        return out._getvalue()

    return arr(arr), codegen


_compiled: dict[Callable[..., Any], Any] = {}


def compile_tree(f: Callable[..., Any]) -> Any:
    """`f` compiled by numba from its own definition, with every plain function of this package it
    calls (by global name) compiled the same way: numba cannot call uncompiled functions, and the
    core modules must not import numba, so the calls are bound to the compiled callees here."""
    done = _compiled.get(f)
    if done is not None:
        return done
    glob = dict(f.__globals__)  # type: ignore[attr-defined]
    for name in f.__code__.co_names:  # type: ignore[attr-defined]
        g = glob.get(name)
        if isinstance(g, pytypes.FunctionType) and g.__module__.startswith("haptic_teleop."):
            glob[name] = compile_tree(g)
    code = f.__code__  # type: ignore[attr-defined]
    fn = pytypes.FunctionType(code, glob, f.__name__, f.__defaults__, f.__closure__)  # type: ignore[attr-defined]
    fn.__qualname__ = f.__qualname__
    fn.__module__ = f.__module__
    done = jit(fn)
    _compiled[f] = done
    return done


map_point = compile_tree(taskspace.map_point)
unmap_point = compile_tree(taskspace.unmap_point)
map_vector = compile_tree(taskspace.map_vector)
map_vector_back = compile_tree(taskspace.map_vector_back)
coupling = compile_tree(taskspace.coupling)
orientation_coupling = compile_tree(taskspace.orientation_coupling)
jacobian_times = compile_tree(taskspace.jacobian_times)
jacobian_transpose = compile_tree(taskspace.jacobian_transpose)
null_space_damping = compile_tree(taskspace.null_space_damping)
add_into = compile_tree(taskspace.add_into)
dot = compile_tree(taskspace.dot)
matrix_times = compile_tree(taskspace.matrix_times)
cross = compile_tree(taskspace.cross)
coupled_reservoir = compile_tree(eba.coupled_reservoir)
coupled_bounded = compile_tree(eba.coupled_bounded)
slew_bounded = compile_tree(eba.slew_bounded)
joint_limited = compile_tree(eba.joint_limited)
push1 = compile_tree(op.push1)
sinusoid1 = compile_tree(op.sinusoid1)

# The side tuple (compiled_arm_loop.side_tuple builds it; the kernel unpacks it in this order):
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
I_SIZE = 25
F_LIMIT, F_MU, F_SCALE, F_FORCE_SCALE, F_K_HAND, F_B_HAND = 0, 1, 2, 3, 4, 5
F_SIZE = 6
S_ENERGY, S_HAS_LAST, S_HAS_REMOTE, S_HAS_HOLD, S_RATIO, S_REJECTED, S_SCALE, S_LIMITED = 0, 1, 2, 3, 4, 5, 6, 7
S_SIZE = 8
# The operator, in OP: profile code (compiled_loop.PROFILE_CODES), x0, start, speed, t_end, x_end,
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
    for k in range(6):
        wrench6[k] = wrench6[k] / iv[I_SUBSTEPS]


@inline  # type: ignore[misc]
def side_torque(
    side: Any, q: np.ndarray, qd: np.ndarray, x: np.ndarray, v: np.ndarray, out: np.ndarray, w: Any
) -> None:
    """arm_loop._SideTick.torque: the task-space law on the newest remote sample, J^T F, the
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
    wrench, tau, limited, omega, j3, dq = w[11:]
    n = iv[I_N]
    rotational = iv[I_ROTATIONAL] != 0
    # jac: this tick's Jacobian, from `point` (the state has not moved since)
    for k in range(3):
        for j in range(n):
            j3[k, j] = jac[k, j]
    if iv[I_JAC_SCALE] != 0:
        matrix_times(jac[:3], jac_scale, j3)
    # TaskSpaceLaw.torque
    if S[S_HAS_REMOTE] == 0.0:
        for k in range(3):
            wrench[k] = 0.0
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
        orientation_coupling(wrench[3:6], k_rot, d_rot, r_hold, m, omega)
    jacobian_transpose(tau, jac, wrench)
    if iv[I_NULL] != 0:
        null_space_damping(tmp, jac, qd, null_d, F[F_MU])
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
    tt = dot(tau, tau)
    ratio = dot(out, tau) / tt if tt > 0.0 else 0.0
    sat = min(1.0, limit / norm) if norm > 0.0 else 0.0
    S[S_RATIO] = ratio * sat


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
K_SCALE, K_FORCE_SCALE, K_K_HAND, K_B_HAND, K_PERIOD, K_NM, K_NS = range(7)


@inline  # type: ignore[misc]
def run_constants(ms: Any, ss: Any, ov: np.ndarray) -> Any:
    """What the tick reads of the parameters, read once before the loop: the mapping's scales, the
    hand's stiffness and damping, the period, both sides' joint counts."""
    MF = ms[T_F]
    return (MF[F_SCALE], MF[F_FORCE_SCALE], MF[F_K_HAND], MF[F_B_HAND], ov[O_PERIOD], ms[T_I][I_N], ss[T_I][I_N])


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
def forward_sample(out: np.ndarray, v: Any) -> None:
    """The forward packet's payload: the master's x, v in the task frame."""
    x, vel = v[V_XM], v[V_VM]
    for k in range(3):
        out[k] = x[k]
        out[3 + k] = vel[k]


@inline  # type: ignore[misc]
def backward_sample(out: np.ndarray, v: Any) -> None:
    """The backward packet's payload: the slave's x, v and the wall's force."""
    x, vel, f = v[V_XS], v[V_VS], v[V_F_ENV]
    for k in range(3):
        out[k] = x[k]
        out[3 + k] = vel[k]
        out[6 + k] = f[k]


@inline  # type: ignore[misc]
def released(side: Any, seq: int, hist: np.ndarray, mask: int) -> int:
    """The schedule's release at this tick (`seq`, -1: none) from the sender's ring, through the
    receiving side's guard; returns `seq` (the row's `received` column)."""
    if seq >= 0:
        guarded(side, hist[seq & mask])
    return seq


@inline  # type: ignore[misc]
def finish_tick(
    n: int, ms: Any, ss: Any, mw: Any, sw: Any, ov: np.ndarray, cols: np.ndarray, v: Any, c: Any,
    row: np.ndarray, frx: float, brx: float, focc: float, bocc: float,
) -> None:  # fmt: skip
    """Step 6 of the tick, after both sides' torques and the network: the operator, both plants'
    steps (the hand force on the master), the held torques, the tick's row."""
    rot, offset = ms[T_ROT], ms[T_OFFSET]
    scale, force_scale, k_h, b_h, nm, ns = c[K_SCALE], c[K_FORCE_SCALE], c[K_K_HAND], c[K_B_HAND], c[K_NM], c[K_NS]
    qm, qdm, qs, qds = v[V_QM], v[V_QDM], v[V_QS], v[V_QDS]
    app_m, app_s = v[V_APP_M], v[V_APP_S]
    xm_dev, vm_dev, x_m, v_m, xs, vs = v[V_XM_DEV], v[V_VM_DEV], v[V_XM], v[V_VM], v[V_XS], v[V_VS]
    f_env, t_env, f_hand, op_f = v[V_F_ENV], v[V_T_ENV], v[V_F_HAND], v[V_OP_F]
    xd_t, vd_t, xd, vd = v[V_XD_T], v[V_VD_T], v[V_XD], v[V_VD]
    m_S, s_S = ms[T_S], ss[T_S]
    m_force, s_force = ms[T_FORCE], ss[T_FORCE]
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
    map_vector_back(vd, rot, 1.0 / scale, vd_t)
    for k in range(3):
        f_hand[k] = k_h * (xd[k] - xm_dev[k]) + b_h * (vd[k] - vm_dev[k])
    plant_step(ms, v[V_TAU_M], f_hand, app_m, mw)
    plant_step(ss, v[V_TAU_S], f_hand, app_s, sw)
    held_m, held_s = ms[T_HELD], ss[T_HELD]
    for i in range(nm):
        held_m[i] = app_m[i]
    for i in range(ns):
        held_s[i] = app_s[i]
    map_vector(op_f, rot, 1.0 / force_scale, f_hand)
    for k in range(3):
        row[cols[C_OP_X] + k] = xd_t[k]
        row[cols[C_OP_V] + k] = vd_t[k]
        row[cols[C_OP_F] + k] = op_f[k]
        row[cols[C_M_X] + k] = x_m[k]
        row[cols[C_M_V] + k] = v_m[k]
        row[cols[C_M_F] + k] = m_S[S_RATIO] * m_force[k]
        row[cols[C_M_FD] + k] = m_force[k]
        row[cols[C_S_X] + k] = xs[k]
        row[cols[C_S_V] + k] = vs[k]
        row[cols[C_S_F] + k] = s_S[S_RATIO] * s_force[k]
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


@inline  # type: ignore[misc]
def run_start(
    ms_own: Any, ss_own: Any, mw_own: Any, sw_own: Any, ov: np.ndarray, cols: np.ndarray, fwd_rel: np.ndarray,
    fwd_occ: np.ndarray, bwd_rel: np.ndarray, bwd_occ: np.ndarray, fwd_hist: np.ndarray, bwd_hist: np.ndarray,
    data: np.ndarray,
) -> Any:  # fmt: skip
    """The start of a run of ticks (`run_ticks`, arm_codec_kernel.run_ticks_codec): its arguments
    as `borrowed` views (no reference counting in the loop; the caller's arguments own them), in
    the order given, then the tick's vectors (`own`, which the caller keeps alive past every use
    of its views, and `tick_vectors`) and the `run_constants`."""
    ms, ss = detach(ms_own), detach(ss_own)
    nm, ns = ms[T_I][I_N], ss[T_I][I_N]
    own = np.zeros((V_SIZE, max(nm, ns, 3)))  # the tick's vectors, one row each
    ovb = borrowed(ov)
    return (
        ms, ss, detach_work(mw_own), detach_work(sw_own), ovb, borrowed(cols),
        borrowed(fwd_rel), borrowed(fwd_occ), borrowed(bwd_rel), borrowed(bwd_occ),
        borrowed(fwd_hist), borrowed(bwd_hist), borrowed(data),
        own, tick_vectors(own, nm, ns), run_constants(ms, ss, ovb),
    )  # fmt: skip


@jit  # type: ignore[misc]
def run_ticks(
    n0: int,
    n1: int,
    ms_own: Any,
    ss_own: Any,
    mw_own: Any,
    sw_own: Any,
    ov: np.ndarray,
    cols: np.ndarray,
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
    """Ticks [n0, n1) of an arm scene (arm_loop.run_arm_loop's order). fwd_rel, fwd_occ, bwd_rel,
    bwd_occ hold the window of ticks from w0 on; data the block of ticks from d0 on; the
    histories are rings (a power of two deep) of the packets' payloads, indexed by seq."""
    # Every array the ticks use is a borrowed view (no reference counting in the loop); the
    # arguments and the locals below own them until the function returns.
    ms, ss, mw, sw, ov, cols, fwd_rel, fwd_occ, bwd_rel, bwd_occ, fwd_hist, bwd_hist, data, own, v, c = run_start(
        ms_own, ss_own, mw_own, sw_own, ov, cols, fwd_rel, fwd_occ, bwd_rel, bwd_occ, fwd_hist, bwd_hist, data
    )
    fmask = fwd_hist.shape[0] - 1
    bmask = bwd_hist.shape[0] - 1
    for n in range(n0, n1):
        sense(ms, ss, mw, sw, v, c)  # 1. both arms
        side_torque(ms, v[V_QM], v[V_QDM], v[V_XM], v[V_VM], v[V_TAU_M], mw)  # 2. master
        forward_sample(fwd_hist[n & fmask], v)  # 3. forward packet
        frx = released(ss, fwd_rel[n - w0], fwd_hist, fmask)
        side_torque(ss, v[V_QS], v[V_QDS], v[V_XS], v[V_VS], v[V_TAU_S], sw)  # 4. slave
        backward_sample(bwd_hist[n & bmask], v)  # 5. backward packet
        brx = released(ms, bwd_rel[n - w0], bwd_hist, bmask)
        # 6. operator, plants, the row
        finish_tick(n, ms, ss, mw, sw, ov, cols, v, c, data[n - d0], frx, brx, fwd_occ[n - w0], bwd_occ[n - w0])
    own[0, 0] = 0.0  # `own` lives until here, past every use of its views
    return n1


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
