"""The deterministic lockstep runner in simulated time and its compiled (numba) twins.

`lockstep` (Engine, record_run: the main job), `arm_loop` (the per-side arm tick and the Python
arm loop, shared with the live nodes), `compiled_loop` and `axis_kernel` (the compiled one-axis
loop), `compiled_arm_loop` and `arm_kernel` (the compiled arm loop). docs/architecture.md.
"""
