"""The per-tick record schema (record/columns.py): names, groups, the topics derived from it."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from haptic_teleop.record.columns import ONE_DOF, SchemaError, TickSchema, tick_topics

# The 18 columns the 1-DoF engine has always recorded, in this order (its bags keep their bytes).
LEGACY = (
    "op_x_m", "op_v_m_per_s", "op_force_n",
    "m_x_m", "m_v_m_per_s", "m_force_n", "m_force_desired_n", "m_energy_j",
    "s_x_m", "s_v_m_per_s", "s_force_n", "s_force_desired_n", "s_energy_j", "s_contact_n",
    "fwd_rx_seq", "bwd_rx_seq", "fwd_occupancy", "bwd_occupancy",
)  # fmt: skip

ARM = TickSchema(("yaw", "shoulder", "elbow"), ("j1", "j2", "j3", "j4", "j5", "j6"), 3)


def test_one_dof_columns_are_the_legacy_ones() -> None:
    assert ONE_DOF.columns == LEGACY
    assert ONE_DOF.col == {c: i for i, c in enumerate(LEGACY)}
    # a slide joint's columns are the axis's; no contact torque in 1-D
    assert ONE_DOF.group("m_q") == ONE_DOF.group("m_x_m") == slice(3, 4)
    assert ONE_DOF.group("s_tau_nm") == ONE_DOF.group("s_force_n")
    assert ONE_DOF.group("s_contact_torque_nm") == slice(14, 14)


def test_arm_schema_groups() -> None:
    n = 3 * 3 + 3 * 3 + 3 * 4 + 1 + 6 * 3 + 3 * 4 + 1 + 3 + 3 + 4
    assert ARM.width == len(ARM.columns) == n
    assert len(set(ARM.columns)) == n
    for group in ("op_x_m", "m_x_m", "s_contact_n", "s_contact_torque_nm", "m_force_desired_n"):
        s = ARM.group(group)
        assert ARM.columns[s] == tuple(f"{group}[{a}]" for a in "xyz")
    assert ARM.columns[ARM.group("m_q")] == ("m_q[yaw]", "m_q[shoulder]", "m_q[elbow]")
    assert ARM.columns[ARM.group("s_tau_nm")] == tuple(f"s_tau_nm[j{i}]" for i in range(1, 7))
    assert ARM.columns[ARM.group("s_energy_j")] == ("s_energy_j",)
    assert ARM.index("s_x_m[z]") == ARM.group("s_x_m").start + 2
    # the groups tile the row, in order, without overlap
    covered = sorted(i for g in ("op_x_m", "op_v_m_per_s", "op_force_n", "m_q", "m_qd", "m_tau_nm", "m_x_m",
                                 "m_v_m_per_s", "m_force_n", "m_force_desired_n", "m_energy_j", "s_q", "s_qd",
                                 "s_tau_nm", "s_x_m", "s_v_m_per_s", "s_force_n", "s_force_desired_n", "s_energy_j",
                                 "s_contact_n", "s_contact_torque_nm", "fwd_rx_seq", "bwd_rx_seq", "fwd_occupancy",
                                 "bwd_occupancy") for i in range(ARM.group(g).start, ARM.group(g).stop))  # fmt: skip
    assert covered == list(range(n))
    assert TickSchema.from_facts(ARM.facts()) == ARM


@pytest.mark.parametrize(
    ("args", "words"),
    [
        ((("a",), ("b",), 4), "task_axes must be 1, 2 or 3"),
        (((), ("b",), 3), "master joints: at least one"),
        ((("a", "a"), ("b",), 3), "distinct"),
        ((("a b",), ("b",), 3), "letters, digits"),
        ((("a", "b"), ("c",), 1), "one slide joint per side"),
    ],
)
def test_bad_schemas_are_named(args: tuple[tuple[str, ...], tuple[str, ...], int], words: str) -> None:
    with pytest.raises(SchemaError, match=words):
        TickSchema(*args)
    with pytest.raises(SchemaError, match="no column group"):
        ARM.group("s_x")


def test_topics_derived_from_the_schema() -> None:
    one = {t.topic: t for t in tick_topics(ONE_DOF)}
    assert [one[t].columns(ONE_DOF) for t in ("/master/joint_states", "/slave/contact_wrench", "/backward/sent")] == [
        [3, 4, 5],
        [13],
        [8, 9, 13],
    ]
    assert "/slave/tool_pose" not in one
    arm = {t.topic: t for t in tick_topics(ARM)}
    js = arm["/slave/joint_states"]
    assert js.names == ARM.slave_joints
    assert js.columns(ARM) == list(range(ARM.group("s_q").start, ARM.group("s_tau_nm").stop))
    wrench = tuple(f"{f}_{a}" for f in ("force", "torque") for a in "xyz")
    assert arm["/slave/contact_wrench"].value_names(ARM) == wrench
    assert arm["/slave/tool_pose"].columns(ARM) == list(range(ARM.group("s_x_m").start, ARM.group("s_x_m").stop))
    assert arm["/forward/sent"].names == ("master_x", "master_y", "master_z")


def test_record_layer_does_not_import_the_engine() -> None:
    root = Path(__file__).resolve().parents[1] / "haptic_teleop" / "record"
    for path in root.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                mod = node.module or ""
                below = ("haptic_teleop.record", "haptic_teleop.errors", "haptic_teleop.lifetime")
                assert not mod.startswith("haptic_teleop.") or mod.startswith(below), f"{path.name} imports {mod}"
