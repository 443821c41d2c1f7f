"""The compiled (numba) loops: hosts that pack a scene's objects into arrays and write their state
back (`axis_host.py`, `arm_host.py`, `codec_host.py`), the kernels (`*_kernel.py`), their layouts
(`layout.py`, `codec_layout.py`), the driver around every kernel (`windows.py`), MuJoCo's C calls
(`mujoco_native.py`), numba's cache kept honest (`cache.py`) and `haptic-teleop compile` (`warm.py`)."""
