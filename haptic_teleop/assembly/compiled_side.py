"""One side of an arm scene's tick, compiled, from the side's objects (the live nodes: nodes/arm_side.py;
the engine's compiled arm loop packs both sides the same way): `side_tuple` packs a side's plant,
law, bound and guard into the arrays of side_kernel.py's T_* layout, `store_side` writes the state
back, and `CompiledSideTick` runs the side's tick (`side_kernel.side_tick`, `side_begin`,
`side_law`, `side_end`) with the interface of the Python `side.SideTick`. `side_tick` gives the
compiled one where it can run, else the Python one and why.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_teleop import compiling
from haptic_teleop.core.eba_coupled import CoupledBoundState

if TYPE_CHECKING:
    from haptic_teleop.assembly.parts import ArmParts, ArmSide
    from haptic_teleop.scene.schema import Scene


@functools.cache
def _side_kernel_or_error() -> tuple[Any, str | None]:
    try:
        return compiling.load("haptic_teleop.assembly.side_kernel"), None
    except Exception as exc:  # noqa: BLE001 - no numba, or it cannot load here: the Python tick runs
        return None, f"numba unavailable or failing ({type(exc).__name__}: {exc})"


def side_kernel() -> Any:
    """The compiled side stage (module assembly/side_kernel.py); raises if it cannot load."""
    k, err = _side_kernel_or_error()
    if k is None:
        raise RuntimeError(err)
    return k


@functools.cache
def side_unusable() -> str | None:
    """Why a side's tick cannot run compiled on this machine (no numba, or an mjData contact
    layout it does not know), or None."""
    err = _side_kernel_or_error()[1]
    if err is not None:
        return err
    from haptic_teleop.plants.mujoco_native import contact_layout

    layout = contact_layout()
    return layout if isinstance(layout, str) else None


def side_tuple(side: ArmSide, parts: ArmParts, master: bool, data: Any = None) -> tuple[Any, ...]:
    """The kernel's side tuple (side_kernel's T_* order) of one side, sharing the plant's MjData
    arrays (or those of `data`, another MjData of the same model), with the constants and a copy
    of the state the side's objects give through their public seams (`constants()`, `state()`):
    `store_side` writes the state back (`set_state`, `stepped_externally`)."""
    from haptic_teleop.plants.mujoco_native import contact_layout

    k = side_kernel()
    layout = contact_layout()
    assert not isinstance(layout, str)
    plant: Any = side.plant
    m, d = plant.model, plant.data if data is None else data
    n = plant.n
    law, bound = side.law, side.bound
    bp = bound.params
    pc = plant.constants()  # the plant's, the law's and the bound's constants, and the bound's state
    lc = law.constants()
    bc = bound.constants()
    bs = bound.state()
    iv = np.zeros(k.I_SIZE, dtype=np.int64)
    iv[k.I_MODEL], iv[k.I_DATA] = m._address, d._address
    iv[k.I_N] = n
    iv[k.I_SITE] = pc.site_id
    iv[k.I_SUBSTEPS] = pc.substeps
    iv[k.I_GRAVITY] = 1 if pc.gravity_compensation else 0
    iv[k.I_ROTATIONAL] = 1 if side.rotational else 0
    iv[k.I_NULL] = 1 if lc.null_space else 0
    iv[k.I_ENABLED] = 1 if bp.enabled else 0
    iv[k.I_KEEP_DIRECTION] = 1 if bc.keep_direction else 0
    iv[k.I_SLEW] = 0 if bc.slew_step_nm is None else 1
    pg = pc.wall_geoms
    iv[k.I_WALL] = 0 if pg is None else 1
    iv[k.I_GEOM1], iv[k.I_GEOM2] = (-1, -1) if pg is None else pg
    for pos, value in zip(
        (k.I_NCON, k.I_CONTACT, k.I_STRIDE, k.I_POS, k.I_FRAME, k.I_G1, k.I_G2, k.I_EFC), layout, strict=True
    ):
        iv[pos] = value
    iv[k.I_HAND] = 1 if master else 0
    iv[k.I_JAC_SCALE] = 1 if master else 0
    iv[k.I_NV] = m.nv
    iv[k.I_LAW] = law_code(bound)
    mp = parts.mapping
    F = np.zeros(k.F_SIZE)
    F[k.F_LIMIT] = side.force_limit_n
    F[k.F_MU] = law.params.pinv_damping_m
    F[k.F_SCALE] = mp.scale
    F[k.F_FORCE_SCALE] = mp.force_scale
    opp = parts.operator.params
    F[k.F_K_HAND] = opp.stiffness_n_per_m
    F[k.F_B_HAND] = opp.damping_n_s_per_m
    F[k.F_E0] = getattr(bound, "initial_energy_j", bp.initial_energy_j)  # TDPA: lowered by a restart
    F[k.F_REFLECT] = getattr(bound, "reflection", 0.0)  # TDPA's kept fraction
    F[k.F_ADMIT] = 1.0 if getattr(bound, "admittance", False) else 0.0  # TDPA's admittance placement
    F[k.F_RECOVER] = getattr(bound, "recover", 0.0)
    if law_code(bound) == k.LAW_WAVE:  # CoupledWaveBound's port constants
        F[k.F_WAVE_B], F[k.F_WAVE_S], F[k.F_WAVE_POLE] = bound.impedance, bound.s, bound.pole
        F[k.F_WAVE_DRIFT], F[k.F_WAVE_MATCHED] = bound.drift_gain, 1.0 if bound.matched else 0.0
        F[k.F_WAVE_MASTER] = 1.0 if bound.master else 0.0
    F[k.F_PERIOD] = bp.period_s
    S = np.zeros(max(k.S_SIZE, k.S_EXTRA + len(bs.extra)))  # the two-condition law: a ledger per joint
    S[k.S_ENERGY] = bs.energy_j
    S[k.S_HAS_LAST] = 1.0 if bs.has_last else 0.0
    S[k.S_REJECTED] = side.guard.rejected
    S[k.S_SCALE] = bs.scale
    S[k.S_EXTRA : k.S_EXTRA + len(bs.extra)] = bs.extra
    r_hold = np.zeros((3, 3))
    if law.r_hold is not None:
        r_hold[:] = law.r_hold
        S[k.S_HAS_HOLD] = 1.0
    lim = np.array(side.guard.limits, dtype=float)
    step = bc.slew_step_nm if bc.slew_step_nm is not None else np.zeros(n)
    return (
        iv,
        np.asarray(pc.qpos_adr, dtype=np.int64),
        np.asarray(pc.dof_adr, dtype=np.int64),
        np.asarray(pc.actuator_ids, dtype=np.int64),
        F,
        lc.stiffness_n_per_m,
        lc.damping_n_s_per_m,
        lc.rot_stiffness_nm_per_rad,
        lc.rot_damping_nm_s_per_rad,
        lc.null_damping_nm_s_per_rad,
        bc.gain,
        bc.bound_gain,
        np.asarray(step, dtype=float),
        bc.low,
        bc.high,
        np.asarray(plant.torque_lo, dtype=float),
        np.asarray(plant.torque_hi, dtype=float),
        np.asarray(pc.hand_support_n, dtype=float),
        np.ascontiguousarray(mp.force_scale * mp.matrix),
        lim,
        np.ascontiguousarray(mp.matrix),
        np.ascontiguousarray(mp.offset),
        d.qpos,
        d.qvel,
        d.ctrl,
        d.qfrc_applied,
        d.qfrc_gravcomp,
        d.site_xpos,
        d.site_xmat,
        S,
        bs.last_q_rad,
        bs.held_nm,
        np.zeros(len(lim)),
        r_hold,
        np.zeros(3),
        np.concatenate(plant.contact_wrench()),
    )


def store_side(side: ArmSide, t: tuple[Any, ...]) -> int:
    """Write a side's compiled state back into its Python objects (the bound's state, guard count,
    held orientation, the plant's wall wrench); returns the ticks a motor's room scaled the torque down."""
    k = side_kernel()
    S = t[k.T_S]
    extra = len(side.bound.state().extra)  # TDPA's state (core/tdpa_coupled.TDPA_EXTRA), the joints' ledgers, or none
    side.bound.set_state(
        CoupledBoundState(
            energy_j=float(S[k.S_ENERGY]),
            held_nm=t[k.T_HELD],
            last_q_rad=t[k.T_LAST_Q],
            has_last=bool(S[k.S_HAS_LAST]),
            scale=float(S[k.S_SCALE]),
            extra=tuple(float(e) for e in S[k.S_EXTRA : k.S_EXTRA + extra]),
        )
    )
    side.guard.rejected = int(S[k.S_REJECTED])
    if S[k.S_HAS_HOLD]:
        side.law.r_hold = np.array(t[k.T_RHOLD])
    side.plant.stepped_externally(t[k.T_WRENCH])  # type: ignore[attr-defined]  # mj_step1 is due
    return int(S[k.S_LIMITED])


def law_code(bound: Any) -> int:
    """side_kernel's I_LAW code of a side's bound: EBA's pooled bound, the two conditions joint by
    joint, TDPA's with its controller, or wave variables' ports."""
    from haptic_teleop.core.eba_two_condition_coupled import CoupledTwoConditionBound
    from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound
    from haptic_teleop.core.wave_coupled import CoupledWaveBound

    k = side_kernel()
    if isinstance(bound, CoupledTwoConditionBound):
        return int(k.LAW_TWO_CONDITION)
    if isinstance(bound, CoupledWaveBound):
        return int(k.LAW_WAVE)
    if not isinstance(bound, CoupledTdpaBound):
        return int(k.LAW_EBA)
    return int(k.LAW_TDPA_ZOH if bound.controller == "zoh" else k.LAW_TDPA_VELOCITY)


def compiled_bounds() -> tuple[type, ...]:
    """The arm stabilizers the compiled side runs (side_kernel's I_LAW codes)."""
    from haptic_teleop.core.eba_coupled import CoupledEnergyBound
    from haptic_teleop.core.eba_two_condition_coupled import CoupledTwoConditionBound
    from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound
    from haptic_teleop.core.wave_coupled import CoupledWaveBound

    return (CoupledEnergyBound, CoupledTdpaBound, CoupledTwoConditionBound, CoupledWaveBound)


def compiled_reason_side(side: ArmSide) -> str | None:
    """Why one side's tick cannot run compiled (`CompiledSideTick`), or None if it can."""
    from haptic_teleop.plants.arm import MujocoArm

    if type(side.plant) is not MujocoArm:
        return "plant effects or a non-MuJoCo backend (only the bare MuJoCo arms are compiled)"
    if side.law.params.law != "position":
        return f"task law {side.law.params.law!r} (compiled: position)"
    if type(side.bound) not in compiled_bounds():
        return f"stabilizer {type(side.bound).__name__} (compiled: EBA's bounds, TDPA)"
    return side_unusable()


class _Ledger:
    """The compiled side's energy bound as `SideTick.bound` is used by the nodes: the reservoir (or
    TDPA's budget), the parameters, `restart`, `held` (the kernel's own array: writing it is the
    ledger's input) and, with TDPA, `receive`, `sent_j` and the counts (`CoupledTdpaBound`'s,
    kept in the kernel's state from S_EXTRA on in TDPA_EXTRA's order)."""

    def __init__(self, side: ArmSide, t: tuple[Any, ...], k: Any) -> None:
        self.params = side.bound.params
        self.held: np.ndarray = t[k.T_HELD]
        self._S: np.ndarray = t[k.T_S]
        self._F: np.ndarray = t[k.T_F]
        self._k = k
        law = int(t[k.T_I][k.I_LAW])
        self.tdpa = law in (int(k.LAW_TDPA_VELOCITY), int(k.LAW_TDPA_ZOH))
        self.joints = side.plant.n if law == int(k.LAW_TWO_CONDITION) else 0  # a ledger per joint
        self.wave = law == int(k.LAW_WAVE)

    @property
    def energy_j(self) -> float:
        return float(self._S[self._k.S_ENERGY])

    def _extra(self, name: str) -> float:
        from haptic_teleop.core.tdpa_coupled import TDPA_EXTRA

        return float(self._S[self._k.S_EXTRA + TDPA_EXTRA.index(name)])

    @property
    def energy_in_j(self) -> float:
        return self._extra("energy_in_j")

    @property
    def energy_out_j(self) -> float:
        return self._extra("energy_out_j")

    @property
    def remote_in_j(self) -> float:
        return self._extra("remote_in_j")

    @property
    def sent_j(self) -> float:
        return self._extra("sent_j")

    @property
    def initial_energy_j(self) -> float:
        return float(self._F[self._k.F_E0]) if self.tdpa else float(self.params.initial_energy_j)

    @property
    def sent(self) -> np.ndarray:
        """`CoupledWaveBound.sent`: the waves this tick sends (a view of the kernel's state)."""
        from haptic_teleop.core.wave_coupled import AXES, W_SENT

        i = self._k.S_EXTRA + W_SENT
        return self._S[i : i + AXES]

    def receive(self, sample: Any) -> None:
        """`CoupledTdpaBound.receive` (the remote side's cumulative input energy, `tdpa.received1`),
        or with wave variables `CoupledWaveBound.receive` (a whole accepted sample: its waves)."""
        if self.wave:
            from haptic_teleop.core.wave_coupled import WAVE_ARM_SIZE, wave_receive

            i = self._k.S_EXTRA
            wave_receive(self._S[i : i + WAVE_ARM_SIZE], np.asarray(sample[:6], dtype=float))
            return
        energy_in_j = float(sample)
        from haptic_teleop.core.tdpa import received1
        from haptic_teleop.core.tdpa_coupled import TDPA_EXTRA

        i = self._k.S_EXTRA + TDPA_EXTRA.index("remote_in_j")
        self._S[i] = received1(float(self._S[i]), float(energy_in_j))

    def restart(self, energy_j: float) -> None:
        """`CoupledEnergyBound.restart` (the reservoir set, the next tick's q taken as the first);
        with TDPA `CoupledTdpaBound.restart` (E0 := energy_j, every count 0)."""
        k = self._k
        self._S[k.S_ENERGY] = float(energy_j)
        self._S[k.S_HAS_LAST] = 0.0
        if self.wave:  # CoupledWaveBound.restart: the port state afresh, its ledger at energy_j
            from haptic_teleop.core.wave_coupled import W_ENERGY, WAVE_ARM_SIZE

            self._S[k.S_EXTRA : k.S_EXTRA + WAVE_ARM_SIZE] = 0.0
            self._S[k.S_EXTRA + W_ENERGY] = float(energy_j)
        if self.joints:  # CoupledTwoConditionBound.restart: each joint's ledger E0 / n
            ledgers = self._S[k.S_EXTRA : k.S_EXTRA + self.joints]
            ledgers[:] = float(energy_j) / self.joints
            self._S[k.S_ENERGY] = float(np.sum(ledgers))
        if self.tdpa:
            from haptic_teleop.core.tdpa_coupled import TDPA_EXTRA

            self._F[k.F_E0] = float(energy_j)
            self._S[k.S_EXTRA : k.S_EXTRA + len(TDPA_EXTRA)] = 0.0


class CompiledSideTick:
    """`side.SideTick` for one side, compiled: `torque` runs `side_kernel.side_tick` (the side's
    part of the engine's compiled tick) on the plant's MjData after mj_step1. Its state (reservoir,
    held torques, last q, held orientation) lives in the kernel's arrays, built from the side's
    Python objects when made; `limit`, `force`, `ratio`, `limited_ticks` and `bound` as SideTick's."""

    def __init__(self, side: ArmSide, parts: ArmParts, master: bool) -> None:
        self.k = k = side_kernel()
        plant: Any = side.plant
        self.t = t = side_tuple(side, parts, master)
        self.w = tuple(k.work_arrays(plant.n, plant.model.nv, 6 if side.rotational else 3))
        self._F: np.ndarray = t[k.T_F]
        self._S: np.ndarray = t[k.T_S]
        self._remote: np.ndarray = t[k.T_REMOTE]
        self.force: np.ndarray = t[k.T_FORCE]
        self.bound = _Ledger(side, t, k)
        self._last: Any = None
        self.q = np.zeros(plant.n)
        self.qd = np.zeros(plant.n)
        self.plant = plant
        self.wrench: np.ndarray = t[k.T_WRENCH]
        self._run = k.side_tick
        self._begun = False
        self.torque(np.zeros(3), np.zeros(3), None, dry=True)  # compile (or load) now, not in the loop

    @property
    def limit(self) -> float:
        return float(self._F[self.k.F_LIMIT])

    @limit.setter
    def limit(self, value: float) -> None:
        self._F[self.k.F_LIMIT] = value

    @property
    def ratio(self) -> float:
        return float(self._S[self.k.S_RATIO])

    @property
    def rendered(self) -> np.ndarray:
        """`SideTick.rendered`: the task force the applied torque renders (ratio x desired, or with
        TDPA's velocity controller the task force of the applied torque), a copy."""
        return np.array(self.w[self.k.W_FELT])

    @property
    def limited_ticks(self) -> int:
        return int(self._S[self.k.S_LIMITED])

    def torque(self, x: np.ndarray, v: np.ndarray, remote: tuple[float, ...] | None, dry: bool = False) -> np.ndarray:
        """The side's torque (SideTick.torque) on the newest accepted remote sample (None: none yet).
        `dry`: only compile, on a copy of the state (the side is left as it was)."""
        if remote is not None and remote is not self._last:
            self._remote[: len(remote)] = remote
            self._S[self.k.S_HAS_REMOTE] = 1.0
            self._last = remote
        out = np.zeros(len(self.q))
        if dry:
            k = self.k
            t = tuple(np.array(a) if i >= k.T_S else a for i, a in enumerate(self.t))
            self._run(t, self.w, np.zeros_like(self.q), np.zeros_like(self.qd), x, v, out)
            k.side_law(t, self.w, np.zeros_like(self.q), np.zeros_like(self.qd), x, v, out)
            k.side_begin(t, self.w, np.zeros_like(self.q), np.zeros_like(self.qd), np.zeros(3), np.zeros(3))
            from numba import typeof  # side_end steps the plant: compiled (or loaded), not run

            k.side_end.compile(tuple(typeof(a) for a in (self.t, self.w, out, np.zeros(3), out)))
            return out
        if self._begun:
            self.k.side_law(self.t, self.w, self.q, self.qd, x, v, out)
            return out
        self._run(self.t, self.w, self.q, self.qd, x, v, out)
        return out

    def read_point(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The plant's `read` and `point` compiled (mj_step1, q, qd, the point's x, v in the world
        frame); then `torque` and `step` finish the tick. Copies."""
        x, v = np.zeros(3), np.zeros(3)
        self.k.side_begin(self.t, self.w, self.q, self.qd, x, v)
        self._begun = True
        return self.q.copy(), self.qd.copy(), x, v

    def step(self, tau: np.ndarray, hand_force_n: np.ndarray | None = None) -> np.ndarray:
        """The plant's `step` compiled, after `read_point` and `torque`; returns the torques applied.
        The plant is told (`stepped_externally`): its `contact_wrench` is this step's."""
        assert self._begun, "step after read_point"
        applied = np.zeros(len(self.q))
        hand = np.zeros(3) if hand_force_n is None else np.asarray(hand_force_n, dtype=float)
        self.k.side_end(self.t, self.w, np.asarray(tau, dtype=float), hand, applied)
        self._begun = False
        self.plant.stepped_externally(self.wrench)
        return applied


def side_tick(side: ArmSide, parts: ArmParts, master: bool, fallback: Any) -> tuple[Any, str | None]:
    """The compiled tick of one side (`CompiledSideTick`), or `fallback` (the Python SideTick) and
    the reason it is not compiled."""
    reason = compiled_reason_side(side)
    if reason is not None:
        return fallback, reason
    return CompiledSideTick(side, parts, master), None


def warm(config: Scene) -> str | None:
    """Compile the side tick the live arm nodes run (or load it from numba's cache) in this
    process, before the nodes start: cold, it takes tens of seconds, which a node compiling it at
    start-up would spend while the others wait for it (past `start.timeout_s` on a fresh install).
    A scene with a real arm on one side: its simulated side's node runs the compiled tick, whose
    types are those of any MuJoCo arm, so it is built from the scene with that side simulated too
    (the real arm's driver is never made, nothing is opened). None once built, else why it was not."""
    if not config.is_arm:
        return "not an arm scene"
    roles = ("master", "slave")
    simulated = [r for r in roles if getattr(config, r).backend == "mujoco"]
    if not simulated:
        return "no simulated side (a real arm's side runs the Python tick)"
    why = side_unusable()
    if why is not None:
        return why
    import dataclasses

    from haptic_teleop.assembly.parts import build_arm_parts

    if len(simulated) < len(roles):
        twins = {r: dataclasses.replace(getattr(config, r), backend="mujoco") for r in roles if r not in simulated}
        config = dataclasses.replace(config, **twins)
    parts = build_arm_parts(config)
    k = side_kernel()
    with compiling.first_compile(k.side_tick):
        for master in (True, False):
            side = parts.master if master else parts.slave
            if compiled_reason_side(side) is None:
                CompiledSideTick(side, parts, master)
    return None


def warm_saying(config: Scene, say: Callable[[str], None]) -> str | None:
    """`warm`, telling `say` when numba really compiles (not when it loads its cache): which
    loop, why and about how long (`compiling.compile_message`). `haptic-teleop launch` and the
    ROS 2 launch files call it before any node starts."""
    compiling.compile_notice = lambda module: say(compiling.compile_message(module))
    try:
        return warm(config)
    finally:
        compiling.compile_notice = None
