"""ROS 2 launch file, hardware variant: a real haptic device driver instead of the simulated operator.

    ros2 launch haptic_teleop teleop_hardware_launch.py scene:=wall_contact \
        state_topic:=/haptic_device/joint_states command_topic:=/haptic_device/force_command

The master reads the driver's sensor_msgs/JointState (position, velocity of axis 0) and sends the
force command as geometry_msgs/WrenchStamped (force.x); start the driver yourself. There is no
operator source, so the run lasts until Ctrl-C. Everything else is the node set of teleop_launch.py.
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
    ("sim_time", "false", "true: the nodes follow /clock"),
    ("state_topic", "/haptic_device/joint_states", "the device driver's sensor_msgs/JointState"),
    ("command_topic", "/haptic_device/force_command", "force command to the driver (WrenchStamped)"),
)


def generate_launch_description() -> LaunchDescription:
    args = [DeclareLaunchArgument(name, default_value=default, description=text) for name, default, text in ARGUMENTS]
    return LaunchDescription([*args, OpaqueFunction(function=launch_actions, kwargs={"device": "topic"})])
