"""ROS 2 launch file: the live node set of an NVE scene (a consistency server, its clients, and a
relay and a sync buffer per direction of each client's link pair), for a full ROS 2 install.

    ros2 launch haptic_teleop nve_launch.py scene:=nve_push [duration:=5.0] [seed:=7]
        [set:="nve.clients.0.up.effects.delay.delay_s=0.05;nve.clients.0.down.effects.delay.delay_s=0.05"]
        [sim_time:=false] [record:=DIR] [single_process:=false]

The node set, names and parameters come from `haptic_teleop.live.launcher.node_plan`, the same plan
`haptic-teleop launch nve_push` starts (docs/live_nve.md, "NVE scenes live"). With `record:=DIR` a
recorder writes DIR/bag. The run ends when the server finishes (after scene.duration_s); the first
node that exits non-zero stops every node and the launch exits 1, naming it. `single_process:=true`:
every node composed in one process with one shared loop thread (as teleop_launch.py's).
Where the package runs without ROS 2's launch (the PyPI wheels), use `haptic-teleop launch SCENE`.
"""

from haptic_teleop.live.ros2_launch import launch_description


def generate_launch_description():
    return launch_description(device="plant", scene_type="nve")
