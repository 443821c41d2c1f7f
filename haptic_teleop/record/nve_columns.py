"""The per-tick record schema of an NVE run (a consistency server and its clients) and its bag topics.

An NVE run records one float64 row per tick (docs/recording_nve.md, "Schema and columns"). Its columns, per
axis `a` (x, y, z; a 1-axis run names a group alone, without `[x]`):

    server:        obj_x_m[a], obj_v_m_per_s[a], obj_force_n[a]
    per client c:  c.hip_x_m[a], c.hip_v_m_per_s[a], c.obj_x_m[a], c.obj_v_m_per_s[a], c.force_n[a],
                   c.spring_n_per_m, c.rtt_s, c.up_rx_seq, c.down_rx_seq, c.up_occupancy,
                   c.down_occupancy

(clients in scene order; `client1.hip_x_m[x]`, or `client1.hip_x_m` with one axis). The server's
object is its state at the tick and the net coupling force over the step; a client's `obj_*` is
the object as the client uses it (NaN before any packet arrived), `force_n` the force fed back to
its user, `rtt_s` its measured round trip (NaN before any), `*_rx_seq` the tick of the sample its
playout buffer released this tick (-1: none).

`nve_topics` derives the bag's per-tick topics. Pure like record/columns.py (no ROS, no numpy).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.record.columns import AXES, JOINT_STATE, MULTIARRAY, POSE, WRENCH, ColumnLookup, SchemaError

TWIST = "geometry_msgs/msg/TwistStamped"

SERVER_GROUPS = ("obj_x_m", "obj_v_m_per_s", "obj_force_n")
# (group, per axis) in record order, for each client.
_CLIENT_GROUPS: tuple[tuple[str, bool], ...] = (
    ("hip_x_m", True),
    ("hip_v_m_per_s", True),
    ("obj_x_m", True),
    ("obj_v_m_per_s", True),
    ("force_n", True),
    ("spring_n_per_m", False),
    ("rtt_s", False),
    ("up_rx_seq", False),
    ("down_rx_seq", False),
    ("up_occupancy", False),
    ("down_occupancy", False),
)
CLIENT_GROUPS = tuple(g for g, _ in _CLIENT_GROUPS)
# The client groups a /nve/<c>/coupling message holds, in order (its labels).
COUPLING_GROUPS = CLIENT_GROUPS[5:]
DIRECTIONS = ("up", "down")  # up: client -> server (HIP samples); down: server -> client (object)

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


@dataclass(frozen=True)
class NveSchema(ColumnLookup):
    """The columns of one tick's row of an NVE run with these `clients` (scene order) and `axes`
    (1, or 3: x, y, z)."""

    clients: tuple[str, ...]
    axes: int
    columns: tuple[str, ...] = field(init=False, repr=False, compare=False)
    col: dict[str, int] = field(init=False, repr=False, compare=False)
    _slices: dict[str, slice] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if isinstance(self.clients, str) or not isinstance(self.clients, (tuple, list)):
            raise SchemaError(f"NVE clients must be a sequence of client names; got {self.clients!r}")
        object.__setattr__(self, "clients", tuple(self.clients))
        if type(self.axes) is not int or self.axes not in (1, 3):
            raise SchemaError(f"NVE axes must be 1 or 3; got {self.axes!r}")
        if not self.clients:
            raise SchemaError("NVE clients: at least one client name is needed")
        for c in self.clients:
            if not isinstance(c, str) or not _NAME.match(c):
                raise SchemaError(
                    f"NVE client name {c!r}: letters, digits and _ only ([A-Za-z_][A-Za-z0-9_]*), "
                    "not starting with a digit"
                )
        if len(set(self.clients)) != len(self.clients):
            raise SchemaError(f"NVE client names must be distinct; got {', '.join(self.clients)}")
        columns: list[str] = []
        slices: dict[str, slice] = {}

        def add(group: str, per_axis: bool) -> None:
            start = len(columns)
            if per_axis and self.axes > 1:
                columns.extend(f"{group}[{a}]" for a in self.axis_labels)
            else:
                columns.append(group)
            slices[group] = slice(start, len(columns))

        for g in SERVER_GROUPS:
            add(g, True)
        for c in self.clients:
            for g, per_axis in _CLIENT_GROUPS:
                add(f"{c}.{g}", per_axis)
        object.__setattr__(self, "columns", tuple(columns))
        object.__setattr__(self, "col", {c: i for i, c in enumerate(columns)})
        object.__setattr__(self, "_slices", slices)

    # -- names and indices
    @property
    def axis_labels(self) -> tuple[str, ...]:
        """x (1 axis) or x, y, z."""
        return AXES[: self.axes]

    def _groups_allowed(self) -> str:
        return (
            f"{', '.join(SERVER_GROUPS)} and, per client ({', '.join(self.clients)}), "
            f"<client>.{{{','.join(CLIENT_GROUPS)}}}"
        )

    def client_group(self, client: str, name: str) -> slice:
        """`group(f"{client}.{name}")`, with the client checked."""
        if client not in self.clients:
            raise SchemaError(f"no NVE client {client!r}; clients: {', '.join(self.clients)}")
        return self.group(f"{client}.{name}")

    # -- what the bag records of it
    def facts(self) -> dict[str, Any]:
        """The schema as plain data (JSON/YAML): `from_facts` rebuilds it."""
        return {"clients": list(self.clients), "axes": self.axes}

    @classmethod
    def from_facts(cls, facts: Any) -> NveSchema:
        if not isinstance(facts, dict):
            raise SchemaError(f"an NVE schema is a mapping of clients and axes; got {facts!r}")
        try:
            clients = facts["clients"]
            axes = facts["axes"]
        except KeyError as exc:
            raise SchemaError(f"NVE schema: no {exc} key") from None
        if not isinstance(clients, (list, tuple)):
            raise SchemaError(f"NVE schema: clients must be a list of names; got {clients!r}")
        return cls(tuple(clients), axes)

    # -- packets
    @property
    def directions(self) -> tuple[str, ...]:
        """The packet directions of `append_packets`: `<client>/up`, `<client>/down`, per client."""
        return tuple(f"{c}/{d}" for c in self.clients for d in DIRECTIONS)

    def packet_topic(self, direction: str) -> str:
        """`/nve/<client>/up/packets` for "<client>/up" (and down); SchemaError for another direction."""
        if direction not in self.directions:
            raise SchemaError(f"NVE packet direction must be one of {', '.join(self.directions)}; got {direction!r}")
        return f"/nve/{direction}/packets"

    def packet_topics(self) -> tuple[str, ...]:
        return tuple(self.packet_topic(d) for d in self.directions)


def object_names(schema: NveSchema) -> tuple[str, ...]:
    """JointState names of /nve/object/joint_states: object_x (1 axis) or object_x, object_y, object_z."""
    return tuple(f"object_{a}" for a in schema.axis_labels)


def hip_names(schema: NveSchema, client: str) -> tuple[str, ...]:
    """JointState names of /nve/<client>/hip/joint_states: <client>_hip_x ..."""
    return tuple(f"{client}_hip_{a}" for a in schema.axis_labels)


@dataclass(frozen=True)
class NveTopic:
    """One per-tick topic of an NVE run (as `columns.TopicColumns`): message type, header frame,
    names (JointState names or Float64MultiArray labels) and (message field, column group) pairs
    in field order. JointState `position`, `velocity`, `effort` (one value per name); PoseStamped
    `position`, TwistStamped `linear`, WrenchStamped `force` (x, y, z: axes the run lacks are 0);
    Float64MultiArray `data` (the groups back to back, one label per value)."""

    topic: str
    msgtype: str
    frame: str
    names: tuple[str, ...]
    fields: tuple[tuple[str, str], ...]

    def columns(self, schema: NveSchema) -> list[int]:
        """The row indices of the values, in the order the message holds them."""
        out: list[int] = []
        for _, group in self.fields:
            s = schema.group(group)
            out += list(range(s.start, s.stop))
        return out

    def value_names(self, schema: NveSchema) -> tuple[str, ...]:
        """A name per value: JointState `field` (one name) or `field[name]`; PoseStamped,
        TwistStamped and WrenchStamped `field_axis` (`force_x`); Float64MultiArray its labels."""
        if self.msgtype == MULTIARRAY:
            return self.names
        out: list[str] = []
        for f, _ in self.fields:
            if self.msgtype == JOINT_STATE:
                out += [f] if len(self.names) == 1 else [f"{f}[{n}]" for n in self.names]
            else:
                out += [f"{f}_{a}" for a in schema.axis_labels]
        return tuple(out)


def nve_topics(schema: NveSchema) -> tuple[NveTopic, ...]:
    """Every per-tick topic of an NVE run, in the order its messages follow one another in a tick:
    the object, then per client (scene order) its HIP, the object as it uses it (pose, twist), its
    feedback force and its coupling facts."""
    pve = ("position", "velocity", "effort")
    server = tuple(zip(pve, SERVER_GROUPS, strict=True))
    out = [NveTopic("/nve/object/joint_states", JOINT_STATE, "", object_names(schema), server)]
    groups = COUPLING_GROUPS
    for c in schema.clients:
        out += [
            NveTopic(
                f"/nve/{c}/hip/joint_states",
                JOINT_STATE,
                "",
                hip_names(schema, c),
                tuple(zip(pve, (f"{c}.hip_x_m", f"{c}.hip_v_m_per_s", f"{c}.force_n"), strict=True)),
            ),
            NveTopic(f"/nve/{c}/object_pose", POSE, "world", (), (("position", f"{c}.obj_x_m"),)),
            NveTopic(f"/nve/{c}/object_twist", TWIST, "world", (), (("linear", f"{c}.obj_v_m_per_s"),)),
            NveTopic(f"/nve/{c}/feedback_wrench", WRENCH, "world", (), (("force", f"{c}.force_n"),)),
            NveTopic(f"/nve/{c}/coupling", MULTIARRAY, "", groups, tuple(("data", f"{c}.{g}") for g in groups)),
        ]
    return tuple(out)


def nve_clients(topics: list[str]) -> tuple[str, ...]:
    """The NVE clients a bag's topics name (their HIP topics), in the order given (connection
    order: the scene's)."""
    out = []
    for t in topics:
        m = re.fullmatch(r"/nve/([A-Za-z_][A-Za-z0-9_]*)/hip/joint_states", t)
        if m:
            out.append(m.group(1))
    return tuple(out)


def nve_schema_from_topics(topics: list[str], axes: int) -> NveSchema | None:
    """The schema of a bag from its topic names in connection order and the number of object
    axes; None if no topic is an NVE client's."""
    clients = nve_clients(topics)
    return NveSchema(clients, axes) if clients else None
