"""The compiled loop for arm scenes: the same tick as the Python arm loop (engine/loop.py), in numba.

The tick (docs/performance_arms.md, "Arm scenes") calls MuJoCo from compiled code on the plants' own
`MjModel`/`MjData`: `mj_step1` (positions, velocities, kinematics, gravity torques, collisions),
`mj_jacSite` (the handle's or tool's Jacobian), `mj_step2` (actuation, constraints, integration;
the split step gives the bits of `mj_step` for the Euler and implicit integrators), and
`mj_contactForce` for the wall's force on the tool. The contact array is read in place: its
address and count are fields of mjData, whose offsets (and mjContact's) are laid out by C's rules
from `mujoco.introspect`, MuJoCo's description of its headers, and checked against what the
bindings read on a probe model before use (`contact_layout`). The
task-space law, J^T F, the null-space damping, the pooled joint bound (EBA's, or TDPA's step with
its zoh controller, `core.tdpa_coupled.coupled_tdpa`) and the operator are the functions of `core`
compiled from their one definition (`compiling.compile_tree`).

The network is the 1-DoF loop's: `axis_host.schedule` decides, window by window, which sequence
number each buffer releases at each tick (nothing it decides depends on what packets carry); the
loop looks the released payload up in the sender's ring of recent payloads.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_teleop import compiling
from haptic_teleop.assembly.compiled_side import side_kernel, side_tuple, store_side

if TYPE_CHECKING:
    from haptic_teleop.assembly.parts import ArmParts, ArmSide

PROFILE_CODES = {"push": 0, "sinusoid": 1, "hold": 2}


def _load(module: str, failing: str) -> tuple[Any, str | None]:
    """engine/compiled/<module>, imported after its stale numba cache is dropped (cache.load); or
    None and why (`failing`: what failed)."""
    try:
        return compiling.load(f"haptic_teleop.engine.compiled.{module}"), None
    except Exception as exc:  # noqa: BLE001 - no numba, or it cannot load here: the Python loop runs
        return None, f"{failing} ({type(exc).__name__}: {exc})"


@functools.cache
def _kernel_or_error() -> tuple[Any, str | None]:
    return _load("arm_kernel", "numba unavailable or failing")


def kernel() -> Any:
    """The compiled arm kernel module, or None without numba."""
    return _kernel_or_error()[0]


def kernel_error() -> str | None:
    return _kernel_or_error()[1]


@functools.cache
def _codec_kernel_or_error() -> tuple[Any, str | None]:
    err = kernel_error()
    if err is not None:
        return None, err
    return _load("arm_codec_kernel", "the arm codec kernel cannot load")


def codec_kernel() -> Any:
    """The compiled arm loop with the codec stage (module engine/arm_codec_kernel), or None."""
    return _codec_kernel_or_error()[0]


def codec_kernel_error() -> str | None:
    """Why the arm loop with the codec stage cannot load here, or None."""
    return _codec_kernel_or_error()[1]


# --------------------------------------------------------------------------------------------
# mjData's contact array, read from compiled code.


@functools.cache
def kernel_unusable() -> str | None:
    """Why the arm kernel cannot run on this machine (no numba, or an mjData contact layout it
    does not know), or None."""
    err = kernel_error()
    if err is not None:
        return err
    from haptic_teleop.assembly.compiled_side import side_unusable

    return side_unusable()


# --------------------------------------------------------------------------------------------
# What can be compiled, and the arrays the kernel takes.


def compiled_reason_arm(
    parts: ArmParts, forward: Any, backward: Any, fbuf: Any, bbuf: Any, period_s: float | None = None
) -> str | None:
    """Why the arm scene cannot run in the compiled loop, or None if it can. `period_s`: the
    scene's period (a side whose bound runs at another period ticks in the Python loop only)."""
    from haptic_teleop.assembly.compiled_side import compiled_bounds
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
        if type(side.bound) not in compiled_bounds():
            return f"{role}: stabilizer {type(side.bound).__name__} (compiled: EBA's bounds, TDPA)"
    profile = parts.operator.constants().profile
    if profile not in PROFILE_CODES:
        return f"operator profile {profile!r} (compiled: {', '.join(PROFILE_CODES)})"
    for name, link, buf in (("forward", forward, fbuf), ("backward", backward, bbuf)):
        if any(e.name == "corrupt" for e in link.effects):
            return f"{name} link corrupts payloads (the schedule must not depend on what packets carry)"
        if buf.extrapolates:
            return f"{name} buffer extrapolates payloads"
    return kernel_unusable()


def operator_vector(parts: ArmParts, period_s: float) -> np.ndarray:
    """The operator's parameters (arm_kernel's O_* layout)."""
    from haptic_teleop.engine.compiled import arm_kernel as k

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
    from haptic_teleop.engine.compiled import arm_kernel as k

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
    from haptic_teleop.core.codec_layout import (
        ARM_C_SIZE,
        ARM_C_TRIG0,
        ARM_DIM,
        ARM_LAYOUT,
        ARM_RING_WIDTH,
        ARM_S_SIZE,
    )
    from haptic_teleop.engine.compiled.codec_host import CodecNet

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
    scene's Python objects; `run` ticks it like `engine/loop.py`. With `codec` the loop is
    engine/compiled/arm_codec_kernel.py's (the codec stage in the kernel; `run` takes the directions'
    `arm_codec_nets`)."""

    def __init__(self, parts: ArmParts, period_s: float, codec: bool = False) -> None:
        from haptic_teleop.engine.compiled import arm_kernel as k

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
        self.own = k.tick_array(self.ms, self.ss)
        self.width = len(parts.schema.columns)

    def take(self) -> None:
        """(Re)build both side tuples from the scene's Python objects as they are now (`run` does,
        so what was changed on them since the engine was built counts)."""
        self.ms = side_tuple(self.parts.master, self.parts, True)
        self.ss = side_tuple(self.parts.slave, self.parts, False)

    def _work(self, side: ArmSide) -> tuple[np.ndarray, ...]:
        plant: Any = side.plant
        return tuple(side_kernel().work_arrays(plant.n, plant.model.nv, 6 if side.rotational else 3))

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) now, not in the timed loop: zero ticks."""
        rel, occ = np.full(1, -1, dtype=np.int64), np.zeros(1)
        args = (
            0, 0, self.ms, self.ss, self.mw, self.sw, self.ov, self.cols, self.own, rel, occ, rel, occ,
            np.zeros((1, 6)), np.zeros((1, 9)), np.zeros((1, self.width)), 0, 0,
        )  # fmt: skip
        from haptic_teleop.compiling import first_compile

        if self.codec:
            from haptic_teleop.engine.compiled.codec_host import no_codec, no_history

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
        """Ticks from 0 until the scene's end or a stop into `output` (the engine's output.Output built
        on the directions' `settled`); returns the ticks done. `nets`: each direction's
        `arm_codec_nets` (with a codec, that direction's schedule, fwd or bwd, is None)."""
        from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound
        from haptic_teleop.engine.compiled import axis_host
        from haptic_teleop.engine.compiled.windows import run_windows

        self.take()
        block = output.block
        ms, ss, mw, sw, ov, cols, own = self.ms, self.ss, self.mw, self.sw, self.ov, self.cols, self.own
        codec = self.codec
        run_ticks = self.ck.run_ticks_codec if codec else self.k.run_ticks

        def call(c0: int, c1: int, *network: Any) -> None:
            # (network: the schedules' window, rings, w0, then the codec arrays: `codec_tail`)
            w0, tail = network[-2:]
            run_ticks(c0, c1, ms, ss, mw, sw, ov, cols, own, *network[:-2], block, w0, output.start, *tail)

        # the payloads' widths: x, v forward; x, v, f backward; with TDPA the sender's energy last
        extra = 1 if isinstance(self.parts.master.bound, CoupledTdpaBound) else 0
        rings = axis_host.Rings((6 + extra, 9 + extra))
        return run_windows(engine, call, (fwd, bwd), nets, rings, output, window, progress, np.zeros((3, 9)))
