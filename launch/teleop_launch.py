"""ROS 2 launch file: the live node set of a scene, for a full ROS 2 install.

    ros2 launch haptic_teleop teleop_launch.py scene:=wall_contact [record:=/tmp/run1] [side:=all]
        [seed:=7] [duration:=5.0] [sim_time:=false]

The node set, names and parameters come from `haptic_teleop.launcher.node_plan`, the same plan
`haptic-teleop launch` starts, so both paths run the very same processes from the same scene file.
The run ends when the operator source finishes (after scene.duration_s); the first node that
exits non-zero shuts the launch down. Where the package runs without ROS 2's launch (the PyPI
wheels), use `haptic-teleop launch SCENE` instead.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction

from haptic_teleop.launch_support import launch_actions

ARGUMENTS = (
    ("scene", "wall_contact", "scene YAML path, or a bundled scene name"),
    ("record", "", "directory for the bag (DIR/bag); empty: no recording"),
    ("side", "all", "all | master | slave (two hosts: the nodes of one side)"),
    ("seed", "", "override scene.seed"),
    ("duration", "", "override scene.duration_s (seconds)"),
    ("sim_time", "false", "true: the nodes follow /clock (a clock node publishes it)"),
)


def generate_launch_description() -> LaunchDescription:
    args = [DeclareLaunchArgument(name, default_value=default, description=text) for name, default, text in ARGUMENTS]
    return LaunchDescription([*args, OpaqueFunction(function=launch_actions, kwargs={"device": "plant"})])
