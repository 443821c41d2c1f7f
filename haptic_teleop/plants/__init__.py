"""Things that move: the `Plant` protocol and the backend registry (`base.py`), the MuJoCo plants,
the real arms and their drivers. A backend's SDK (mujoco, dynamixel_sdk, rtde) is imported inside
its module, so this package imports without them; plants are built from a scene by
assembly/plants.py."""
