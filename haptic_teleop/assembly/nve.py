"""Builds an NVE scene's core objects, once, for the engine and the live nodes: the server's
object, each client (its coupling, spring schedule, HIP profile) and each client's link pair with
the playout buffer at each end (docs/nve.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from haptic_teleop.core.link import Link
from haptic_teleop.core.nve import (
    Coupling,
    Fujimoto04,
    NoCompensation,
    NveClient,
    ObjectServer,
    SpringSchedule,
    TransparencyCompensation,
)
from haptic_teleop.core.nve_transparency import NveModel
from haptic_teleop.core.operator import Operator, OperatorParams
from haptic_teleop.core.playout import PlayoutBuffer
from haptic_teleop.core.playout_config import build_buffer
from haptic_teleop.core.playout_seed import TransparencyBuffer
from haptic_teleop.scene.direction import DirectionConfig
from haptic_teleop.scene.nve_schema import NveClientConfig, NveConfig
from haptic_teleop.scene.schema import Scene
from haptic_teleop.scene.traces import build_scene_link, read_operator_trace

UP, DOWN = "up", "down"


def coupling_of(c: NveClientConfig) -> Coupling:
    k = c.coupling
    return Coupling(
        k.client_stiffness_n_per_m, k.client_damping_n_s_per_m, k.server_stiffness_n_per_m, k.server_damping_n_s_per_m
    )


def client_model(nve: NveConfig, c: NveClientConfig) -> NveModel:
    """The transparency model of one client (its own couplings and the object)."""
    k = c.coupling
    return NveModel(
        nve.object.mass_kg,
        nve.object.damping_n_s_per_m,
        k.client_stiffness_n_per_m,
        k.server_stiffness_n_per_m,
        k.client_damping_n_s_per_m,
        k.server_damping_n_s_per_m,
    )


def build_schedule(nve: NveConfig, c: NveClientConfig) -> SpringSchedule:
    """The client's spring coefficient against its measured round trip (`compensation`)."""
    comp = c.compensation
    kh = c.coupling.client_stiffness_n_per_m
    if comp.scheme == "none":
        return NoCompensation(kh)
    if comp.scheme == "transparency":
        return TransparencyCompensation.build(
            client_model(nve, c),
            comp.rule,
            comp.interaction_rad_per_s,
            comp.allowable_mass_kg if comp.allowable_mass_kg is not None else float("inf"),
            comp.allowable_damping_n_s_per_m if comp.allowable_damping_n_s_per_m is not None else float("inf"),
            comp.min_spring_n_per_m,
        )
    assert comp.reduction_n_per_m_per_s is not None  # the schema requires it
    return Fujimoto04(
        comp.initial_spring_n_per_m if comp.initial_spring_n_per_m is not None else kh,
        comp.reduction_n_per_m_per_s,
        comp.threshold_rtt_s if comp.threshold_rtt_s is not None else 0.0,
        comp.min_spring_n_per_m,
    )


class Hip:
    """A client's haptic interaction pointer, driven by its operator profile: its rest point plus
    the profile's displacement (which starts at 0; a trace's positions are displacements too) along
    a unit direction (1 axis: +x), position and velocity per axis at time t."""

    def __init__(self, operator: Operator, rest_m: np.ndarray, direction: np.ndarray) -> None:
        self.operator = operator
        self.rest_m = rest_m
        self.direction = direction

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        xd, vd = self.operator.intended(t)
        return self.rest_m + xd * self.direction, vd * self.direction


def build_hip(nve: NveConfig, c: NveClientConfig) -> Hip:
    op = c.operator
    rest = np.array(c.hip_start_m if c.hip_start_m is not None else nve.object_start, dtype=np.float64)
    trace = read_operator_trace(Path(op.trace_file), "scene", "operator.trace_file") if op.trace_file else None
    params = OperatorParams(
        profile=op.profile,
        start_position_m=0.0,
        start_s=op.start_s,
        speed_m_per_s=op.speed_m_per_s,
        distance_m=op.distance_m,
        amplitude_m=op.amplitude_m,
        frequency_hz=op.frequency_hz,
        trace_time_s=trace[0] if trace else (),
        trace_position_m=trace[1] if trace else (),
    )
    direction = np.ones(1) if nve.axes == 1 else np.array(op.direction or (1.0, 0.0, 0.0), dtype=np.float64)
    return Hip(Operator(params), rest, direction)


def build_direction(d: DirectionConfig, seed: int, stream: str, period_ns: int) -> tuple[Link, PlayoutBuffer]:
    """One direction's link (its random streams named `stream`) and the buffer at its end."""
    link = build_scene_link(d.effects, seed, stream)
    buf = build_buffer(d.buffer, period_ns)
    if isinstance(buf, TransparencyBuffer) and d.buffer.force_slope_n_per_s is None:
        raise ValueError(f"{stream}: buffer policy 'transparency' needs force_slope_n_per_s in an NVE scene")
    return link, buf


@dataclass
class NveClientParts:
    name: str
    client: NveClient
    hip: Hip
    up: Link
    down: Link
    up_buffer: PlayoutBuffer  # at the server
    down_buffer: PlayoutBuffer  # at the client


@dataclass
class NveParts:
    server: ObjectServer
    clients: list[NveClientParts]
    axes: int


def build_nve_parts(config: Scene, period_ns: int) -> NveParts:
    """Everything an NVE scene's tick uses, fresh (the same objects for the engine and the nodes)."""
    nve = config.nve
    if nve is None:
        raise ValueError("not an NVE scene (no nve section)")
    seed = config.scene.seed
    server = ObjectServer(
        nve.object.mass_kg,
        nve.object.damping_n_s_per_m,
        [coupling_of(c) for c in nve.clients],
        period_ns * 1e-9,
        nve.object_start,
    )
    clients = []
    for c in nve.clients:
        up, up_buffer = build_direction(c.up, seed, f"{c.name}/{UP}", period_ns)
        down, down_buffer = build_direction(c.down, seed, f"{c.name}/{DOWN}", period_ns)
        clients.append(
            NveClientParts(
                c.name,
                NveClient(coupling_of(c), build_schedule(nve, c), nve.axes),
                build_hip(nve, c),
                up,
                down,
                up_buffer,
                down_buffer,
            )
        )
    return NveParts(server, clients, nve.axes)
