"""The deterministic lockstep runner in simulated time and its compiled (numba) twins.

`lockstep` (Engine, record_run: the main job), `arm_loop` (the per-side arm tick and the Python
arm loop, shared with the live nodes), `axis_host` and `axis_kernel` (the compiled one-axis
loop), `arm_host` and `arm_kernel` (the compiled arm loop). docs/architecture.md.
"""
