"""The compiled (numba) loops: hosts that pack a scene's objects into arrays and write their state
back (`axis_host.py`, `arm_host.py`, `codec_host.py`), the kernels (`*_kernel.py`), the axis
loop's layout (`layout.py`; the codecs' state layouts are core's `codec_layout.py`) and the driver
around every kernel (`windows.py`)."""
