"""The engine's compiled loop: the same tick as `Engine._loop`, compiled with numba.

A tick of the Python loop costs 20 to 50 us on this project's 2-vCPU machine, of which MuJoCo is
5 to 9 us; the rest is the interpreter (docs/performance.md). This module runs the same tick in
machine code: the one-axis law and bound of `core` (`eba.command1`, `bound1`: what
`TeleopController.step1` and `EnergyBound.step1` call; `tdpa.tdpa1` and `wave.wave1`, what
`TdpaBound` and `WaveSide` call, for the two other stabilizers), `within1/2/3`, `operator.push1`,
`sinusoid1`, `hand1`, `imposed_force1`, `plants.actuator_limited1`
are compiled by numba from their single definition, and MuJoCo's `mj_step` is called straight
from the compiled code on the same `MjModel`/`MjData` the plants own.

The network is decided ahead of the loop, window by window, because nothing a link or a playout
buffer decides depends on what a packet carries (fates and arrival times depend on send times,
sizes and the effects' own random streams; buffers release by sequence number and arrival time).
Per direction and window of ticks the schedule is: which sequence number the buffer releases at
each tick (or none) and the buffer's occupancy; the packets' records are handed over as their
fates become final. It is computed either
- vectorized (`VectorizedSchedule`, `Link.schedule_all` on each window: the random streams go
  on where the last window left them), when every effect has a vectorized form and the buffer
  plays on arrival and holds: constant delay, uncorrelated loss, blackouts, Gilbert-Elliott and
  4-state loss (their chains run compiled over the window: link_runs.py), policy `none`; or
- by the very `Link` and `PlayoutBuffer` objects the Python loop uses, ticked in the same order
  with empty payloads (`TickedSchedule`: any other effect chain or policy).
The loop then looks the released sample up in the sender's history, a ring of the last ticks'
samples as deep as the oldest released sample needs. No array grows with the run's duration.
The result is the same columns and packet records, bit for bit, as the Python loop
(test_compiled_loop.py), and the same bag.

A direction with a codec (deadband, prediction, FEC, ARQ) cannot be decided ahead: which packets exist
depends on the samples. Its network runs inside the kernel instead (engine/compiled/codec_host.py,
engine/compiled/codec_kernel.py), for links whose effects give a packet its fate from its index and send
time alone; a direction without a codec keeps its schedule.

Not compiled (the Python loop runs instead, `compiled_reason` says why): plant effects, hardware
backends, operator traces, payload-changing effects (corruption), extrapolating buffers, the
two-condition energy bound (`controllers.<side>.eba.law`; reservoir, TDPA and wave variables
are compiled), other
codecs or codec links (`codec_host.codec_reason`), and machines without numba. Arm scenes
(more than one axis) have their own compiled loop,
`haptic_teleop/engine/compiled/arm_host.py`, which reuses this module's network schedule; it does not take arm
plants with effects or another backend, the force law, an operator trace, corruption or
extrapolating buffers either.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_teleop import compiling
from haptic_teleop.assembly.stages import settled_records
from haptic_teleop.core.delay import Delay, TokenBucket
from haptic_teleop.core.eba_state import AxisBoundState
from haptic_teleop.core.link import DELIVERED, Link, Packet
from haptic_teleop.core.playout import PlayOnArrival, PlayoutBuffer
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
    P_LIM3,
    P_LIMIT,
    P_MASS,
    P_PERIOD_S,
    P_PLANT_LIMIT,
    P_PROFILE,
    P_REFLECT,
    P_SIZE,
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
    PROFILE_CODES,
    S_CONTACT,
    S_ENERGY,
    S_HAS_LAST,
    S_HAS_REMOTE,
    S_HELD,
    S_LAST,
    S_R0,
    S_R3,
    S_REJECTED,
    S_SIZE,
    S_X0,
    SLAVE,
)
from haptic_teleop.engine.compiled.records import packet_rows

if TYPE_CHECKING:
    from haptic_teleop.assembly.parts import AxisParts


# The stabilizers (`controllers.<side>.eba.law`) the compiled 1-DoF loop runs.
COMPILED_LAWS = ("reservoir", "two_condition", "tdpa", "wave")


def law_code(ctrl: Any) -> float:
    """A side's stabilizer as the kernel's code (layout.LAW_*)."""
    b = ctrl.bound
    if b.params.law == "wave":
        return LAW_WAVE
    if b.params.law == "tdpa":
        return LAW_TDPA_ZOH if b.params.tdpa_controller == "zoh" else LAW_TDPA_VELOCITY
    if b.params.law == "two_condition":
        return LAW_TWO_CONDITION
    return LAW_RESERVOIR


def ring_widths(parts: AxisParts) -> tuple[int, int]:
    """The values of one forward and one backward sample (the rings' widths): (x, v) and
    (f_env, x, v); with TDPA the sender's energy after them."""
    return (3, 4) if parts.master_ctrl.tdpa is not None else (2, 3)


@functools.cache
def _kernel_or_error() -> tuple[Callable[..., int] | None, str | None]:
    try:
        axis_kernel = compiling.load("haptic_teleop.engine.compiled.axis_kernel")
    except Exception as exc:  # noqa: BLE001 - no numba, or it cannot load here: the Python loop runs
        return None, f"numba unavailable or failing ({type(exc).__name__}: {exc})"
    return axis_kernel.run_ticks, None


@functools.cache
def _codec_kernel_or_error() -> tuple[Callable[..., int] | None, str | None]:
    try:
        codec_kernel = compiling.load("haptic_teleop.engine.compiled.codec_kernel")
    except Exception as exc:  # noqa: BLE001 - as `_kernel_or_error`
        return None, f"the codec kernel cannot load ({type(exc).__name__}: {exc})"
    return codec_kernel.run_ticks_codec, None


def codec_kernel() -> Callable[..., int] | None:
    """The compiled tick loop with the codec stage (engine/compiled/codec_kernel.py), loaded only for a
    scene with a codec; None if it cannot load."""
    return _codec_kernel_or_error()[0]


def codec_kernel_error() -> str | None:
    """Why there is no compiled codec loop on this machine, or None."""
    return _codec_kernel_or_error()[1]


def kernel() -> Callable[..., int] | None:
    """The compiled tick loop, built (or loaded from numba's cache) on first use; None without numba."""
    return _kernel_or_error()[0]


def kernel_error() -> str | None:
    """Why there is no compiled loop on this machine, or None."""
    return _kernel_or_error()[1]


# --------------------------------------------------------------------------------------------
# What can be compiled.


def compiled_reason(parts: AxisParts) -> str | None:
    """Why the scene's parts cannot run in the compiled loop, or None if it can."""
    codecs = parts.codecs
    if codecs != (None, None):
        from haptic_teleop.engine.compiled.codec_host import codec_reason

        for ch in codecs:
            why = None if ch is None else codec_reason(ch)
            if why is not None:
                return why
    from haptic_teleop.plants.mujoco_plant import MujocoDevice, MujocoWallRobot

    if type(parts.master) is not MujocoDevice or type(parts.slave) is not MujocoWallRobot:
        return "plant effects or a non-MuJoCo backend (only the bare MuJoCo plants are compiled)"
    if not hasattr(parts.master.model, "_address"):  # type: ignore[attr-defined]
        return "this mujoco's bindings do not expose model addresses (MjModel._address)"
    if parts.master_ctrl.bound.params.axes != 1 or parts.slave_ctrl.bound.params.axes != 1:
        return "more than one axis"
    for side, ctrl in (("master", parts.master_ctrl), ("slave", parts.slave_ctrl)):
        law = ctrl.bound.params.law
        if law not in COMPILED_LAWS:
            return (
                f"energy bound law {law} on the {side} side runs in the Python loop only (compiled laws: "
                f"{', '.join(COMPILED_LAWS)})"
            )
    profile = parts.operator.constants().profile
    if profile not in PROFILE_CODES:
        return f"operator profile {profile!r} (compiled: {', '.join(PROFILE_CODES)})"
    for name, link, buf in (
        ("forward", parts.forward, parts.forward_buffer),
        ("backward", parts.backward, parts.backward_buffer),
    ):
        if any(e.name == "corrupt" for e in link.effects):
            return f"{name} link corrupts payloads (the schedule must not depend on what packets carry)"
        if buf.extrapolates:
            return f"{name} buffer extrapolates payloads"
    if codecs != (None, None):
        return kernel_error() or codec_kernel_error()
    return kernel_error()


# --------------------------------------------------------------------------------------------
# The network schedule, window by window.


def _vectorized(link: Link, buf: PlayoutBuffer) -> bool:
    # (a jittered delay may reorder packets, and it or a rate limit's burst bring two in a tick:
    # BufferedSchedule runs them)
    return (
        link.vectorized
        and type(buf) is PlayOnArrival
        and not buf.extrapolates
        and not any(type(e) in (Delay, TokenBucket) for e in link.effects)
    )


def _seq(p: Packet) -> int:
    return p.seq


class TickedSchedule:
    """One direction's decisions, made by the very `Link` and `PlayoutBuffer` objects the Python
    loop uses, ticked in the same order with empty payloads (any effect chain or policy)."""

    vectorized = False

    def __init__(self, link: Link, buf: PlayoutBuffer, period_ns: int, size_bytes: int) -> None:
        self.link, self.buf, self.period_ns, self.size_bytes = link, buf, period_ns, size_bytes

    def window(self, n0: int, n1: int) -> tuple[np.ndarray, np.ndarray]:
        """For ticks [n0, n1) (following the last window): the seq the buffer releases at each
        tick (-1: none) and its occupancy after the release."""
        released = np.full(n1 - n0, -1, dtype=np.int64)
        occupancy = np.zeros(n1 - n0)
        link, buf, period, size = self.link, self.buf, self.period_ns, self.size_bytes
        send_one, deliver, push, release = link.send, link.deliver, buf.push, buf.release
        empty: tuple[float, ...] = ()
        for n in range(n0, n1):
            now = n * period
            send_one(Packet(n, now, empty, size))
            for p in deliver(now):
                push(p, now)
            rel = release(now)
            if rel is not None:
                released[n - n0] = rel.seq
            occupancy[n - n0] = buf.occupancy
        return released, occupancy

    def settled(self, sent: int, final: bool) -> np.ndarray | None:
        """`settled_records` of this direction (the schedule has reached `sent`)."""
        return settled_records(self.link, self.buf, sent, final)


class VectorizedSchedule:
    """One direction's decisions in numpy (`Link.schedule_all`), when every effect has a vectorized
    form and the buffer plays on arrival and holds: constant delay, uncorrelated loss, blackouts,
    policy `none`. Fates are decided at send time; a delivered packet arrives at the first tick
    at or after its arrival time and is released in that tick. That is exact only if no tick gets
    two packets and arrivals keep send order (else the buffer would mark some late): checked,
    never assumed. Packets still on their way at a window's end are carried to the next."""

    vectorized = True

    def __init__(self, link: Link, period_ns: int, size_bytes: int) -> None:
        self.link, self.period_ns, self.size_bytes = link, period_ns, size_bytes
        self.runs = link_runs()
        # Delivered packets whose records are not handed over yet: arrival tick and seq, both
        # ascending (the check in `window`).
        self._tick = np.zeros(0, dtype=np.int64)
        self._seq = np.zeros(0, dtype=np.int64)
        self._rows: list[np.ndarray] = []  # records not handed over yet, in seq order
        self._first = 0  # seq of the first of them

    def window(self, n0: int, n1: int) -> tuple[np.ndarray, np.ndarray]:
        """As `TickedSchedule.window`."""
        period = self.period_ns
        send = np.arange(n0, n1, dtype=np.int64) * period
        arrival, fate = self.link.schedule_all(send, self.runs, self.size_bytes)
        got = np.flatnonzero(fate == DELIVERED)
        tick_of = -(-arrival[got] // period)
        if len(tick_of) and (
            (len(self._tick) and tick_of[0] <= self._tick[-1]) or not bool(np.all(np.diff(tick_of) > 0))
        ):
            raise AssertionError("a vectorized link delivered two packets in one tick")  # constant delay cannot
        self._rows.append(packet_rows(send, arrival, fate, self.size_bytes, first_seq=n0))
        self._tick = np.concatenate((self._tick, tick_of))
        self._seq = np.concatenate((self._seq, got + n0))
        a, b = np.searchsorted(self._tick, (n0, n1))
        released = np.full(n1 - n0, -1, dtype=np.int64)
        released[self._tick[a:b] - n0] = self._seq[a:b]
        return released, np.zeros(n1 - n0)

    def settled(self, sent: int, final: bool) -> np.ndarray | None:
        """As `settled_records`, once the loop has run the ticks before `sent` (a window may reach
        further): the records of packets older than the oldest one sent before `sent` and still on
        its way then (none is ever held: the buffer releases an arrival in its tick)."""
        mark = sent
        if not final:
            i = int(np.searchsorted(self._tick, sent))  # the first to arrive at `sent` or later
            if i < len(self._seq) and self._seq[i] < mark:
                mark = int(self._seq[i])
        k = mark - self._first
        if k <= 0:
            return None
        keep = int(np.searchsorted(self._seq, mark))
        self._tick, self._seq = self._tick[keep:], self._seq[keep:]
        rows = self._rows[0] if len(self._rows) == 1 else np.concatenate(self._rows)
        self._rows = [rows[k:]]
        self._first = mark
        return rows[:k]


def link_runs() -> dict[str, Any] | None:
    """The Markov loss chains' runs compiled (engine/compiled/link_runs.py), or None without numba
    (`Link.schedule_all` then runs core/loss.py's plain functions: the same decisions, slower)."""
    try:
        from haptic_teleop.engine.compiled import link_runs as lr
    except ImportError:
        return None
    return lr.RUNS


def schedule(link: Link, buf: PlayoutBuffer, period_ns: int, size_bytes: int) -> Any:
    """The decisions of `link` and `buf`, one packet per tick, window by window (module docstring):
    a `VectorizedSchedule`, a `BufferedSchedule` or a `TickedSchedule`."""
    if _vectorized(link, buf):
        return VectorizedSchedule(link, period_ns, size_bytes)
    from haptic_teleop.engine.compiled.buffer_schedule import BufferedSchedule, buffered

    if buffered(link, buf):
        return BufferedSchedule(link, buf, period_ns, size_bytes, link_runs())  # type: ignore[arg-type]
    return TickedSchedule(link, buf, period_ns, size_bytes)


def parameters(parts: AxisParts, period_s: float) -> np.ndarray:
    """The parameter vector P of a scene's parts (layout at the top of this module)."""
    P = np.zeros(P_SIZE)
    for side, ctrl, plant in ((MASTER, parts.master_ctrl, parts.master), (SLAVE, parts.slave_ctrl, parts.slave)):
        p = ctrl.params
        b = ctrl.bound
        P[side + P_FORCE_LAW] = 1.0 if p.law == "force" else 0.0
        P[side + P_GAIN] = p.force_gain
        P[side + P_C1] = p.stiffness_n_per_m
        P[side + P_C2] = p.damping_n_s_per_m
        P[side + P_LIMIT] = p.force_limit_n
        P[side + P_EBA_GAIN] = b.params.reservoir_gains()[0]
        P[side + P_BOUND_GAIN] = b.params.bound_gains()[0]
        P[side + P_EBA_ON] = 1.0 if b.params.enabled else 0.0
        P[side + P_ACT_LIMIT], P[side + P_SLEW_STEP] = b.params.actuator_limits()
        guard = ctrl.guard
        if guard is not None:
            P[side + P_GUARD_ON] = 1.0
            for i, lim in enumerate(guard.limits):
                P[side + (P_LIM0 + i if i < 3 else P_LIM3)] = lim
        P[side + P_PLANT_LIMIT] = plant.force_limit_n  # type: ignore[attr-defined]
        P[side + P_SUBSTEPS] = plant.substeps  # type: ignore[attr-defined]
        P[side + P_LAW] = law_code(ctrl)
        P[side + P_E0] = b.params.initial_energy_j
        P[side + P_REFLECT] = b.params.tdpa_reflection
        if ctrl.tdpa is not None:
            P[side + P_CAP] = ctrl.tdpa.cap_n
            P[side + P_TDPA_ADMIT] = 1.0 if ctrl.tdpa.admittance else 0.0
            P[side + P_TDPA_RECOVER] = ctrl.tdpa.recover
        if ctrl.wave is not None:
            w = ctrl.wave.wave
            P[side + P_CAP] = min(p.force_limit_n, ctrl.wave.clip_n)
            P[side + P_WAVE_B] = w.impedance_n_s_per_m
            P[side + P_WAVE_S] = ctrl.wave.s
            P[side + P_WAVE_A] = ctrl.wave.pole
            P[side + P_DRIFT] = w.drift_gain_per_s
            P[side + P_WAVE_MATCHED] = 1.0 if w.matched and not ctrl.wave.master else 0.0
    o = parts.operator
    oc = o.constants()
    P[OP + P_PROFILE] = PROFILE_CODES[oc.profile]
    P[OP + P_X0] = oc.x0_m
    P[OP + P_K] = oc.stiffness_n_per_m
    P[OP + P_B] = oc.damping_n_s_per_m
    P[OP + P_START] = oc.start_s
    P[OP + P_SPEED] = oc.speed_m_per_s
    P[OP + P_T_END] = oc.t_end_s
    P[OP + P_X_END] = oc.x_end_m
    P[OP + P_AMP] = o.params.amplitude_m
    P[OP + P_W] = 2.0 * np.pi * o.params.frequency_hz if oc.profile == "sinusoid" else 0.0
    if oc.profile == "imposed":
        P[OP + P_MASS] = parts.master.inertia_kg()  # type: ignore[attr-defined]
        P[OP + P_DAMP] = parts.master.joint_damping()[0]
    P[P_PERIOD_S] = period_s
    return P


def initial_state(parts: AxisParts) -> np.ndarray:
    """The state vector S of a scene's parts's controllers and slave plant as they are now."""
    S = np.zeros(S_SIZE)
    for side, ctrl in ((MASTER, parts.master_ctrl), (SLAVE, parts.slave_ctrl)):
        b = ctrl.bound.axis_state()
        S[side + S_ENERGY] = b.energy_j
        S[side + S_HELD] = b.held_n
        S[side + S_LAST] = b.last_x_m
        S[side + S_HAS_LAST] = 1.0 if b.has_last else 0.0
        for i, value in enumerate(b.extra):
            S[side + S_X0 + i] = value
        r = ctrl.remote
        if r is not None:
            S[side + S_HAS_REMOTE] = 1.0
            for i, value in enumerate(r):
                S[side + (S_R0 + i if i < 3 else S_R3)] = value
    S[SLAVE + S_CONTACT] = parts.slave.contact_force()[0]
    return S


def store_state(parts: AxisParts, S: np.ndarray) -> None:
    """Write the compiled loop's state back into the parts' Python objects (energies, counts, remote)."""
    widths = ring_widths(parts)
    for side, ctrl, width in ((MASTER, parts.master_ctrl, widths[1]), (SLAVE, parts.slave_ctrl, widths[0])):
        n_extra = len(ctrl.bound.axis_state().extra)
        ctrl.bound.set_axis_state(
            AxisBoundState(
                energy_j=float(S[side + S_ENERGY]),
                held_n=float(S[side + S_HELD]),
                last_x_m=float(S[side + S_LAST]),
                has_last=bool(S[side + S_HAS_LAST]),
                extra=tuple(float(S[side + S_X0 + i]) for i in range(n_extra)),
            )
        )
        n_remote = 2 if ctrl.wave is not None else width  # a wave sample: (the wave, the sender's position)
        if S[side + S_HAS_REMOTE]:
            ctrl.remote = tuple(float(S[side + (S_R0 + i if i < 3 else S_R3)]) for i in range(n_remote))
        if ctrl.guard is not None:
            ctrl.guard.rejected = int(S[side + S_REJECTED])
    parts.slave.set_contact_force(float(S[SLAVE + S_CONTACT]))  # type: ignore[attr-defined]


def model_addresses(parts: AxisParts) -> np.ndarray:
    m: Any = parts.master
    s: Any = parts.slave
    return np.array([m.model._address, m.data._address, s.model._address, s.data._address], dtype=np.int64)


class Rings:
    """The sent payloads of both directions: rings indexed by seq (a power of two deep), deep
    enough for the oldest payload a window releases; grown (keeping what they hold) if a window
    needs more. Their size follows the network's delay, never the run's length."""

    def __init__(self, widths: tuple[int, int], depth: int = 1024) -> None:
        self.fwd = np.zeros((depth, widths[0]))
        self.bwd = np.zeros((depth, widths[1]))

    def fit(self, frel: np.ndarray, brel: np.ndarray, w0: int, w1: int) -> None:
        oldest = w0
        for rel in (frel, brel):
            got = rel[rel >= 0]
            if len(got):
                oldest = min(oldest, int(got.min()))
        need = w1 - oldest
        depth = self.fwd.shape[0]
        if need <= depth:
            return
        new = depth
        while new < need:
            new *= 2
        seqs = np.arange(max(0, w0 - depth), w0)  # what the rings hold: the ticks before w0
        for name in ("fwd", "bwd"):
            old = getattr(self, name)
            grown = np.zeros((new, old.shape[1]))
            grown[seqs & (new - 1)] = old[seqs & (depth - 1)]
            setattr(self, name, grown)
