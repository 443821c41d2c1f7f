"""`haptic-teleop run SCENE --emulate`: an emulator for each side of a scene that is on real hardware
(Dynamixel servos or a Universal Robots arm), so the hardware path runs with no hardware, through
the unmodified SDKs (docs/hardware_emulate.md, "Trying it without hardware").

For each side with `backend: dynamixel` one emulator process is started
(`emulators/dynamixel/process.start_bus`) on a pseudo-terminal, built from the scene:

- its servos: the side's ids, models and signs; each servo's joint offset is chosen so that the
  driver, with the scene's `zero_offsets_rad`, reads the emulated joint's angle (the emulator puts
  a joint's angle `offset` at register 2048, the driver reads `sign (angle - zero_offset)`);
- its physics: the side's MJCF (the same model the kinematics use), started at `start_q_rad`,
  with the true viscous joint friction equal to the damping the scene lets EBA assume (the
  model's when the scene names none, as for `identify`; so the
  energy analysis' margins, which use the assumed damping, are those of the emulated arm; the
  model's Coulomb friction stays and only dissipates more), gravity on;
- a slave's wall (the scene's `slave.wall`), a master's operator hand (the scene's push profile:
  start, speed, distance, spring and damper, along the operator's direction mapped into the
  device frame, from the handle's start);
- its time: "lockstep" (default: the emulated arm advances one control period at each Goal
  Current write, so the same scene and seed give the same bag) or "realtime" (the arm follows the
  wall clock, as real servos do).

A side with `backend: ur` gets the UR emulator (`emulators/ur/process.start_ur`: RTDE, dashboard
and script ports on the loopback, as ur_rtde connects to them) with the side's model, start pose
and the scene's wall; in `control_mode: torque` it reports PolyScope 5.26 (direct_torque is in
ur_rtde's control script from 5.26 on). Its physics runs on the wall clock (the UR controller's 500
Hz), so such a run is real time, not lockstep: the same seed gives a bag of the same scene, not the
same bag. It has no operator's hand: it stands in for a slave. Its true joint damping is the
model's (ur5e.xml's dof_damping), so the scene must assume no more (touch_ur5e_wall does).
Its ports are fixed, so one UR side at a time.

`emulated(...)` starts them, yields the `--set` overrides that point the drivers at them
(`<side>.hardware.port=PTY` for servos, `<side>.hardware.host=127.0.0.1` for the UR; for servos
also `read_timeout_s`, EMULATED_READ_TIMEOUT_S, unless the scene sets one), and stops them on the
way out, whatever happens.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.schema import Scene

TIME_MODES = ("lockstep", "realtime")


EMULATED_BACKENDS = ("dynamixel", "ur")
# PolyScope version the UR emulator reports for a side in control_mode torque: ur_rtde's control
# script calls direct_torque() from 5.26 on.
UR_TORQUE_VERSION = (5.0, 26.0, 0.0, 0.0)
# How long a read waits for an emulated bus's replies when the scene does not say. The emulator is
# a process on a shared machine, not a servo that answers within microseconds: with the SDK's
# default (its 16 ms latency timer and the packet's time) three reads in a row gave up once on a
# busy 2-core CI machine, and the session stopped on "the replies come late".
EMULATED_READ_TIMEOUT_S = 0.5


def emulated_sides(config: Scene) -> tuple[str, ...]:
    """The sides of a scene on a backend `--emulate` serves (EMULATED_BACKENDS)."""
    return tuple(side for side in ("master", "slave") if getattr(config, side).backend in EMULATED_BACKENDS)


def ur_config(config: Scene, role: str, source: str = "--emulate") -> Any:
    """The UR emulator's `URConfig` for the UR side of a validated scene (module docstring)."""
    from haptic_teleop.emulators.ur.config import URConfig, WallConfig

    cfg = getattr(config, role)
    if role != "slave":
        raise ConfigError(
            source,
            f"{role}.backend",
            cfg.backend,
            "the UR emulator stands in for a slave (it has no operator's hand); allowed: slave.backend=ur",
        )
    if cfg.start_q_rad is None:
        raise ConfigError(source, f"{role}.start_q_rad", None, "required for an emulated side")
    w = config.slave.wall
    wall = None
    if w.point_m is not None and w.normal is not None:
        wall = WallConfig(tuple(w.point_m), tuple(w.normal), w.stiffness_n_per_m, w.damping_n_s_per_m)
    hw = cfg.hardware
    ur = URConfig(model=cfg.model, start_q_rad=tuple(cfg.start_q_rad), wall=wall)
    if hw is not None and hw.control_mode == "torque":
        ur = dataclasses.replace(ur, controller_version=UR_TORQUE_VERSION)
    return ur


def bus_config(config: Scene, role: str, time_mode: str = "lockstep", source: str = "--emulate") -> Any:
    """The emulator's `BusConfig` for one side of a validated scene (module docstring)."""
    from haptic_teleop.core.taskspace import rotation_from_rpy
    from haptic_teleop.emulators.dynamixel.config import (
        BusConfig,
        HandConfig,
        PhysicsConfig,
        ServoConfig,
        TimeConfig,
        WallConfig,
    )
    from haptic_teleop.plants.arm import inspect_model

    if time_mode not in TIME_MODES:
        raise ConfigError(source, "", time_mode, f"allowed: {', '.join(TIME_MODES)}")
    cfg = getattr(config, role)
    hw = cfg.hardware
    if cfg.backend != "dynamixel" or hw is None or hw.ids is None or hw.models is None:
        raise ConfigError(source, f"{role}.backend", cfg.backend, "the emulator stands in for a dynamixel side")
    if cfg.start_q_rad is None:
        raise ConfigError(source, f"{role}.start_q_rad", None, "required for an emulated side")
    info = inspect_model(cfg.model)
    joints = cfg.joints if cfg.joints is not None else tuple(m for m in info.motors if m in info.joints)
    n = len(joints)
    signs = hw.signs if hw.signs is not None else (1,) * n
    zeros = hw.zero_offsets_rad if hw.zero_offsets_rad is not None else (0.0,) * n
    kts = hw.torque_constants_nm_per_a
    servos = tuple(
        ServoConfig(
            id=hw.ids[k],
            model=hw.models[k],
            joint=joints[k],
            sign=signs[k],
            offset_rad=signs[k] * (math.pi - zeros[k]),
            torque_constant_nm_per_a=kts[k] if kts is not None else None,
        )
        for k in range(n)
    )
    # Per model joint (the emulator's order): the scene's start and damping where it names the joint.
    start = []
    damping: list[float] | None = None if cfg.damping_nm_s_per_rad is None else []  # None: the model's
    for name in info.joints:
        k = joints.index(name) if name in joints else None
        start.append(cfg.start_q_rad[k] if k is not None else 0.0)
        if damping is not None:
            damping.append(cfg.damping_nm_s_per_rad[k] if k is not None else 0.0)
    wall = None
    hand = None
    if role == "slave":
        w = config.slave.wall
        assert w.point_m is not None and w.normal is not None
        wall = WallConfig(
            point_m=tuple(w.point_m),
            normal=tuple(w.normal),
            stiffness_n_per_m=w.stiffness_n_per_m,
            damping_n_s_per_m=w.damping_n_s_per_m,
            contact_impedance=config.slave.contact_impedance,
        )
    else:
        op = config.operator
        if op.profile != "push":
            raise ConfigError(
                source, "operator.profile", op.profile, "the emulator's operator hand follows a push; allowed: push"
            )
        direction = np.array(op.direction if op.direction is not None else [-c for c in config.slave.wall.normal or ()])
        mc = config.mapping
        rpy = mc.rotation_rpy_deg if mc is not None else (0.0, 0.0, 0.0)
        r = np.array(rotation_from_rpy(*(math.radians(a) for a in rpy)))
        d_dev = r.T @ direction  # the task-frame direction in the device's frame
        d_dev = d_dev / np.linalg.norm(d_dev)
        hand = HandConfig(
            start_s=op.start_s,
            speed_m_per_s=op.speed_m_per_s,
            distance_m=op.distance_m,
            stiffness_n_per_m=op.stiffness_n_per_m,
            damping_n_s_per_m=op.damping_n_s_per_m,
            direction=tuple(float(c) for c in d_dev),
        )
    physics = PhysicsConfig(
        kind="mujoco",
        model=cfg.model,
        start_q_rad=tuple(start),
        damping_nm_s_per_rad=None if damping is None else tuple(damping),
        wall=wall,
        hand=hand,
    )
    return BusConfig(
        servos=servos,
        baud_bps=hw.baud_bps,
        time=TimeConfig(mode=time_mode, lockstep_dt_s=config.scene.period_s),
        physics=physics,
    )


@contextlib.contextmanager
def emulated(config: Scene, time_mode: str = "lockstep") -> Iterator[list[str]]:
    """Start an emulator for each side of `config` on Dynamixel servos or a UR arm; yields the
    `--set` overrides that point each side's driver at its emulator; stops them all on the way out.
    `time_mode` is the servos' (a UR emulator always runs on the wall clock)."""
    sides = emulated_sides(config)
    if not sides:
        raise ConfigError(
            "--emulate",
            "master.backend, slave.backend",
            "mujoco",
            "no side is on hardware --emulate serves; allowed: a scene with --set slave.backend=dynamixel, "
            "--set master.backend=dynamixel or --set slave.backend=ur",
        )
    ur_sides = [s for s in sides if getattr(config, s).backend == "ur"]
    if len(ur_sides) > 1:
        raise ConfigError("--emulate", "master.backend", "ur", "one UR side at a time (its emulator's ports are fixed)")
    # Every configuration is checked before the first emulator starts.
    configs = {s: ur_config(config, s) if s in ur_sides else bus_config(config, s, time_mode) for s in sides}
    with contextlib.ExitStack() as stack:
        overrides = []
        for side, cfg in configs.items():
            if side in ur_sides:
                from haptic_teleop.emulators.ur.process import start_ur

                ur = start_ur(cfg)
                stack.callback(ur.stop)
                overrides += [f"{side}.hardware.host={ur.host}", f"{side}.hardware.device_clock=real"]
                continue
            from haptic_teleop.emulators.dynamixel.process import start_bus

            bus = start_bus(cfg)
            stack.callback(bus.stop)
            overrides += [
                f"{side}.hardware.port={bus.port}",
                f"{side}.hardware.device_clock={time_mode.replace('realtime', 'real')}",
            ]
            if getattr(config, side).hardware.read_timeout_s is None:
                overrides.append(f"{side}.hardware.read_timeout_s={EMULATED_READ_TIMEOUT_S}")
        yield overrides
