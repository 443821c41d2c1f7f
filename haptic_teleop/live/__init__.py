"""Live mode's supervisor: the project's launcher (`launcher.py`, `haptic-teleop launch`) and the
ROS 2 launch files' support (`ros2_launch.py`)."""
