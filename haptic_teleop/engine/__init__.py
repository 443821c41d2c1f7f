"""The deterministic lockstep runner in simulated time and its compiled (numba) loops.

`lockstep` (`Engine`: a scene's parts, run by the Python loop or a compiled one), `loop` (the one
Python tick over assembly's stages), `run` (`record_run`: the main job), `output` (sinks),
`reference` (the undisturbed reference run), `pacer` (wall-clock deadlines with a real device),
`nve_loop`, `excitation` (`identify`), `warm` (`haptic-teleop compile`), and `compiled/` (the numba
loops). docs/architecture.md.
"""
