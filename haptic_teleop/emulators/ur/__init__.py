"""A Universal Robots controller emulator (docs/ur_emulator.md): RTDE (30004), the dashboard server (29999),
the script ports (30002/30003) and an emulated ur_rtde control script driving a MuJoCo UR5e.

Start it with `process.start_ur(config)` or `python -m haptic_teleop.emulators.ur --config FILE`.
"""
