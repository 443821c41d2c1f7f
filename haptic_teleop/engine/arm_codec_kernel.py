"""The compiled arm loop with the codec stage (numba), imported only when an arm scene with a
codec runs compiled (`compiled_arm_loop.codec_kernel`), so codec-less arm runs never compile or
load it (docs/codec.md, "Compiled", "Arm scenes").

The tick is `arm_kernel.run_ticks`'s (the same inlined parts: `read_joints`, `point`,
`side_torque`, `plant_step`, the maps and the operator); a direction with a codec replaces its
schedule lookup by `arm_codec_tick`, which is `CodecChannel.step` for an arm scene's sample
(codec_channel.LAYOUT_ARM: forward x, v; backward x, v, f; 3 task axes each): the grouped
deadband's encoder on 3-value groups (`GroupedDeadbandEncoder`: the distance and the norm of a
group summed in order as core/deadband.vector_norm), or prediction's; the link and the decoders
are the 1-DoF codec kernel's own functions (engine/codec_kernel.py), compiled from their one
definition with the arm layout's places of the vectors (`relaid`: codec_layout's ARM_S_* instead
of S_SENT0, S_LAST0, ...). The decoded sample goes through the receiving side's guard every tick
the decoder gives one, as in the Python arm loop.
"""

from __future__ import annotations

import math
import types as pytypes
from typing import Any

import numba
import numpy as np

from haptic_teleop.engine import codec_kernel as ck
from haptic_teleop.engine.arm_kernel import (
    C_BOCC,
    C_BRX,
    C_FOCC,
    C_FRX,
    C_M_E,
    C_M_F,
    C_M_FD,
    C_M_Q,
    C_M_QD,
    C_M_TAU,
    C_M_V,
    C_M_X,
    C_OP_F,
    C_OP_V,
    C_OP_X,
    C_S_CF,
    C_S_CT,
    C_S_E,
    C_S_F,
    C_S_FD,
    C_S_Q,
    C_S_QD,
    C_S_TAU,
    C_S_V,
    C_S_X,
    F_B_HAND,
    F_FORCE_SCALE,
    F_K_HAND,
    F_SCALE,
    I_DATA,
    I_MODEL,
    I_N,
    O_AMP,
    O_DIR,
    O_ORIGIN,
    O_PERIOD,
    O_PROFILE,
    O_SPEED,
    O_START,
    O_T_END,
    O_W,
    O_X0,
    O_X_END,
    S_ENERGY,
    S_HAS_REMOTE,
    S_RATIO,
    S_REJECTED,
    T_F,
    T_FORCE,
    T_HELD,
    T_I,
    T_LIMITS,
    T_OFFSET,
    T_REMOTE,
    T_ROT,
    T_S,
    T_WRENCH,
    borrowed,
    detach,
    detach_work,
    guarded,
    map_point,
    map_vector,
    map_vector_back,
    mj_step1,
    plant_step,
    point,
    push1,
    read_joints,
    side_torque,
    sinusoid1,
    unmap_point,
)
from haptic_teleop.engine.codec_layout import (
    ARM_AXES,
    ARM_C_TRIG0,
    ARM_S_LAST0,
    ARM_S_OLD0,
    ARM_S_PREV0,
    ARM_S_RATE0,
    ARM_S_SENT0,
    C_DIM,
    C_GAIN,
    C_KIND,
    C_MIN,
    C_P0,
    C_PERIOD_NS,
    C_PMAX,
    C_SENDS_RATE,
    C_SIZE,
    C_VEL,
    DEADBAND,
    NO_CODEC,
    S_BYTES,
    S_COUNT,
    S_FILTERED,
    S_HAS_PREV,
    S_HAS_SENT,
    S_HEAD,
    S_NEWEST,
    S_OFFERED,
    S_PREV_NS,
    S_SENT,
)

jit = numba.njit(cache=True, nogil=True)
inline = numba.njit(cache=True, nogil=True, inline="always")

# Where the vectors of a direction's state are in the arm layout (the 1-DoF names they replace).
ARM_PLACES = {
    "S_SENT0": ARM_S_SENT0,
    "S_PREV0": ARM_S_PREV0,
    "S_LAST0": ARM_S_LAST0,
    "S_OLD0": ARM_S_OLD0,
    "S_RATE0": ARM_S_RATE0,
}


def relaid(f: Any, places: dict[str, int]) -> Any:
    """The inlined codec_kernel function `f` compiled from its own definition with the layout
    constants `places` in place of the 1-DoF ones (its other globals, compiled callees included,
    are its module's)."""
    py = f.py_func
    glob = dict(py.__globals__)
    glob.update(places)
    fn = pytypes.FunctionType(py.__code__, glob, py.__name__, py.__defaults__, py.__closure__)
    fn.__qualname__ = py.__qualname__
    fn.__module__ = py.__module__
    return numba.njit(nogil=True, inline="always")(fn)


link_send = ck.link_send  # scalars of the state only: the same in both layouts
deadband_receive = relaid(ck.deadband_receive, ARM_PLACES)
deadband_sample = relaid(ck.deadband_sample, ARM_PLACES)
prediction_receive = relaid(ck.prediction_receive, ARM_PLACES)
prediction_sample = relaid(ck.prediction_sample, ARM_PLACES)
deadband_p = ck.deadband_p
outside = ck.outside


@inline  # type: ignore[misc]
def arm_codec_tick(
    C: np.ndarray,
    S: np.ndarray,
    U: np.ndarray,
    B: np.ndarray,
    ring: np.ndarray,
    rec: np.ndarray,
    n: int,
    now: int,
    smp: np.ndarray,
    rate: np.ndarray,
    out: np.ndarray,
) -> tuple[int, bool]:
    # CodecChannel.step of an arm scene's direction: encode, send, deliver, decode. Returns (the
    # `received` column's seq or -1, whether `out` holds the tick's remote sample).
    dim = int(C[C_DIM])
    deadband = C[C_KIND] == DEADBAND
    if deadband:  # GroupedDeadbandEncoder.send, 3-value groups
        sends_rate = C[C_SENDS_RATE] != 0.0
        if sends_rate:
            if S[S_HAS_PREV] == 0.0 or now <= S[S_PREV_NS]:
                for i in range(dim):
                    rate[i] = 0.0
            else:
                dt = (now - int(S[S_PREV_NS])) * 1e-9
                for i in range(dim):
                    rate[i] = (smp[i] - S[ARM_S_PREV0 + i]) / dt
        for i in range(dim):
            S[ARM_S_PREV0 + i] = smp[i]
        S[S_HAS_PREV] = 1.0
        S[S_PREV_NS] = now
        S[S_OFFERED] += 1.0
        send = True
        if S[S_HAS_SENT] != 0.0:
            p = C[C_P0]
            if C[C_GAIN] > 0.0:  # p(|v|), |v| as core/deadband.vector_norm
                vel = int(C[C_VEL])
                s2 = 0.0
                for i in range(vel, vel + ARM_AXES):
                    s2 += smp[i] * smp[i]
                p = deadband_p(C[C_P0], C[C_GAIN], C[C_PMAX], math.sqrt(s2))
            send = False
            for g in range(0, dim, ARM_AXES):
                if C[ARM_C_TRIG0 + g] != 0.0:  # violates(last[g], sample[g], p, min_threshold)
                    d2 = 0.0
                    l2 = 0.0
                    for i in range(g, g + ARM_AXES):
                        last = S[ARM_S_SENT0 + i]
                        d = last - smp[i]
                        d2 += d * d
                        l2 += last * last
                    if outside(math.sqrt(d2), math.sqrt(l2), p, C[C_MIN]):
                        send = True
                        break
            if not send:
                S[S_FILTERED] += 1.0
        if send:
            for i in range(dim):
                S[ARM_S_SENT0 + i] = smp[i]
            S[S_HAS_SENT] = 1.0
            S[S_SENT] += 1.0
            link_send(C, S, U, B, ring, rec, n, now, smp, rate, sends_rate)
    else:  # PredictionEncoder.send
        S[S_OFFERED] += 1.0
        S[S_SENT] += 1.0
        S[S_BYTES] += C[C_SIZE]
        link_send(C, S, U, B, ring, rec, n, now, smp, rate, False)
    # Link.deliver, Decoder.receive
    rx = -1
    depth = ring.shape[0]
    while S[S_COUNT] > 0.0:
        head = int(S[S_HEAD])
        if ring[head, 1] > now:
            break
        S[S_HEAD] = (head + 1) & (depth - 1)
        S[S_COUNT] -= 1.0
        seq = int(ring[head, 0])
        if deadband:
            deadband_receive(C, S, seq, ring, head)
        else:
            prediction_receive(C, S, seq, ring, head)
        if seq > S[S_NEWEST]:
            S[S_NEWEST] = seq
            rx = seq
    if deadband:
        return rx, deadband_sample(C, S, n, out)
    return rx, prediction_sample(C, S, n, out)


@inline  # type: ignore[misc]
def guarded_sample(side: Any, sample: np.ndarray) -> None:
    """SampleGuard.accept on the decoder's sample: taken as the remote sample, or counted
    (`arm_kernel.guarded` on a vector instead of a ring row)."""
    lim, S, remote = side[T_LIMITS], side[T_S], side[T_REMOTE]
    for i in range(lim.shape[0]):
        if not abs(sample[i]) <= lim[i]:
            S[S_REJECTED] += 1.0
            return
    for i in range(lim.shape[0]):
        remote[i] = sample[i]
    S[S_HAS_REMOTE] = 1.0


@jit  # type: ignore[misc]
def run_ticks_codec(
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
    fC: np.ndarray,
    fS: np.ndarray,
    fU: np.ndarray,
    fB: np.ndarray,
    fring: np.ndarray,
    frec: np.ndarray,
    bC: np.ndarray,
    bS: np.ndarray,
    bU: np.ndarray,
    bB: np.ndarray,
    bring: np.ndarray,
    brec: np.ndarray,
    scratch: np.ndarray,
) -> int:
    """`arm_kernel.run_ticks` with a codec on the directions whose C_KIND is not NO_CODEC (the
    others read their window of the schedule as there). fC ... frec, bC ... brec: each
    direction's codec arrays (compiled_codec.CodecNet.args, the arm layout); scratch: 3 rows of
    9 (the sample, its rate, the decoder's output)."""
    ms, ss, mw, sw = detach(ms_own), detach(ss_own), detach_work(mw_own), detach_work(sw_own)
    fwd_rel, fwd_occ, bwd_rel, bwd_occ = borrowed(fwd_rel), borrowed(fwd_occ), borrowed(bwd_rel), borrowed(bwd_occ)
    fwd_hist, bwd_hist, data, ov, cols = (
        borrowed(fwd_hist),
        borrowed(bwd_hist),
        borrowed(data),
        borrowed(ov),
        borrowed(cols),
    )
    fC, fS, fU, fB = borrowed(fC), borrowed(fS), borrowed(fU), borrowed(fB)
    fring, frec = borrowed(fring), borrowed(frec)
    bC, bS, bU, bB = borrowed(bC), borrowed(bS), borrowed(bU), borrowed(bB)
    bring, brec = borrowed(bring), borrowed(brec)
    smp, rate, dec = borrowed(scratch[0]), borrowed(scratch[1]), borrowed(scratch[2])
    fcodec = fC[C_KIND] != NO_CODEC
    bcodec = bC[C_KIND] != NO_CODEC
    period_ns = int(fC[C_PERIOD_NS])
    MI, MF = ms[T_I], ms[T_F]
    SI = ss[T_I]
    nm, ns = MI[I_N], SI[I_N]
    own = np.zeros((22, max(nm, ns, 3)))  # the tick's vectors, one row each
    qm, qdm, qs, qds = borrowed(own[0, :nm]), borrowed(own[1, :nm]), borrowed(own[2, :ns]), borrowed(own[3, :ns])
    tau_m, tau_s = borrowed(own[4, :nm]), borrowed(own[5, :ns])
    app_m, app_s = borrowed(own[6, :nm]), borrowed(own[7, :ns])
    xm_dev, vm_dev, x_m, v_m = borrowed(own[8, :3]), borrowed(own[9, :3]), borrowed(own[10, :3]), borrowed(own[11, :3])
    xs, vs, f_env, t_env = borrowed(own[12, :3]), borrowed(own[13, :3]), borrowed(own[14, :3]), borrowed(own[15, :3])
    xd_t, vd_t, xd, vd = borrowed(own[16, :3]), borrowed(own[17, :3]), borrowed(own[18, :3]), borrowed(own[19, :3])
    f_hand, op_f = borrowed(own[20, :3]), borrowed(own[21, :3])
    rot, offset = ms[T_ROT], ms[T_OFFSET]
    scale, force_scale = MF[F_SCALE], MF[F_FORCE_SCALE]
    k_h, b_h = MF[F_K_HAND], MF[F_B_HAND]
    fmask = fwd_hist.shape[0] - 1
    bmask = bwd_hist.shape[0] - 1
    period_s = ov[O_PERIOD]
    m_S, s_S = ms[T_S], ss[T_S]
    m_force, s_force = ms[T_FORCE], ss[T_FORCE]
    s_wrench = ss[T_WRENCH]
    for n in range(n0, n1):
        now = n * period_ns
        # 1. both arms (mj_step1: the state, kinematics and gravity torques of this instant)
        mj_step1(MI[I_MODEL], MI[I_DATA])
        read_joints(ms, qm, qdm)
        point(ms, qdm, xm_dev, vm_dev, mw)
        mj_step1(SI[I_MODEL], SI[I_DATA])
        read_joints(ss, qs, qds)
        point(ss, qds, xs, vs, sw)
        for k in range(3):
            f_env[k] = s_wrench[k]
            t_env[k] = s_wrench[3 + k]
        map_point(x_m, rot, scale, offset, xm_dev)
        map_vector(v_m, rot, scale, vm_dev)
        # 2. master
        side_torque(ms, qm, qdm, x_m, v_m, tau_m, mw)
        # 3. forward packet (the codec's, or the schedule's release)
        if fcodec:
            for k in range(3):
                smp[k] = x_m[k]
                smp[3 + k] = v_m[k]
            frx, got = arm_codec_tick(fC, fS, fU, fB, fring, frec, n, now, smp, rate, dec)
            if got:
                guarded_sample(ss, dec)
            focc = 0.0
        else:
            slot = fwd_hist[n & fmask]
            for k in range(3):
                slot[k] = x_m[k]
                slot[3 + k] = v_m[k]
            frx = fwd_rel[n - w0]
            if frx >= 0:
                guarded(ss, fwd_hist, frx, fmask)
            focc = fwd_occ[n - w0]
        # 4. slave
        side_torque(ss, qs, qds, xs, vs, tau_s, sw)
        # 5. backward packet
        if bcodec:
            for k in range(3):
                smp[k] = xs[k]
                smp[3 + k] = vs[k]
                smp[6 + k] = f_env[k]
            brx, got = arm_codec_tick(bC, bS, bU, bB, bring, brec, n, now, smp, rate, dec)
            if got:
                guarded_sample(ms, dec)
            bocc = 0.0
        else:
            slot = bwd_hist[n & bmask]
            for k in range(3):
                slot[k] = xs[k]
                slot[3 + k] = vs[k]
                slot[6 + k] = f_env[k]
            brx = bwd_rel[n - w0]
            if brx >= 0:
                guarded(ms, bwd_hist, brx, bmask)
            bocc = bwd_occ[n - w0]
        # 6. operator and plants
        t = n * period_s - ov[O_START]
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
        plant_step(ms, tau_m, f_hand, app_m, mw)
        plant_step(ss, tau_s, f_hand, app_s, sw)
        held_m, held_s = ms[T_HELD], ss[T_HELD]
        for i in range(nm):
            held_m[i] = app_m[i]
        for i in range(ns):
            held_s[i] = app_s[i]
        map_vector(op_f, rot, 1.0 / force_scale, f_hand)
        row = data[n - d0]
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
    own[0, 0] = 0.0  # `own` lives until here, past every use of its views
    return n1
