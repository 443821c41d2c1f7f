"""The layout of the compiled 1-DoF loop's parameter vector P and state vector S (float64): one
block per side, then the operator and the clock. The host (axis_host.py) packs them from the
scene's objects and unpacks S after a run; the kernels (axis_kernel.py, codec_kernel.py) index them
with these compile-time constants."""

from __future__ import annotations

# Layout of the parameter vector P and the state vector S (float64), one block per side.
MASTER, SLAVE = 0, 16
# per side, in P
P_FORCE_LAW, P_GAIN, P_C1, P_C2, P_LIMIT, P_EBA_GAIN, P_BOUND_GAIN, P_EBA_ON = 0, 1, 2, 3, 4, 5, 6, 7
P_GUARD_ON, P_LIM0, P_LIM1, P_LIM2, P_PLANT_LIMIT, P_SUBSTEPS = 8, 9, 10, 11, 12, 13
P_ACT_LIMIT, P_SLEW_STEP = 14, 15  # the actuator limits the bound models (inf: none)
# the operator and the clock, in P
OP = 32
P_PROFILE, P_X0, P_K, P_B, P_START, P_SPEED, P_T_END, P_X_END, P_AMP, P_W = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
P_MASS, P_DAMP = 10, 11  # imposed: the handle's mass and damping (operator.imposed_force1)
P_PERIOD_S = 48
P_SIZE = 49
PROFILE_CODES = {"push": 0, "sinusoid": 1, "hold": 2, "imposed": 3}
# per side, in S
S_ENERGY, S_HELD, S_LAST, S_HAS_LAST, S_HAS_REMOTE, S_R0, S_R1, S_R2, S_REJECTED, S_CONTACT = range(10)
S_SIZE = 32
