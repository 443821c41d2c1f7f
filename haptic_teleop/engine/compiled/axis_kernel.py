"""The compiled tick loop (numba), imported only by `haptic_teleop.engine.compiled.axis_host`; see its docstring.

Importing this module needs numba and links `mj_step` of the libmujoco the `mujoco` bindings
loaded. Every formula comes from `core` and `plants` and is compiled here from its one
definition; this module holds only the tick's order, which is `Engine._loop`'s, line for line.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import eba, eba_two_condition, tdpa, wave
from haptic_teleop.core import operator as op
from haptic_teleop.engine.compiled import driver
from haptic_teleop.engine.compiled.layout import (
    LAW_RESERVOIR,
    LAW_TDPA_VELOCITY,
    LAW_TDPA_ZOH,
    LAW_TWO_CONDITION,
    LAW_WAVE,
    MASTER,
    OP,
    P_ACT_LIMIT,
    P_AMP,
    P_B,
    P_BOUND_GAIN,
    P_C1,
    P_C2,
    P_CAP,
    P_DAMP,
    P_DRIFT,
    P_E0,
    P_EBA_GAIN,
    P_EBA_ON,
    P_FORCE_LAW,
    P_GAIN,
    P_GUARD_ON,
    P_K,
    P_LAW,
    P_LIM0,
    P_LIM1,
    P_LIM2,
    P_LIM3,
    P_LIMIT,
    P_MASS,
    P_PERIOD_S,
    P_PLANT_LIMIT,
    P_PROFILE,
    P_REFLECT,
    P_SLEW_STEP,
    P_SPEED,
    P_START,
    P_SUBSTEPS,
    P_T_END,
    P_TDPA_ADMIT,
    P_TDPA_RECOVER,
    P_W,
    P_WAVE_A,
    P_WAVE_B,
    P_WAVE_MATCHED,
    P_WAVE_S,
    P_X0,
    P_X_END,
    S_CONTACT,
    S_ENERGY,
    S_HAS_LAST,
    S_HAS_REMOTE,
    S_HELD,
    S_LAST,
    S_OUT,
    S_R0,
    S_R1,
    S_R2,
    S_R3,
    S_REJECTED,
    S_X0,
    SLAVE,
)
from haptic_teleop.plants import mujoco_plant
from haptic_teleop.plants.mujoco_native import mj_step
from haptic_teleop.record.columns import ONE_DOF

# Where each value goes in a tick's row (the 1-DoF tick schema; compile-time constants).
C_OP_X_M = ONE_DOF.col["op_x_m"]
C_OP_V_M_PER_S = ONE_DOF.col["op_v_m_per_s"]
C_OP_FORCE_N = ONE_DOF.col["op_force_n"]
C_M_X_M = ONE_DOF.col["m_x_m"]
C_M_V_M_PER_S = ONE_DOF.col["m_v_m_per_s"]
C_M_FORCE_N = ONE_DOF.col["m_force_n"]
C_M_FORCE_DESIRED_N = ONE_DOF.col["m_force_desired_n"]
C_M_ENERGY_J = ONE_DOF.col["m_energy_j"]
C_S_X_M = ONE_DOF.col["s_x_m"]
C_S_V_M_PER_S = ONE_DOF.col["s_v_m_per_s"]
C_S_FORCE_N = ONE_DOF.col["s_force_n"]
C_S_FORCE_DESIRED_N = ONE_DOF.col["s_force_desired_n"]
C_S_ENERGY_J = ONE_DOF.col["s_energy_j"]
C_S_CONTACT_N = ONE_DOF.col["s_contact_n"]
C_FWD_RX_SEQ = ONE_DOF.col["fwd_rx_seq"]
C_BWD_RX_SEQ = ONE_DOF.col["bwd_rx_seq"]
C_FWD_OCCUPANCY = ONE_DOF.col["fwd_occupancy"]
C_BWD_OCCUPANCY = ONE_DOF.col["bwd_occupancy"]


jit = numba.njit(cache=True, nogil=True)
# The tick's parts (accept2, accept3, finish_tick) are inlined into the loops that call them
# (numba IR): a call between separately compiled functions passes every array field by value.
inline = numba.njit(cache=True, nogil=True, inline="always")
# The tick loop without numba's reference counting (NRT): it allocates nothing, and the array
# views and arguments of its parts would otherwise be counted in and out with atomic operations
# every tick (docs/performance.md).
loop_jit = numba.njit(cache=True, nogil=True, _nrt=False)
# One axis's law and its bound, one definition (core/eba.py: TeleopController.step1 and
# EnergyBound.step1 call the same functions)
command1 = compile_tree(eba.command1)
bound1 = compile_tree(eba.bound1)
within1 = jit(eba.within1)
within2 = jit(eba.within2)
within3 = jit(eba.within3)
# The other stabilizers, one definition each: TDPA's observer and controllers (core/tdpa.py, what
# TdpaBound.step1 runs) and the wave port (core/wave.py, WaveSide.port1)
tdpa1 = compile_tree(tdpa.tdpa1)
received1 = jit(tdpa.received1)
slipped1 = jit(tdpa.slipped1)
wave1 = compile_tree(wave.wave1)
two_condition_bound1 = compile_tree(eba_two_condition.two_condition_bound1)  # TwoConditionBound.step1
push1 = jit(op.push1)
sinusoid1 = jit(op.sinusoid1)
hand1 = jit(op.hand1)
imposed_force1 = jit(op.imposed_force1)
actuator_limited1 = jit(mujoco_plant.actuator_limited1)


@jit  # type: ignore[misc]
def control(P: np.ndarray, S: np.ndarray, side: int, x: float, v: float, master: bool) -> tuple[float, float]:
    # TeleopController.step1 then the bound's step1 (core/eba.py's `command1`, `bound1`; TDPA's
    # `tdpa1`; a wave port's `wave1`): returns (applied, desired). The master's remote sample is
    # (f_env, x, v), the slave's (x, v) (with TDPA its energy after them; waves: (wave, x)).
    law = P[side + P_LAW]
    X = side + S_X0
    if law == LAW_WAVE:
        S[side + S_ENERGY], S[X + 4], S[X + 3], desired, f, S[side + S_OUT] = wave1(
            master, S[side + S_ENERGY], S[side + S_HELD], S[side + S_LAST], S[side + S_HAS_LAST] != 0.0, S[X + 4],
            S[X + 3], S[X], S[X + 1] != 0.0, S[X + 2], x, v, P[side + P_CAP], P[P_PERIOD_S], P[side + P_WAVE_S],
            P[side + P_WAVE_B], P[side + P_C1], P[side + P_C2], P[side + P_WAVE_A], P[side + P_DRIFT],
            P[side + P_WAVE_MATCHED] != 0.0,
        )  # fmt: skip
        S[X + 1] = 0.0  # each received wave is used once
    else:
        has_remote = S[side + S_HAS_REMOTE] != 0.0
        force_law = P[side + P_FORCE_LAW] != 0.0
        ra, rb = S[side + S_R0], S[side + S_R1]
        if master and not force_law:
            ra, rb = S[side + S_R1], S[side + S_R2]
        tdpa_law = law == LAW_TDPA_VELOCITY or law == LAW_TDPA_ZOH  # noqa: PLR1714 (numba: plain comparisons)
        admittance = tdpa_law and P[side + P_TDPA_ADMIT] != 0.0 and not force_law
        if admittance:  # TDPA's admittance placement: the reference offset by its slip
            ra = ra + S[X + 5]
        desired, f = command1(
            has_remote, force_law, P[side + P_GAIN], P[side + P_C1], P[side + P_C2], ra, rb, x, v, P[side + P_LIMIT]
        )
        if law == LAW_RESERVOIR:
            limited = P[side + P_ACT_LIMIT] < np.inf or P[side + P_SLEW_STEP] < np.inf  # EnergyBoundParams.limited
            S[side + S_ENERGY], f = bound1(
                S[side + S_ENERGY], P[side + P_EBA_GAIN], S[side + S_HELD], S[side + S_LAST],
                S[side + S_HAS_LAST] != 0.0, x, f, P[side + P_EBA_ON] != 0.0, limited, P[side + P_BOUND_GAIN],
                P[side + P_ACT_LIMIT], P[side + P_SLEW_STEP],
            )  # fmt: skip
        elif law == LAW_TWO_CONDITION:
            dx = x - S[side + S_LAST] if S[side + S_HAS_LAST] != 0.0 else 0.0
            S[side + S_ENERGY], f = two_condition_bound1(
                S[side + S_ENERGY], S[side + S_HELD], dx, f, P[side + P_EBA_ON] != 0.0, P[side + P_EBA_GAIN],
                P[side + P_BOUND_GAIN], P[side + P_ACT_LIMIT],
            )  # fmt: skip
        else:  # TDPA_EXTRA: E_in, E_out, the remote's E_in, the damping credit, what the samples carry, slip
            before = f
            S[X], S[X + 1], S[X + 3], S[side + S_ENERGY], S[X + 4], f = tdpa1(
                S[X], S[X + 1], S[X + 3], S[X + 2], S[side + S_HELD], S[side + S_LAST], S[side + S_HAS_LAST] != 0.0,
                x, f, P[side + P_E0], P[side + P_EBA_GAIN], P[side + P_BOUND_GAIN], P[side + P_REFLECT],
                law == LAW_TDPA_ZOH, P[side + P_EBA_ON] != 0.0, P[side + P_CAP],
            )  # fmt: skip
            if admittance:
                S[X + 5] = slipped1(S[X + 5], before, f, P[side + P_C1], P[side + P_TDPA_RECOVER])
    S[side + S_HAS_LAST] = 1.0
    S[side + S_LAST] = x
    S[side + S_HELD] = f
    return f, desired


@inline  # type: ignore[misc]
def accept2(P: np.ndarray, S: np.ndarray, a: float, b: float) -> None:
    # The slave's remote sample (x, v), through its guard (TeleopController.set_remote).
    if P[SLAVE + P_GUARD_ON] == 0.0 or within2(a, b, P[SLAVE + P_LIM0], P[SLAVE + P_LIM1]):
        S[SLAVE + S_HAS_REMOTE] = 1.0
        S[SLAVE + S_R0] = a
        S[SLAVE + S_R1] = b
    else:
        S[SLAVE + S_REJECTED] += 1.0


@inline  # type: ignore[misc]
def accept3(P: np.ndarray, S: np.ndarray, a: float, b: float, c: float) -> None:
    # The master's remote sample (f_env, x, v), through its guard.
    if P[MASTER + P_GUARD_ON] == 0.0 or within3(a, b, c, P[MASTER + P_LIM0], P[MASTER + P_LIM1], P[MASTER + P_LIM2]):
        S[MASTER + S_HAS_REMOTE] = 1.0
        S[MASTER + S_R0] = a
        S[MASTER + S_R1] = b
        S[MASTER + S_R2] = c
    else:
        S[MASTER + S_REJECTED] += 1.0


@inline  # type: ignore[misc]
def accept_energy(P: np.ndarray, S: np.ndarray, side: int, ok: bool, e: float) -> bool:
    # A TDPA sample's energy `e` through the guard's last limit; accepted, the remote side's input
    # energy grows to it (TeleopController.set_remote, TdpaBound.receive).
    lim = P[side + P_LIM2] if side == SLAVE else P[side + P_LIM3]
    if P[side + P_GUARD_ON] != 0.0 and not (ok and within1(e, lim)):
        S[side + S_REJECTED] += 1.0
        return False
    S[side + S_HAS_REMOTE] = 1.0
    S[side + S_X0 + 2] = received1(S[side + S_X0 + 2], e)
    return True


@inline  # type: ignore[misc]
def accept_wave(P: np.ndarray, S: np.ndarray, side: int, u: float, x: float) -> None:
    # A wave sample (the wave, the sender's position) through the guard (WaveSide.receive): fresh,
    # used at the side's next tick.
    if P[side + P_GUARD_ON] == 0.0 or within2(u, x, P[side + P_LIM0], P[side + P_LIM1]):
        S[side + S_HAS_REMOTE] = 1.0
        S[side + S_R0] = u
        S[side + S_R1] = x
        S[side + S_X0] = u
        S[side + S_X0 + 1] = 1.0
        S[side + S_X0 + 2] = x
    else:
        S[side + S_REJECTED] += 1.0


@inline  # type: ignore[misc]
def put_sample(
    P: np.ndarray, S: np.ndarray, hist: np.ndarray, j: int, side: int, a: float, b: float, c: float, n: int, x: float
) -> None:
    # A side's sample into its sender's ring (AxisSide.tick): its n values (the master's (x, v),
    # the slave's (f_env, x, v)); with TDPA its energy after them; a wave port's (wave, x).
    law = P[side + P_LAW]
    if law == LAW_WAVE:
        hist[j, 0] = S[side + S_OUT]
        hist[j, 1] = x
        return
    hist[j, 0] = a
    hist[j, 1] = b
    if n == 3:
        hist[j, 2] = c
    if law == LAW_TDPA_VELOCITY or law == LAW_TDPA_ZOH:  # noqa: PLR1714, SIM109 (numba: plain comparisons)
        hist[j, n] = S[side + S_X0 + 4]


@inline  # type: ignore[misc]
def forward_sample(P: np.ndarray, S: np.ndarray, hist: np.ndarray, j: int, x_m: float, v_m: float) -> None:
    put_sample(P, S, hist, j, MASTER, x_m, v_m, 0.0, 2, x_m)


@inline  # type: ignore[misc]
def forward_accept(P: np.ndarray, S: np.ndarray, h: np.ndarray) -> None:
    # The slave takes a released forward sample (`forward_sample`'s layout).
    law = P[SLAVE + P_LAW]
    if law == LAW_RESERVOIR or law == LAW_TWO_CONDITION:  # noqa: PLR1714, SIM109 (numba: plain comparisons)
        accept2(P, S, h[0], h[1])
    elif law == LAW_WAVE:
        accept_wave(P, S, SLAVE, h[0], h[1])
    else:
        ok = P[SLAVE + P_GUARD_ON] == 0.0 or within2(h[0], h[1], P[SLAVE + P_LIM0], P[SLAVE + P_LIM1])
        if accept_energy(P, S, SLAVE, ok, h[2]):
            S[SLAVE + S_R0] = h[0]
            S[SLAVE + S_R1] = h[1]
            S[SLAVE + S_R2] = h[2]


@inline  # type: ignore[misc]
def backward_sample(
    P: np.ndarray, S: np.ndarray, hist: np.ndarray, j: int, f_env: float, x_s: float, v_s: float
) -> None:
    put_sample(P, S, hist, j, SLAVE, f_env, x_s, v_s, 3, x_s)


@inline  # type: ignore[misc]
def backward_accept(P: np.ndarray, S: np.ndarray, h: np.ndarray) -> None:
    # The master takes a released backward sample (`backward_sample`'s layout).
    law = P[MASTER + P_LAW]
    if law == LAW_RESERVOIR or law == LAW_TWO_CONDITION:  # noqa: PLR1714, SIM109 (numba: plain comparisons)
        accept3(P, S, h[0], h[1], h[2])
    elif law == LAW_WAVE:
        accept_wave(P, S, MASTER, h[0], h[1])
    else:
        ok = P[MASTER + P_GUARD_ON] == 0.0 or within3(
            h[0], h[1], h[2], P[MASTER + P_LIM0], P[MASTER + P_LIM1], P[MASTER + P_LIM2]
        )
        if accept_energy(P, S, MASTER, ok, h[3]):
            S[MASTER + S_R0] = h[0]
            S[MASTER + S_R1] = h[1]
            S[MASTER + S_R2] = h[2]
            S[MASTER + S_R3] = h[3]


@inline  # type: ignore[misc]
def finish_tick(
    n: int,
    models: np.ndarray,
    mq: np.ndarray,
    mv: np.ndarray,
    mctrl: np.ndarray,
    sctrl: np.ndarray,
    sqfrc: np.ndarray,
    P: np.ndarray,
    S: np.ndarray,
    row: np.ndarray,
    x_m: float,
    v_m: float,
    x_s: float,
    v_s: float,
    f_env: float,
    fm: float,
    m_desired: float,
    fs: float,
    s_desired: float,
    frx: float,
    brx: float,
    focc: float,
    bocc: float,
) -> None:
    # The tick after the controllers and the network: operator, plants, the tick's row.
    tau = n * P[P_PERIOD_S] - P[OP + P_START]
    profile = P[OP + P_PROFILE]
    imposed = profile == 3.0
    if profile == 0.0 or imposed:
        xd, vd = push1(tau, P[OP + P_X0], P[OP + P_SPEED], P[OP + P_T_END], P[OP + P_X_END])
    elif profile == 1.0:
        xd, vd = sinusoid1(tau, P[OP + P_X0], P[OP + P_AMP], P[OP + P_W])
    else:
        xd, vd = P[OP + P_X0], 0.0
    fh = 0.0 if imposed else hand1(P[OP + P_K], P[OP + P_B], xd, vd, x_m, v_m)
    fm_applied = actuator_limited1(fm, P[MASTER + P_PLANT_LIMIT])
    S[MASTER + S_HELD] = fm_applied  # EnergyBound.applied1: the reservoir accounts with it
    mctrl[0] = fh
    mctrl[1] = fm_applied
    for _ in range(int(P[MASTER + P_SUBSTEPS])):
        mj_step(models[0], models[1])
    if imposed:  # the handle put on the trajectory at tick n + 1 (Engine._drive)
        x1, v1 = push1(
            (n + 1) * P[P_PERIOD_S] - P[OP + P_START], P[OP + P_X0], P[OP + P_SPEED], P[OP + P_T_END], P[OP + P_X_END]
        )
        mq[0] = x1
        mv[0] = v1
        fh = imposed_force1(P[OP + P_MASS], P[OP + P_DAMP], P[P_PERIOD_S], v_m, v1, fm_applied)
    fs_applied = actuator_limited1(fs, P[SLAVE + P_PLANT_LIMIT])
    S[SLAVE + S_HELD] = fs_applied
    sctrl[0] = fs_applied
    s_steps = int(P[SLAVE + P_SUBSTEPS])
    if s_steps == 1:
        mj_step(models[2], models[3])
        S[SLAVE + S_CONTACT] = 0.0 + sqfrc[0]
    else:
        acc = 0.0
        for _ in range(s_steps):
            mj_step(models[2], models[3])
            acc += sqfrc[0]
        S[SLAVE + S_CONTACT] = acc / s_steps
    row[C_OP_X_M] = xd
    row[C_OP_V_M_PER_S] = vd
    row[C_OP_FORCE_N] = fh
    row[C_M_X_M] = x_m
    row[C_M_V_M_PER_S] = v_m
    row[C_M_FORCE_N] = fm_applied
    row[C_M_FORCE_DESIRED_N] = m_desired
    row[C_M_ENERGY_J] = S[MASTER + S_ENERGY]
    row[C_S_X_M] = x_s
    row[C_S_V_M_PER_S] = v_s
    row[C_S_FORCE_N] = fs_applied
    row[C_S_FORCE_DESIRED_N] = s_desired
    row[C_S_ENERGY_J] = S[SLAVE + S_ENERGY]
    row[C_S_CONTACT_N] = f_env
    row[C_FWD_RX_SEQ] = frx
    row[C_BWD_RX_SEQ] = brx
    row[C_FWD_OCCUPANCY] = focc
    row[C_BWD_OCCUPANCY] = bocc


@inline  # type: ignore[misc]
def forward_released(
    P: np.ndarray, S: np.ndarray, w: int, j: int, mask: int, rel: np.ndarray, hist: np.ndarray, x_m: float, v_m: float
) -> int:
    # The forward direction on its schedule: the master's sample into the sender's ring (row j),
    # the packet the window's row w releases (if any) to the slave. Returns its seq or -1.
    forward_sample(P, S, hist, j, x_m, v_m)
    rx = rel[w]
    if rx >= 0:
        forward_accept(P, S, hist[rx & mask])
    return rx


@inline  # type: ignore[misc]
def backward_released(
    P: np.ndarray, S: np.ndarray, w: int, j: int, mask: int, rel: np.ndarray, hist: np.ndarray,
    f_env: float, x_s: float, v_s: float,
) -> int:  # fmt: skip
    # `forward_released` of the backward direction (the slave's contact force, x, v).
    backward_sample(P, S, hist, j, f_env, x_s, v_s)
    rx = rel[w]
    if rx >= 0:
        backward_accept(P, S, hist[rx & mask])
    return rx


# The stages of the compiled tick (engine/compiled/driver.py) for one axis: `run` is the plants'
# and controllers' arrays, the tick's values a tuple (x_m, v_m, x_s, v_s, f_env, then each side's
# applied and desired force as its law runs); a direction on its schedule is (rel, occ, hist,
# mask, w0).


@inline  # type: ignore[misc]
def axis_begin(world: Any) -> Any:
    return world


@inline  # type: ignore[misc]
def schedule_open(net: Any) -> Any:
    # a direction on its schedule: its window of releases and occupancies (from tick w0 on) and
    # the sender's ring of payloads (a power of two deep, indexed by seq)
    rel, occ, hist, w0 = net
    return rel, occ, hist, hist.shape[0] - 1, w0


@inline  # type: ignore[misc]
def axis_sense(run: Any, n: int) -> Any:
    mq, mv, sq, sv, S = run[1], run[2], run[4], run[5], run[9]
    return mq[0], mv[0], sq[0], sv[0], S[SLAVE + S_CONTACT]


@inline  # type: ignore[misc]
def axis_master(run: Any, t: Any) -> Any:
    fm, m_desired = control(run[8], run[9], MASTER, t[0], t[1], True)
    return t[0], t[1], t[2], t[3], t[4], fm, m_desired


@inline  # type: ignore[misc]
def axis_slave(run: Any, t: Any) -> Any:
    fs, s_desired = control(run[8], run[9], SLAVE, t[2], t[3], False)
    return t[0], t[1], t[2], t[3], t[4], t[5], t[6], fs, s_desired


@inline  # type: ignore[misc]
def schedule_forward(run: Any, f: Any, t: Any, n: int, n1: int) -> tuple[int, float]:
    rel, occ, hist, mask, w0 = f
    return forward_released(run[8], run[9], n - w0, n & mask, mask, rel, hist, t[0], t[1]), occ[n - w0]


@inline  # type: ignore[misc]
def schedule_backward(run: Any, b: Any, t: Any, n: int, n1: int) -> tuple[int, float]:
    rel, occ, hist, mask, w0 = b
    return backward_released(run[8], run[9], n - w0, n & mask, mask, rel, hist, t[4], t[2], t[3]), occ[n - w0]


@inline  # type: ignore[misc]
def axis_finish(run: Any, t: Any, n: int, frx: float, brx: float, focc: float, bocc: float) -> None:
    models, mq, mv, mctrl, _sq, _sv, sctrl, sqfrc, P, S, data, d0 = run
    x_m, v_m, x_s, v_s, f_env, fm, m_desired, fs, s_desired = t
    finish_tick(
        n, models, mq, mv, mctrl, sctrl, sqfrc, P, S, data[n - d0], x_m, v_m, x_s, v_s, f_env,
        fm, m_desired, fs, s_desired, frx, brx, focc, bocc,
    )  # fmt: skip


@inline  # type: ignore[misc]
def axis_end(run: Any) -> None:
    pass


AXIS_SIDES = {
    "begin": axis_begin, "sense": axis_sense, "master": axis_master, "slave": axis_slave,
    "finish": axis_finish, "end": axis_end,
}  # fmt: skip
# The tick on the schedule both ways (the codec kernel composes the same sides with its channels)
drive_axis = driver.compose(
    **AXIS_SIDES,
    open_forward=schedule_open,
    open_backward=schedule_open,
    forward=schedule_forward,
    backward=schedule_backward,
)


@loop_jit  # type: ignore[misc]
def run_ticks(
    n0: int,
    n1: int,
    models: np.ndarray,  # int64: master model, master data, slave model, slave data addresses
    mq: np.ndarray,
    mv: np.ndarray,
    mctrl: np.ndarray,
    sq: np.ndarray,
    sv: np.ndarray,
    sctrl: np.ndarray,
    sqfrc: np.ndarray,
    fwd_rel: np.ndarray,
    fwd_occ: np.ndarray,
    bwd_rel: np.ndarray,
    bwd_occ: np.ndarray,
    fwd_hist: np.ndarray,
    bwd_hist: np.ndarray,
    P: np.ndarray,
    S: np.ndarray,
    data: np.ndarray,
    w0: int,
    d0: int,
) -> int:
    # The composed tick over ticks [n0, n1): fwd_rel, fwd_occ, bwd_rel, bwd_occ hold the window of
    # ticks from w0 on; data the block of ticks from d0 on; the histories are rings (a power of two
    # deep) indexed by seq.
    run = (models, mq, mv, mctrl, sq, sv, sctrl, sqfrc, P, S, data, d0)
    return drive_axis(n0, n1, run, (fwd_rel, fwd_occ, fwd_hist, w0), (bwd_rel, bwd_occ, bwd_hist, w0))  # type: ignore[no-any-return]


@jit  # type: ignore[misc]
def bare_steps(models: np.ndarray, steps: int) -> None:
    """`steps` mj_steps of the master model then the slave's, nothing else: the floor under a tick
    (`bench speed`)."""
    for _ in range(steps):
        mj_step(models[0], models[1])
        mj_step(models[2], models[3])
