"""Foxglove layouts for this stack's data, built with the SDK's own layout API (`foxglove.layouts`),
shipped as JSON in config/foxglove/ (`haptic-teleop` finds them: resources.foxglove_dir()):

- `bag_one_axis.json`: a one-axis scene's bag: forces (rendered to the operator, wall), positions
  (operator, master, slave), the EBA reservoirs, the buffers' released samples;
- `bag_arm.json`: an arm scene's bag: the rendered and contact forces and the handle's and tool's
  positions per task axis, the EBA reservoirs;
- `live.json`: the live view of `run --foxglove` / `launch --foxglove` (record/foxglove_view.py).

In Foxglove: Layouts, Import from file. `test/test_foxglove_view.py` checks that the shipped files are
what `layouts()` builds and that every path names a topic and field the bags and the view have.
"""

from __future__ import annotations

from typing import Any

AXES = ("x", "y", "z")


def _plot(title: str, series: list[tuple[str, str]]) -> Any:
    from foxglove.layouts import PlotConfig, PlotPanel, PlotSeries

    paths = [PlotSeries(value=value, label=label, timestamp_method="receiveTime") for value, label in series]
    return PlotPanel(title=title, config=PlotConfig(paths=paths, show_legend=True))


def _column(panels: list[Any]) -> Any:
    from foxglove.layouts import Layout, SplitContainer, SplitItem

    return Layout(content=SplitContainer(direction="column", items=[SplitItem(content=p) for p in panels]))


def layouts() -> dict[str, str]:
    """File name -> the layout's JSON."""
    reservoirs = _plot("EBA reservoirs (J)", [("/master/eba.data[0]", "master"), ("/slave/eba.data[0]", "slave")])
    one_axis = _column([
        _plot("forces (N)", [("/master/joint_states.effort[0]", "rendered to the operator"),
                             ("/slave/contact_wrench.wrench.force.x", "wall force")]),
        _plot("positions (m)", [("/operator/joint_states.position[0]", "operator"),
                                ("/master/joint_states.position[0]", "master"),
                                ("/slave/joint_states.position[0]", "slave")]),
        reservoirs,
        _plot("released samples (position, m)", [("/forward/received.position[0]", "forward (master's)"),
                                                 ("/backward/received.position[0]", "backward (slave's)")]),
    ])  # fmt: skip
    arm = _column([
        _plot("forces (N)", [(f"/master/rendered_wrench.wrench.force.{a}", f"rendered {a}") for a in AXES]
              + [(f"/slave/contact_wrench.wrench.force.{a}", f"contact {a}") for a in AXES]),
        _plot("positions (m)", [(f"/master/handle_pose.pose.position.{a}", f"handle {a}") for a in AXES]
              + [(f"/slave/tool_pose.pose.position.{a}", f"tool {a}") for a in AXES]),
        reservoirs,
    ])  # fmt: skip
    live = _column([
        _plot("forces (N)", [("/view/m.m_force_n", "rendered to the operator"), ("/view/s.s_contact_n", "wall")]),
        _plot("positions (m)", [("/view/op.op_x_m", "operator"), ("/view/m.m_x_m", "master"),
                                ("/view/s.s_x_m", "slave")]),
        _plot("EBA reservoirs (J)", [("/view/m.m_energy_j", "master"), ("/view/s.s_energy_j", "slave")]),
        _plot("playout buffers (samples held)", [("/view/fwd.fwd_occupancy", "forward"),
                                                 ("/view/bwd.bwd_occupancy", "backward")]),
    ])  # fmt: skip
    return {name: layout.to_json() + "\n" for name, layout in
            (("bag_one_axis.json", one_axis), ("bag_arm.json", arm), ("live.json", live))}  # fmt: skip


if __name__ == "__main__":  # regenerate the shipped files: python -m haptic_teleop.record.foxglove_layouts DIR
    import sys
    from pathlib import Path

    for name, text in layouts().items():
        (Path(sys.argv[1]) / name).write_text(text)
