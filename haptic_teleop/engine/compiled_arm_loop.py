"""The compiled loop for arm scenes: the same tick as the Python arm loop (`arm_loop.py`), in numba.

The tick (docs/performance.md, "Arm scenes") calls MuJoCo from compiled code on the plants' own
`MjModel`/`MjData`: `mj_step1` (positions, velocities, kinematics, gravity torques, collisions),
`mj_jacSite` (the handle's or tool's Jacobian), `mj_step2` (actuation, constraints, integration;
the split step gives the bits of `mj_step` for the Euler and implicit integrators), and
`mj_contactForce` for the wall's force on the tool. The contact array is read in place: its
address and count are fields of mjData, whose offsets (and mjContact's) are laid out by C's rules
from `mujoco.introspect`, MuJoCo's description of its headers, and checked against what the
bindings read on a probe model before use (`contact_layout`). The
task-space law, J^T F, the null-space damping, the pooled joint bound and the operator are the
functions of `core` compiled from their one definition (`arm_kernel.compile_tree`).

The network is the 1-DoF loop's: `compiled_loop.schedule` decides, window by window, which sequence
number each buffer releases at each tick (nothing it decides depends on what packets carry); the
loop looks the released payload up in the sender's ring of recent payloads.
"""

from __future__ import annotations

import ctypes
import functools
import importlib
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_teleop.core.eba import CoupledBoundState

if TYPE_CHECKING:
    from haptic_teleop.assembly import ArmParts, ArmSide

PROFILE_CODES = {"push": 0, "sinusoid": 1, "hold": 2}


# The sources the compiled arm loop is built from. numba's cache of a function checks only its
# own file's time stamp, and the loop holds compiled copies of core's functions: when any of these
# files changed since the cache was written, the cache of arm_kernel is dropped first.
_SOURCES = ("arm_kernel.py", "axis_kernel.py", "../core/eba.py", "../core/taskspace.py", "../core/operator.py")


def _drop_stale_cache(caches: tuple[tuple[str, tuple[str, ...]], ...] = (("arm_kernel", _SOURCES),)) -> None:
    """Drop the numba cache of each (kernel, its sources) of `caches` that is stale
    (compiled_loop.drop_stale_cache)."""
    from haptic_teleop.engine.compiled_loop import drop_stale_cache

    for kernel, sources in caches:
        drop_stale_cache(kernel, sources)


def _load(module: str, caches: tuple[tuple[str, tuple[str, ...]], ...], failing: str) -> tuple[Any, str | None]:
    """engine/<module>, imported after `_drop_stale_cache(caches)`; or None and why (`failing`:
    what failed)."""
    try:
        _drop_stale_cache(caches)
        return importlib.import_module(f"haptic_teleop.engine.{module}"), None
    except Exception as exc:  # noqa: BLE001 - no numba, or it cannot load here: the Python loop runs
        return None, f"{failing} ({type(exc).__name__}: {exc})"


@functools.cache
def _kernel_or_error() -> tuple[Any, str | None]:
    return _load("arm_kernel", (("arm_kernel", _SOURCES),), "numba unavailable or failing")


def kernel() -> Any:
    """The compiled arm kernel module, or None without numba."""
    return _kernel_or_error()[0]


def kernel_error() -> str | None:
    return _kernel_or_error()[1]


# The arm loop with the codec stage (engine/arm_codec_kernel.py): its own module and cache, loaded
# only when an arm scene with a codec runs compiled.
_CODEC_SOURCES = (
    "arm_codec_kernel.py",
    *_SOURCES,
    "codec_kernel.py",
    "codec_layout.py",
    "../core/deadband.py",
    "../core/prediction.py",
    "../core/loss.py",
    "../core/fec.py",
    "../core/hli_codec.py",
)


@functools.cache
def _codec_kernel_or_error() -> tuple[Any, str | None]:
    err = kernel_error()
    if err is not None:
        return None, err
    from haptic_teleop.engine.compiled_loop import CODEC_SOURCES

    # the 1-DoF codec kernel's cache as its own loader checks it: the arm's compiles its functions
    return _load(
        "arm_codec_kernel",
        (("codec_kernel", CODEC_SOURCES), ("arm_codec_kernel", _CODEC_SOURCES)),
        "the arm codec kernel cannot load",
    )


def codec_kernel() -> Any:
    """The compiled arm loop with the codec stage (module engine/arm_codec_kernel), or None."""
    return _codec_kernel_or_error()[0]


def codec_kernel_error() -> str | None:
    """Why the arm loop with the codec stage cannot load here, or None."""
    return _codec_kernel_or_error()[1]


# --------------------------------------------------------------------------------------------
# mjData's contact array, read from compiled code.


_PRIMITIVES = {
    "char": 1, "unsigned char": 1, "mjtByte": 1, "mjtBool": 1, "int": 4, "unsigned int": 4, "float": 4,
    "double": 8, "mjtNum": 8, "size_t": 8, "mjtSize": 8, "uintptr_t": 8, "uint64_t": 8, "int64_t": 8,
}  # fmt: skip


def _c_size_align(t: Any) -> tuple[int, int]:
    """sizeof and alignof of a mujoco.introspect type on this (64-bit) machine."""
    from mujoco.introspect import structs

    kind = type(t).__name__
    if kind == "PointerType":
        return 8, 8
    if kind == "ArrayType":
        size, align = _c_size_align(t.inner_type)
        for n in t.extents:
            size *= n
        return size, align
    name = t.name
    if name in _PRIMITIVES:
        return _PRIMITIVES[name], _PRIMITIVES[name]
    if name in structs.STRUCTS:
        return _c_struct(name)[0:2]  # type: ignore[return-value]
    raise KeyError(name)


def _c_struct(name: str) -> tuple[int, int, dict[str, int]]:
    """sizeof, alignof and the field offsets of a MuJoCo struct, laid out by C's rules from the
    field list of `mujoco.introspect` (MuJoCo's own description of its headers)."""
    from mujoco.introspect import structs

    offset, align, fields = 0, 1, {}
    for f in structs.STRUCTS[name].fields:
        size, a = _c_size_align(f.type)
        offset = -(-offset // a) * a
        fields[f.name] = offset
        offset += size
        align = max(align, a)
    return -(-offset // align) * align, align, fields


@functools.cache
def kernel_unusable() -> str | None:
    """Why the arm kernel cannot run on this machine (no numba, or an mjData contact layout it
    does not know), or None."""
    err = kernel_error()
    if err is not None:
        return err
    layout = contact_layout()
    return layout if isinstance(layout, str) else None


def contact_layout() -> tuple[int, int, int, int, int, int, int, int] | str:
    """(ncon offset in mjData, contact-pointer offset in mjData, mjContact stride, and the offsets
    in mjContact of pos, frame, geom[0], geom[1], efc_address); or why not (then arm scenes run in
    the Python loop).

    The offsets come from the layout of MuJoCo's structs by C's rules (`_c_struct`, from
    `mujoco.introspect`), and are used only if they read what the bindings read on a probe model
    with one contact: `ncon`, the contact array's address, and its first record's geoms, efc
    address and position (each field read from memory inside the struct, never beyond it)."""
    import mujoco

    try:
        data_size, _, data_fields = _c_struct("mjData")
        stride, _, contact_fields = _c_struct("mjContact")
        layout = (
            data_fields["ncon"],
            data_fields["contact"],
            stride,
            contact_fields["pos"],
            contact_fields["frame"],
            contact_fields["geom"],
            contact_fields["geom"] + 4,
            contact_fields["efc_address"],
        )
    except (ImportError, KeyError, AttributeError) as exc:
        return f"cannot lay out mjData from mujoco.introspect ({type(exc).__name__}: {exc})"
    xml = """<mujoco><worldbody><geom name="floor" type="plane" size="1 1 .1"/>
      <body pos="0 0 0.05"><freejoint/><geom name="ball" type="sphere" size="0.1" mass="1"/></body>
      </worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    if not hasattr(d, "_address"):
        return "this mujoco's bindings do not expose MjData._address"
    mujoco.mj_forward(m, d)
    if d.ncon != 1:
        return f"probe model: expected one contact, got {d.ncon}"
    c = d.contact
    base = int(c.dist.__array_interface__["data"][0])
    if not (layout[0] >= 0 and layout[1] + 8 <= data_size and c.dist.strides[0] == stride):
        return "mjData's layout from mujoco.introspect does not match the bindings (mjContact's size)"
    read = ctypes.c_int32.from_address(d._address + layout[0]).value
    ptr = ctypes.c_uint64.from_address(d._address + layout[1]).value
    if read != d.ncon or ptr != base:
        return "mjData's layout from mujoco.introspect does not read ncon and contact as the bindings do"
    pos = np.frombuffer((ctypes.c_double * 3).from_address(ptr + layout[3]), dtype=np.float64)
    frame = np.frombuffer((ctypes.c_double * 9).from_address(ptr + layout[4]), dtype=np.float64)
    g = ctypes.c_int32.from_address(ptr + layout[5]).value, ctypes.c_int32.from_address(ptr + layout[6]).value
    efc = ctypes.c_int32.from_address(ptr + layout[7]).value
    if not (
        np.array_equal(pos, c.pos[0])
        and np.array_equal(frame, c.frame[0])
        and g == tuple(c.geom[0])
        and efc == c.efc_address[0]
    ):
        return "mjContact's layout from mujoco.introspect does not read what the bindings read"
    return layout


# --------------------------------------------------------------------------------------------
# What can be compiled, and the arrays the kernel takes.


def compiled_reason_arm(
    parts: ArmParts, forward: Any, backward: Any, fbuf: Any, bbuf: Any, period_s: float | None = None
) -> str | None:
    """Why the arm scene cannot run in the compiled loop, or None if it can. `period_s`: the
    scene's period (a side whose bound runs at another period ticks in the Python loop only)."""
    from haptic_teleop.plants.arm import MujocoArm
    from haptic_teleop.plants.hardware_arm import HardwareArm

    for role, side in (("master", parts.master), ("slave", parts.slave)):
        p = side.bound.params.period_s
        if period_s is not None and abs(p - period_s) > 1e-12:
            return f"{role}: its own period {p:g} s (the compiled loop ticks both sides every {period_s:g} s)"
        if isinstance(side.plant, HardwareArm):
            return f"{role}: a real device (its driver is read and written from Python, once per tick)"
        if type(side.plant) is not MujocoArm:
            return f"{role}: plant effects or a non-MuJoCo backend (only the bare MuJoCo arms are compiled)"
        if side.law.params.law != "position":
            return f"{role}: task law {side.law.params.law!r} (compiled: position)"
    profile = parts.operator.constants().profile
    if profile not in PROFILE_CODES:
        return f"operator profile {profile!r} (compiled: {', '.join(PROFILE_CODES)})"
    for name, link, buf in (("forward", forward, fbuf), ("backward", backward, bbuf)):
        if any(e.name == "corrupt" for e in link.effects):
            return f"{name} link corrupts payloads (the schedule must not depend on what packets carry)"
        if buf.extrapolates:
            return f"{name} buffer extrapolates payloads"
    return kernel_unusable()


def side_tuple(side: ArmSide, parts: ArmParts, master: bool, data: Any = None) -> tuple[Any, ...]:
    """The kernel's side tuple (arm_kernel's T_* order) of one side, sharing the plant's MjData
    arrays (or those of `data`, another MjData of the same model), with the constants and a copy
    of the state the side's objects give through their public seams (`constants()`, `state()`):
    `store_side` writes the state back (`set_state`, `stepped_externally`)."""
    from haptic_teleop.engine import arm_kernel as k

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
    mp = parts.mapping
    F = np.zeros(k.F_SIZE)
    F[k.F_LIMIT] = side.force_limit_n
    F[k.F_MU] = law.params.pinv_damping_m
    F[k.F_SCALE] = mp.scale
    F[k.F_FORCE_SCALE] = mp.force_scale
    opp = parts.operator.params
    F[k.F_K_HAND] = opp.stiffness_n_per_m
    F[k.F_B_HAND] = opp.damping_n_s_per_m
    S = np.zeros(k.S_SIZE)
    S[k.S_ENERGY] = bs.energy_j
    S[k.S_HAS_LAST] = 1.0 if bs.has_last else 0.0
    S[k.S_REJECTED] = side.guard.rejected
    S[k.S_SCALE] = bs.scale
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
    from haptic_teleop.engine import arm_kernel as k

    S = t[k.T_S]
    side.bound.set_state(
        CoupledBoundState(
            energy_j=float(S[k.S_ENERGY]),
            held_nm=t[k.T_HELD],
            last_q_rad=t[k.T_LAST_Q],
            has_last=bool(S[k.S_HAS_LAST]),
            scale=float(S[k.S_SCALE]),
        )
    )
    side.guard.rejected = int(S[k.S_REJECTED])
    if S[k.S_HAS_HOLD]:
        side.law.r_hold = np.array(t[k.T_RHOLD])
    side.plant.stepped_externally(t[k.T_WRENCH])  # type: ignore[attr-defined]  # mj_step1 is due
    return int(S[k.S_LIMITED])


def operator_vector(parts: ArmParts, period_s: float) -> np.ndarray:
    """The operator's parameters (arm_kernel's O_* layout)."""
    from haptic_teleop.engine import arm_kernel as k

    o = parts.operator
    oc = o.constants()
    ov = np.zeros(k.O_SIZE)
    ov[k.O_PROFILE] = PROFILE_CODES[oc.profile]
    ov[k.O_X0] = oc.x0_m
    ov[k.O_START] = oc.start_s
    ov[k.O_SPEED] = oc.speed_m_per_s
    ov[k.O_T_END] = oc.t_end_s
    ov[k.O_X_END] = oc.x_end_m
    ov[k.O_AMP] = o.params.amplitude_m
    ov[k.O_W] = 2.0 * math.pi * o.params.frequency_hz if oc.profile == "sinusoid" else 0.0
    ov[k.O_ORIGIN : k.O_ORIGIN + 3] = parts.operator_origin_m
    ov[k.O_DIR : k.O_DIR + 3] = parts.operator_direction
    ov[k.O_PERIOD] = period_s
    return ov


def column_starts(parts: ArmParts) -> np.ndarray:
    """First column of each group of the scene's tick schema, in arm_kernel.GROUPS' order."""
    from haptic_teleop.engine import arm_kernel as k

    return np.array([parts.schema.group(name).start for name in k.GROUPS], dtype=np.int64)


def model_addresses(parts: ArmParts) -> np.ndarray:
    m: Any = parts.master.plant
    s: Any = parts.slave.plant
    return np.array([m.model._address, m.data._address, s.model._address, s.data._address], dtype=np.int64)


# --------------------------------------------------------------------------------------------
# The loop around the kernel.


def arm_codec_nets(codecs: tuple[Any, Any], period_ns: int) -> list[Any]:
    """The kernel's codec arrays of each direction that has a codec (None for the others), in the
    arm layout (`ArmCodecNet`)."""
    from haptic_teleop.engine.codec_layout import (
        ARM_C_SIZE,
        ARM_C_TRIG0,
        ARM_DIM,
        ARM_LAYOUT,
        ARM_RING_WIDTH,
        ARM_S_SIZE,
    )
    from haptic_teleop.engine.compiled_codec import CodecNet

    class ArmCodecNet(CodecNet):
        """`CodecNet` with codec_layout's ARM_* layout (up to 9 values a sample, and their rate)."""

        _c_size, _trig0, _s_size, _ring_width = ARM_C_SIZE, ARM_C_TRIG0, ARM_S_SIZE, ARM_RING_WIDTH
        _places = ARM_LAYOUT

    out = []
    for ch in codecs:
        if ch is not None:
            assert ch.dim <= ARM_DIM
        out.append(None if ch is None else ArmCodecNet(ch, period_ns))
    return out


class CompiledArm:
    """An arm scene's compiled loop: the kernel's arrays, built from (and sharing state with) the
    scene's Python objects; `run` ticks it like `arm_loop.run_arm_loop`. With `codec` the loop is
    engine/arm_codec_kernel.py's (the codec stage in the kernel; `run` takes the directions'
    `arm_codec_nets`)."""

    def __init__(self, parts: ArmParts, period_s: float, codec: bool = False) -> None:
        from haptic_teleop.engine import arm_kernel as k

        self.k = k
        self.codec = codec
        self.ck = codec_kernel() if codec else None
        assert not codec or self.ck is not None
        self.parts = parts
        self.take()
        self.mw = self._work(parts.master)
        self.sw = self._work(parts.slave)
        self.ov = operator_vector(parts, period_s)
        self.cols = column_starts(parts)
        self.width = len(parts.schema.columns)

    def take(self) -> None:
        """(Re)build both side tuples from the scene's Python objects as they are now (`run` does,
        so what was changed on them since the engine was built counts)."""
        self.ms = side_tuple(self.parts.master, self.parts, True)
        self.ss = side_tuple(self.parts.slave, self.parts, False)

    def _work(self, side: ArmSide) -> tuple[np.ndarray, ...]:
        plant: Any = side.plant
        return tuple(self.k.work_arrays(plant.n, plant.model.nv, 6 if side.rotational else 3))

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) now, not in the timed loop: zero ticks."""
        rel, occ = np.full(1, -1, dtype=np.int64), np.zeros(1)
        args = (
            0, 0, self.ms, self.ss, self.mw, self.sw, self.ov, self.cols, rel, occ, rel, occ,
            np.zeros((1, 6)), np.zeros((1, 9)), np.zeros((1, self.width)), 0, 0,
        )  # fmt: skip
        from haptic_teleop.engine.compiled_loop import first_compile

        if self.codec:
            from haptic_teleop.engine.compiled_codec import no_codec, no_history

            idle = no_codec(1)
            with first_compile(self.ck.run_ticks_codec):
                self.ck.run_ticks_codec(*args, *idle, *idle, np.zeros((3, 9)), *no_history(), *no_history())
        else:
            with first_compile(self.k.run_ticks):
                self.k.run_ticks(*args)

    def store(self, engine: Any) -> None:
        """The kernel's state back into the scene's Python objects and `engine.joint_limit_ticks`."""
        engine.joint_limit_ticks = {
            "master": store_side(self.parts.master, self.ms),
            "slave": store_side(self.parts.slave, self.ss),
        }

    def run(self, engine: Any, progress: Any, output: Any, fwd: Any, bwd: Any, window: int, nets: Any) -> int:
        """Ticks from 0 until the scene's end or a stop into `output` (the engine's _Output built
        on the directions' `settled`); returns the ticks done. `nets`: each direction's
        `arm_codec_nets` (with a codec, that direction's schedule, fwd or bwd, is None)."""
        from haptic_teleop.engine import compiled_loop
        from haptic_teleop.engine.compiled_driver import run_windows

        self.take()
        block = output.block
        ms, ss, mw, sw, ov, cols = self.ms, self.ss, self.mw, self.sw, self.ov, self.cols
        codec = self.codec
        run_ticks = self.ck.run_ticks_codec if codec else self.k.run_ticks

        def call(c0: int, c1: int, *network: Any) -> None:
            # (network: the schedules' window, rings, w0, then the codec arrays: `codec_tail`)
            w0, tail = network[-2:]
            run_ticks(c0, c1, ms, ss, mw, sw, ov, cols, *network[:-2], block, w0, output.start, *tail)

        rings = compiled_loop.Rings((6, 9))
        return run_windows(engine, call, (fwd, bwd), nets, rings, output, window, progress, np.zeros((3, 9)))


# --------------------------------------------------------------------------------------------
# One side's tick alone, for the live nodes (nodes/arm_side.py).


def compiled_reason_side(side: ArmSide) -> str | None:
    """Why one side's tick cannot run compiled (`CompiledSideTick`), or None if it can."""
    from haptic_teleop.plants.arm import MujocoArm

    if type(side.plant) is not MujocoArm:
        return "plant effects or a non-MuJoCo backend (only the bare MuJoCo arms are compiled)"
    if side.law.params.law != "position":
        return f"task law {side.law.params.law!r} (compiled: position)"
    return kernel_unusable()


class _Ledger:
    """The compiled side's energy bound as `SideTick.bound` is used by the nodes: the reservoir,
    the parameters, `restart`, and `held` (the kernel's own array: writing it is the ledger's input)."""

    def __init__(self, side: ArmSide, t: tuple[Any, ...], k: Any) -> None:
        self.params = side.bound.params
        self.held: np.ndarray = t[k.T_HELD]
        self._S: np.ndarray = t[k.T_S]
        self._k = k

    @property
    def energy_j(self) -> float:
        return float(self._S[self._k.S_ENERGY])

    def restart(self, energy_j: float) -> None:
        """`CoupledEnergyBound.restart`: the reservoir set, the next tick's q taken as the first."""
        self._S[self._k.S_ENERGY] = float(energy_j)
        self._S[self._k.S_HAS_LAST] = 0.0


class CompiledSideTick:
    """`arm_loop.SideTick` for one side, compiled: `torque` runs `arm_kernel.side_tick` (the side's
    part of the engine's compiled tick) on the plant's MjData after mj_step1. Its state (reservoir,
    held torques, last q, held orientation) lives in the kernel's arrays, built from the side's
    Python objects when made; `limit`, `force`, `ratio`, `limited_ticks` and `bound` as SideTick's."""

    def __init__(self, side: ArmSide, parts: ArmParts, master: bool) -> None:
        from haptic_teleop.engine import arm_kernel as k

        self.k = k
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
