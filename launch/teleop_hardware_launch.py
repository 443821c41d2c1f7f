"""ROS 2 launch file, hardware variant: a real haptic device driver instead of the simulated operator.

    ros2 launch haptic_teleop teleop_hardware_launch.py scene:=wall_contact \
        state_topic:=/haptic_device/joint_states command_topic:=/haptic_device/force_command

The master reads the driver's sensor_msgs/JointState (position, velocity of axis 0) and sends the
force command as geometry_msgs/WrenchStamped (force.x); start the driver yourself. There is no
operator source, so the run lasts until Ctrl-C. Everything else is the node set of teleop_launch.py,
with its arguments (`single_process:=true`: every node composed in one process).

Arm scenes on real arms (docs/hardware.md): the side's arm is hosted in master_eba or slave_eba
through its driver, chosen by the scene's `<side>.backend`; the `set` argument takes scene
overrides separated by ';':

    ros2 launch haptic_teleop teleop_hardware_launch.py scene:=touch_dynamixel_wall \
        set:="slave.backend=dynamixel;slave.hardware.port=/dev/ttyUSB0" single_process:=true
"""

from haptic_teleop.live.ros2_launch import launch_description


def generate_launch_description():
    return launch_description(device="topic")
