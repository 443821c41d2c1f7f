"""The per-tick record schema: which columns one tick's row holds, and which bag topics carry them.

A run records one float64 row per tick. Its columns come in groups, per task axis `a` (x, y, z in
the shared task frame: the slave's world frame) or per joint `j` of a side:

    operator: op_x_m[a], op_v_m_per_s[a], op_force_n[a]
    master:   m_q[j], m_qd[j], m_tau_nm[j], m_x_m[a], m_v_m_per_s[a], m_force_n[a],
              m_force_desired_n[a], m_energy_j
    slave:    s_q[j], s_qd[j], s_tau_nm[j], s_x_m[a], s_v_m_per_s[a], s_force_n[a],
              s_force_desired_n[a], s_energy_j, s_contact_n[a], s_contact_torque_nm[a]
    network:  fwd_rx_seq, bwd_rx_seq, fwd_occupancy, bwd_occupancy
    measured: m_tau_measured_nm[j], s_tau_measured_nm[j]   (a side on hardware only)

The `measured` groups exist only for a side whose plant is a real device (`master_measured`,
`slave_measured`): the port torque its motors reported they applied over the hold that ended at
the tick's read (docs/hardware_plant.md, "Applied, not commanded"), beside `m_tau_nm`/`s_tau_nm`, the
torque commanded. They come after every other group, so a schema without them (every simulated
scene) has the columns, topics and bag bytes it always had.

A column is named `group[axis]` or `group[joint]` (`s_x_m[z]`, `m_q[yaw]`); a group of one column
is named as the group. The 1-axis schema (`ONE_DOF`: one slide joint per side moving along the
one task axis) has no separate joint columns: a slide joint's position, velocity and force are the
axis's, so `m_q`, `m_qd`, `m_tau_nm` name the same columns as `m_x_m`, `m_v_m_per_s`, `m_force_n`
(and the slave's alike), and `s_contact_torque_nm` is empty. Its columns are the 18 the 1-DoF
engine has always recorded, in the same order, so its bags keep their bytes.

`tick_topics` derives the bag's per-tick topics from a schema (docs/recording.md). This module is
pure (no ROS, no numpy): the bottom of the import graph for the engine, the recorder and the
analysis alike.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Literal

AXES = ("x", "y", "z")

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE = "geometry_msgs/msg/PoseStamped"
WRENCH = "geometry_msgs/msg/WrenchStamped"
MULTIARRAY = "std_msgs/msg/Float64MultiArray"

Kind = Literal["axis", "master_joint", "slave_joint", "one"]

# (group, kind) in record order.
_GROUPS: tuple[tuple[str, Kind], ...] = (
    ("op_x_m", "axis"),
    ("op_v_m_per_s", "axis"),
    ("op_force_n", "axis"),
    ("m_q", "master_joint"),
    ("m_qd", "master_joint"),
    ("m_tau_nm", "master_joint"),
    ("m_x_m", "axis"),
    ("m_v_m_per_s", "axis"),
    ("m_force_n", "axis"),
    ("m_force_desired_n", "axis"),
    ("m_energy_j", "one"),
    ("s_q", "slave_joint"),
    ("s_qd", "slave_joint"),
    ("s_tau_nm", "slave_joint"),
    ("s_x_m", "axis"),
    ("s_v_m_per_s", "axis"),
    ("s_force_n", "axis"),
    ("s_force_desired_n", "axis"),
    ("s_energy_j", "one"),
    ("s_contact_n", "axis"),
    ("s_contact_torque_nm", "axis"),
    ("fwd_rx_seq", "one"),
    ("bwd_rx_seq", "one"),
    ("fwd_occupancy", "one"),
    ("bwd_occupancy", "one"),
)
GROUPS = tuple(g for g, _ in _GROUPS)
# A hardware side's measured port torque (TickSchema.master_measured / slave_measured), after the rest.
MEASURED_GROUPS: dict[str, tuple[str, Kind]] = {
    "master": ("m_tau_measured_nm", "master_joint"),
    "slave": ("s_tau_measured_nm", "slave_joint"),
}

# In the 1-axis schema a slide joint's columns are the axis's; the contact has no torque.
_ONE_AXIS_ALIASES = {
    "m_q": "m_x_m",
    "m_qd": "m_v_m_per_s",
    "m_tau_nm": "m_force_n",
    "s_q": "s_x_m",
    "s_qd": "s_v_m_per_s",
    "s_tau_nm": "s_force_n",
}
_ONE_AXIS_EMPTY = ("s_contact_torque_nm",)

_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


class SchemaError(ValueError):
    """A tick schema that cannot be built (names, axes)."""


class ColumnLookup:
    """Names and indices of a tick row's columns, shared by the teleoperation schema (`TickSchema`)
    and the NVE one (record/nve_columns.py): `columns`, `col` (name -> index) and `_slices` (group
    -> slice of the row) are set by the schema; `_groups_allowed` says what `group` accepts."""

    columns: tuple[str, ...]
    col: dict[str, int]
    _slices: dict[str, slice]

    def _groups_allowed(self) -> str:
        raise NotImplementedError

    @property
    def width(self) -> int:
        """Columns per tick row."""
        return len(self.columns)

    def __len__(self) -> int:
        return len(self.columns)

    def group(self, name: str) -> slice:
        """The columns of one group (`schema.group("s_x_m")`), as a slice of the row."""
        try:
            return self._slices[name]
        except KeyError:
            raise SchemaError(f"no column group {name!r}; groups: {self._groups_allowed()}") from None

    def index(self, name: str) -> int:
        """The index of one column (`s_x_m[z]`, or a group of one column by the group's name)."""
        try:
            return self.col[name]
        except KeyError:
            raise SchemaError(f"no column {name!r} in this schema") from None

    def group_columns(self, name: str) -> tuple[str, ...]:
        return self.columns[self.group(name)]


@dataclass(frozen=True)
class TickSchema(ColumnLookup):
    """The columns of one tick's row for a master with `master_joints`, a slave with
    `slave_joints` and a task space of `task_axes` Cartesian axes (1: the 1-DoF slide; 3: x, y, z).
    `master_measured`, `slave_measured`: that side is a real device, whose row also holds the port
    torque it reported (`m_tau_measured_nm`, `s_tau_measured_nm`; not in a 1-axis schema)."""

    master_joints: tuple[str, ...]
    slave_joints: tuple[str, ...]
    task_axes: int
    master_measured: bool = False
    slave_measured: bool = False
    columns: tuple[str, ...] = field(init=False, repr=False, compare=False)
    col: dict[str, int] = field(init=False, repr=False, compare=False)
    _slices: dict[str, slice] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "master_joints", tuple(self.master_joints))
        object.__setattr__(self, "slave_joints", tuple(self.slave_joints))
        if type(self.task_axes) is not int or not 1 <= self.task_axes <= len(AXES):
            raise SchemaError(f"task_axes must be 1, 2 or 3; got {self.task_axes!r}")
        for side, joints in (("master", self.master_joints), ("slave", self.slave_joints)):
            if not joints:
                raise SchemaError(f"{side} joints: at least one joint name is needed")
            for j in joints:
                if not isinstance(j, str) or not _NAME.match(j):
                    raise SchemaError(f"{side} joint name {j!r}: letters, digits and _ only, not starting with a digit")
            if len(set(joints)) != len(joints):
                raise SchemaError(f"{side} joint names must be distinct; got {', '.join(joints)}")
        if self.task_axes == 1 and (len(self.master_joints) != 1 or len(self.slave_joints) != 1):
            raise SchemaError(
                "a 1-axis task has one slide joint per side; got "
                f"{len(self.master_joints)} master and {len(self.slave_joints)} slave joints"
            )
        for side in ("master", "slave"):
            flag = getattr(self, f"{side}_measured")
            if type(flag) is not bool:
                raise SchemaError(f"{side}_measured must be true or false; got {flag!r}")
        if self.single_axis and (self.master_measured or self.slave_measured):
            raise SchemaError("a 1-axis task has no measured torque columns (its sides are simulated)")
        columns: list[str] = []
        slices: dict[str, slice] = {}
        one = self.single_axis
        groups = _GROUPS + tuple(MEASURED_GROUPS[s] for s in ("master", "slave") if self.measured(s))
        for group, kind in groups:
            if one and group in _ONE_AXIS_ALIASES:
                continue
            if one and group in _ONE_AXIS_EMPTY:
                slices[group] = slice(len(columns), len(columns))
                continue
            labels = self._labels(kind)
            start = len(columns)
            columns += [group] if len(labels) == 1 and (kind == "one" or one) else [f"{group}[{x}]" for x in labels]
            slices[group] = slice(start, len(columns))
        if one:
            for alias, target in _ONE_AXIS_ALIASES.items():
                slices[alias] = slices[target]
        object.__setattr__(self, "columns", tuple(columns))
        object.__setattr__(self, "col", {c: i for i, c in enumerate(columns)})
        object.__setattr__(self, "_slices", slices)

    def _labels(self, kind: Kind) -> tuple[str, ...]:
        if kind == "axis":
            return self.axes
        if kind == "master_joint":
            return self.master_joints
        if kind == "slave_joint":
            return self.slave_joints
        return ("",)

    # -- names and indices
    @property
    def single_axis(self) -> bool:
        """The 1-DoF layout: one task axis, one slide joint per side, joint columns = axis columns."""
        return self.task_axes == 1

    @property
    def axes(self) -> tuple[str, ...]:
        return AXES[: self.task_axes]

    def _groups_allowed(self) -> str:
        return ", ".join((*GROUPS, *(MEASURED_GROUPS[s][0] for s in ("master", "slave") if self.measured(s))))

    def measured(self, side: str) -> bool:
        """Whether `side` ("master" or "slave") records the port torque its device reported."""
        if side == "master":
            return self.master_measured
        if side == "slave":
            return self.slave_measured
        raise SchemaError(f"side must be 'master' or 'slave'; got {side!r}")

    def joints(self, side: str) -> tuple[str, ...]:
        if side == "master":
            return self.master_joints
        if side == "slave":
            return self.slave_joints
        raise SchemaError(f"side must be 'master' or 'slave'; got {side!r}")

    # -- what the bag records of it
    def facts(self) -> dict[str, Any]:
        """The schema as plain data (JSON/YAML): `from_facts` rebuilds it."""
        out: dict[str, Any] = {
            "master_joints": list(self.master_joints),
            "slave_joints": list(self.slave_joints),
            "task_axes": self.task_axes,
        }
        for side in ("master", "slave"):  # only when set: a simulated run's facts keep their bytes
            if self.measured(side):
                out[f"{side}_measured"] = True
        return out

    @classmethod
    def from_facts(cls, facts: Any) -> TickSchema:
        if not isinstance(facts, dict):
            raise SchemaError(f"a tick schema is a mapping of master_joints, slave_joints, task_axes; got {facts!r}")
        try:
            return cls(
                tuple(facts["master_joints"]),
                tuple(facts["slave_joints"]),
                facts["task_axes"],
                facts.get("master_measured", False),
                facts.get("slave_measured", False),
            )
        except KeyError as exc:
            raise SchemaError(f"tick schema: no {exc} key") from None
        except TypeError as exc:
            raise SchemaError(f"tick schema: {exc}") from None


ONE_DOF = TickSchema(("master_x",), ("slave_x",), 1)


# ---------------------------------------------------------------------------------------------
# The bag's per-tick topics, derived from a schema.


@dataclass(frozen=True)
class TopicColumns:
    """One per-tick topic: its message type, header frame, names (JointState joint names or
    Float64MultiArray labels) and the column groups written into its fields, in field order.

    `fields` pairs a message field with a column group: JointState `position`, `velocity`,
    `effort` (one value per name); PoseStamped `position` (x, y, z; axes the task lacks are 0,
    orientation identity); WrenchStamped `force`, `torque` (as the pose); Float64MultiArray `data`
    (the groups back to back, one label per value)."""

    topic: str
    msgtype: str
    frame: str
    names: tuple[str, ...]
    fields: tuple[tuple[str, str], ...]
    eba: bool = False  # only with recording.eba_internals

    def columns(self, schema: TickSchema) -> list[int]:
        """The row indices of the values, in the order the message holds them."""
        out: list[int] = []
        for _, group in self.fields:
            s = schema.group(group)
            out += list(range(s.start, s.stop))
        return out

    def value_names(self, schema: TickSchema) -> tuple[str, ...]:
        """A name per value: JointState `field` (one joint) or `field[joint]`; PoseStamped and
        WrenchStamped `field_axis` (`force_x`); Float64MultiArray its labels."""
        if self.msgtype == MULTIARRAY:
            return self.names
        out: list[str] = []
        for f, group in self.fields:
            if self.msgtype == JOINT_STATE:
                out += [f] if len(self.names) == 1 else [f"{f}[{n}]" for n in self.names]
            else:
                s = schema.group(group)
                out += [f"{f}_{a}" for a in AXES[: s.stop - s.start]]
        return tuple(out)


def _eba(side: str, schema: TickSchema) -> TopicColumns:
    p = side[0]
    labels = ("reservoir_j", *(c[2:] for c in schema.group_columns(f"{p}_force_desired_n")))
    return TopicColumns(
        f"/{side}/eba", MULTIARRAY, "", labels, (("data", f"{p}_energy_j"), ("data", f"{p}_force_desired_n")), True
    )


def forward_names(schema: TickSchema) -> tuple[str, ...]:
    return tuple(f"master_{a}" for a in schema.axes)


def backward_names(schema: TickSchema) -> tuple[str, ...]:
    return tuple(f"slave_{a}" for a in schema.axes)


FORWARD_GROUPS = ("m_x_m", "m_v_m_per_s")
BACKWARD_GROUPS = ("s_x_m", "s_v_m_per_s", "s_contact_n")


def packet_topic(schema: TickSchema, topic: str) -> TopicColumns:
    """/forward/{sent,received} (the master handle's x, v) and /backward/{sent,received} (the
    slave tool's x, v and contact force): JointState with one name per task axis."""
    if topic.startswith("/forward/"):
        pairs = tuple(zip(("position", "velocity"), FORWARD_GROUPS, strict=True))
        return TopicColumns(topic, JOINT_STATE, "", forward_names(schema), pairs)
    pairs = tuple(zip(("position", "velocity", "effort"), BACKWARD_GROUPS, strict=True))
    return TopicColumns(topic, JOINT_STATE, "", backward_names(schema), pairs)


def measured_topic(side: str) -> str:
    """/master/measured_effort or /slave/measured_effort: a hardware side's reported port torque."""
    return f"/{side}/measured_effort"


def tick_topics(schema: TickSchema) -> tuple[TopicColumns, ...]:
    """Every per-tick topic of the schema, in the order its messages follow one another in a tick
    (a hardware side's /<side>/measured_effort right after its joint states; `eba` ones only with
    recording.eba_internals), then /forward/received and /backward/received
    (the samples a playout buffer released that tick: the columns of the tick they were sent)."""
    pve = ("position", "velocity", "effort")
    operator = TopicColumns(
        "/operator/joint_states",
        JOINT_STATE,
        "",
        tuple(f"operator_{a}" for a in schema.axes),
        tuple(zip(pve, ("op_x_m", "op_v_m_per_s", "op_force_n"), strict=True)),
    )
    master = TopicColumns(
        "/master/joint_states",
        JOINT_STATE,
        "",
        schema.master_joints,
        tuple(zip(pve, ("m_q", "m_qd", "m_tau_nm"), strict=True)),
    )
    slave = TopicColumns(
        "/slave/joint_states",
        JOINT_STATE,
        "",
        schema.slave_joints,
        tuple(zip(pve, ("s_q", "s_qd", "s_tau_nm"), strict=True)),
    )
    # A hardware side's measured port torque (only then: simulated bags keep their topics), its
    # joint names and `effort` alone.
    measured = {
        side: (
            TopicColumns(
                measured_topic(side), JOINT_STATE, "", schema.joints(side), (("effort", MEASURED_GROUPS[side][0]),)
            ),
        )
        if schema.measured(side)
        else ()
        for side in ("master", "slave")
    }
    if schema.single_axis:
        contact = TopicColumns("/slave/contact_wrench", WRENCH, "wall", (), (("force", "s_contact_n"),))
        task: tuple[TopicColumns, ...] = ()
    else:
        contact = TopicColumns(
            "/slave/contact_wrench", WRENCH, "world", (), (("force", "s_contact_n"), ("torque", "s_contact_torque_nm"))
        )
        task = (
            TopicColumns("/master/handle_pose", POSE, "world", (), (("position", "m_x_m"),)),
            TopicColumns("/slave/tool_pose", POSE, "world", (), (("position", "s_x_m"),)),
            TopicColumns("/master/rendered_wrench", WRENCH, "world", (), (("force", "m_force_n"),)),
            TopicColumns("/slave/applied_wrench", WRENCH, "world", (), (("force", "s_force_n"),)),
        )
    return (
        operator,
        master,
        *measured["master"],
        slave,
        *measured["slave"],
        contact,
        *task,
        _eba("master", schema),
        _eba("slave", schema),
        packet_topic(schema, "/forward/sent"),
        packet_topic(schema, "/backward/sent"),
        packet_topic(schema, "/forward/received"),
        packet_topic(schema, "/backward/received"),
    )
