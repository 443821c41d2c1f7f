"""What a link direction's samples look like on the wire (sensor_msgs/JointState), for the relay and
the sync buffer of any direction: teleoperation's `forward` and `backward` (topics.py) and an NVE
scene's `<client>/up` and `<client>/down` (docs/live_nve.md, "NVE scenes live").

NVE layouts (a = the scene's axes):
  up   (client -> server): names <client>_hip_x[, _y, _z]; position x[a], velocity v[a]
  down (server -> client): names object_x[, _y, _z], hip_echo_s; position (x_o[a]..., echo_s),
       velocity (v_o[a]..., 0)
header.stamp = the sender's tick. The core payload (what the `Link` and `PlayoutBuffer` carry) is
the engine's: up (x[a]..., v[a]...), down (x_o[a]..., v_o[a]..., echo_s).

A one-axis teleoperation scene's layouts depend on its stabilizer (`controllers.<side>.eba.law`,
`TeleopController.sample1`, docs/stabilizers.md, "On the wire"):
  reservoir, two_condition: forward master_x (position x, velocity v); backward slave_x
       (position x, velocity v, effort f_env)
  tdpa: the same and a second joint, energy_in_j, whose position is the sender's observed input
       energy E_in (J; its velocity and effort 0): payloads (x, v, E_in) and (f_env, x, v, E_in)
  wave: the sender's joint, position x, velocity the wave it sends (u or v, sqrt(W): not a
       velocity; the engine's packet has the same size): payload (wave, x) both ways

An arm scene's samples: one joint per task axis (master_x, master_y, master_z; slave_...), payload
(x[3], v[3]) forward and (x[3], v[3], f_env[3]) backward; with TDPA the energy joint after them,
its position the sender's pooled input energy (core/tdpa_coupled.py), the payload's last value.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from haptic_teleop.nodes.topics import DIRECTION_JOINT, DIRECTIONS, WIRE_FIELDS, payload_fields, wire_names
from haptic_teleop.record.layouts import ENERGY_JOINT, joint_state_size

AXIS_LABELS = ("x", "y", "z")
NVE_UP, NVE_DOWN = "up", "down"
_NVE_DIRECTION = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)/(up|down)\Z")
ECHO_NAME = "hip_echo_s"


def nve_direction(direction: str) -> tuple[str, str] | None:
    """(client, "up" | "down") of an NVE direction `<client>/up|down`, or None for another."""
    m = _NVE_DIRECTION.match(direction)
    return (m.group(1), m.group(2)) if m else None


def direction_problem(direction: str) -> str | None:
    """Why `direction` is not a link direction, or None."""
    if direction in DIRECTIONS or nve_direction(direction) is not None:
        return None
    return f"allowed: {' or '.join(DIRECTIONS)} (teleoperation), or <client>/up, <client>/down (an NVE scene)"


def hip_names(client: str, axes: int) -> tuple[str, ...]:
    return tuple(f"{client}_hip_{a}" for a in AXIS_LABELS[:axes])


def object_names(axes: int) -> tuple[str, ...]:
    return tuple(f"object_{a}" for a in AXIS_LABELS[:axes])


@dataclass(frozen=True)
class Wire:
    """One direction's JointState layout and its mapping to and from the core payload."""

    direction: str
    axes: int
    names: str | tuple[str, ...]  # JointState names (one string: a single joint)
    fields: tuple[str, ...]  # the JointState arrays filled, in JointState order
    want: tuple[str, ...]  # the arrays read, in the order the reader returns them
    width: int  # values per array read
    floats: int  # the engine's floats per axis of this direction's packet (its wire size)
    energy: bool = False  # TDPA: the second joint ENERGY_JOINT carries the sender's input energy

    @property
    def maps(self) -> bool:
        """True when the values read are not the payload as they come (`payload`, `values` map them)."""
        return self.energy or nve_direction(self.direction) is not None

    def payload(self, values: Sequence[float]) -> tuple[float, ...]:
        """Values as read (`want`, `width` each) -> the core payload."""
        if self.energy:  # read per field (the axes' values, the energy joint's): E_in is position's last
            a, w = self.axes, self.axes + 1
            out = [v for k in range(len(self.want)) for v in values[k * w : k * w + a]]
            return (*out, values[self.want.index("position") * w + a])
        if not self._is_down():
            return tuple(values)
        a = self.axes
        # read: position (x_o[a], echo), velocity (v_o[a], 0)
        return (*values[:a], *values[a + 1 : 2 * a + 1], values[a])

    def values(self, payload: Sequence[float]) -> list[float]:
        """The core payload -> JointState values (field by field, one per name)."""
        if self._is_down():
            a = self.axes
            return [*payload[:a], payload[2 * a], *payload[a : 2 * a], 0.0]
        if self.energy:
            a, n = self.axes, len(self.want)
            per_field = {f: payload[k * a : (k + 1) * a] for k, f in enumerate(self.want)}
            e = payload[n * a]
            return [v for f in self.fields for v in (*per_field[f], e if f == "position" else 0.0)]
        if self.axes == 1 and self.direction in DIRECTIONS:
            by_field = dict(zip(self.want, payload, strict=True))
            return [by_field[f] for f in self.fields]
        return list(payload)

    def packet_bytes(self) -> int:
        """The size the engine gives this direction's packet (its links' rate limits count it): a
        one-axis or NVE sample's JointState (`record.layouts.joint_state_size`); an arm sample's
        as the engine's arm loop sizes it (`assembly.side.wire_payload_bytes`: a name per task
        axis, TDPA's energy joint one more)."""
        if self.axes == 1 or nve_direction(self.direction) is not None:
            return joint_state_size(self.floats, self.axes, self.energy)
        from haptic_teleop.assembly.side import wire_payload_bytes

        return wire_payload_bytes(self.axes + self.energy, self.floats)

    def _is_down(self) -> bool:
        nd = nve_direction(self.direction)
        return nd is not None and nd[1] == NVE_DOWN


WIRE_LAWS = ("reservoir", "two_condition", "tdpa", "wave")


def wire_of(direction: str, axes: int = 1, law: str = "reservoir") -> Wire:
    """The wire layout of a direction (`axes`: values per field of the payload: the task axes of an
    arm scene, the NVE scene's axes; `law`: a one-axis teleoperation scene's stabilizer, which
    TDPA and wave variables change: module docstring)."""
    nd = nve_direction(direction)
    if law not in WIRE_LAWS:
        raise ValueError(f"law {law!r}: allowed: {', '.join(WIRE_LAWS)}")
    if law == "wave" and (nd is not None or axes != 1):
        raise ValueError(f"law {law} on the wire: one-axis teleoperation directions only")
    if law == "tdpa" and nd is not None:
        raise ValueError(f"law {law} on the wire: teleoperation directions only")
    if nd is None:
        if direction not in DIRECTIONS:
            raise ValueError(f"direction {direction!r}: {direction_problem(direction)}")
        joint = DIRECTION_JOINT[direction]
        if law == "tdpa":
            fields = WIRE_FIELDS[direction]
            names = (joint,) if axes == 1 else tuple(wire_names(direction, axes))
            want = payload_fields(direction, axes)
            return Wire(direction, axes, (*names, ENERGY_JOINT), fields, want, axes + 1, len(fields), True)
        if law == "wave":  # read (velocity, position) = the payload (wave, x)
            return Wire(direction, 1, joint, ("position", "velocity"), ("velocity", "position"), 1, 2)
        floats = 3 if direction == "backward" else 2
        return Wire(
            direction, axes, wire_names(direction, axes), WIRE_FIELDS[direction],
            payload_fields(direction, axes), axes, floats,
        )  # fmt: skip
    client, which = nd
    if which == NVE_UP:
        return Wire(
            direction, axes, hip_names(client, axes), ("position", "velocity"), ("position", "velocity"), axes, 2
        )
    names = (*object_names(axes), ECHO_NAME)
    return Wire(direction, axes, names, ("position", "velocity"), ("position", "velocity"), axes + 1, 3)


def scene_law(cfg: Any, axes: int = 1) -> str:
    """The stabilizer that shapes a scene's wire (`wire_of`'s `law`): a teleoperation scene's
    `controllers.master.eba.law` (both sides run the same), on an arm scene (`axes` 3) only
    TDPA's energy joint (its other laws' samples are the plain ones); `reservoir` for NVE scenes."""
    if cfg.is_nve:
        return "reservoir"
    law = str(cfg.controllers.master.eba.law)
    if cfg.is_arm or axes != 1:
        return "tdpa" if law == "tdpa" else "reservoir"
    return law
