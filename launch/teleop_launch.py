"""ROS 2 launch file: the live node set of a scene, for a full ROS 2 install.

    ros2 launch haptic_teleop teleop_launch.py scene:=wall_contact [record:=/tmp/run1] [side:=all]
        [seed:=7] [duration:=5.0] [sim_time:=false] [single_process:=false]

The node set, names and parameters come from `haptic_teleop.live.launcher.node_plan`, the same plan
`haptic-teleop launch` starts, so both paths run the very same processes from the same scene file
(arguments and rules: `haptic_teleop.live.ros2_launch`). The run ends when the operator source
finishes (after scene.duration_s): exit 0; a node that exits non-zero stops every node and the
launch exits 1, naming it. `single_process:=true` starts one process instead, every node composed
in it with one shared loop thread (`haptic-teleop launch --single-process`; recommended on a small
machine, 2 vCPUs): it exits 0 when the scene is over, non-zero (the launch exits 1) on a failure.
Where the package runs without ROS 2's launch (the PyPI wheels), use `haptic-teleop launch SCENE`.
"""

from haptic_teleop.live.ros2_launch import launch_description


def generate_launch_description():
    return launch_description(device="plant")
