"""The layout of the compiled 1-DoF loop's parameter vector P and state vector S (float64): one
block per side, then the operator and the clock. The host (axis_host.py) packs them from the
scene's objects and unpacks S after a run; the kernels (axis_kernel.py, codec_kernel.py) index them
with these compile-time constants."""

from __future__ import annotations

# Layout of the parameter vector P and the state vector S (float64), one block per side.
MASTER, SLAVE = 0, 32
# per side, in P
P_FORCE_LAW, P_GAIN, P_C1, P_C2, P_LIMIT, P_EBA_GAIN, P_BOUND_GAIN, P_EBA_ON = 0, 1, 2, 3, 4, 5, 6, 7
P_GUARD_ON, P_LIM0, P_LIM1, P_LIM2, P_PLANT_LIMIT, P_SUBSTEPS = 8, 9, 10, 11, 12, 13
P_ACT_LIMIT, P_SLEW_STEP = 14, 15  # the actuator limits the bound models (inf: none)
# the side's stabilizer (`controllers.<side>.eba.law`, the LAW_* codes) and its constants: TDPA's
# reflection and force cap, the initial energy; wave variables' s = sqrt(2 b), b, filter pole,
# drift gain; the guard's fourth limit (a TDPA sample's energy); the slave's wave matching (1: on)
P_LAW, P_REFLECT, P_CAP, P_E0, P_WAVE_S, P_WAVE_B, P_WAVE_A, P_DRIFT, P_LIM3 = 16, 17, 18, 19, 20, 21, 22, 23, 24
P_WAVE_MATCHED = 25
P_TDPA_ADMIT, P_TDPA_RECOVER = 26, 27  # TDPA's admittance placement (1: on) and its drift gain times T
# the operator and the clock, in P
OP = 64
P_PROFILE, P_X0, P_K, P_B, P_START, P_SPEED, P_T_END, P_X_END, P_AMP, P_W = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
P_MASS, P_DAMP = 10, 11  # imposed: the handle's mass and damping (operator.imposed_force1)
P_PERIOD_S = 80
P_SIZE = 81
PROFILE_CODES = {"push": 0, "sinusoid": 1, "hold": 2, "imposed": 3}
# The stabilizers the compiled loop runs: EBA's reservoir; TDPA with its velocity or zoh
# controller (core/tdpa.py); wave variables (core/wave.py).
LAW_RESERVOIR, LAW_TDPA_VELOCITY, LAW_TDPA_ZOH, LAW_WAVE, LAW_TWO_CONDITION = 0.0, 1.0, 2.0, 3.0, 4.0
# per side, in S (S_X0 on: the law's `AxisBoundState.extra`, TDPA_EXTRA or WAVE_EXTRA; S_OUT: a
# wave port's wave to send)
S_ENERGY, S_HELD, S_LAST, S_HAS_LAST, S_HAS_REMOTE, S_R0, S_R1, S_R2, S_REJECTED, S_CONTACT = range(10)
S_R3, S_OUT, S_X0 = 10, 11, 12
S_EXTRA = 6  # values from S_X0 on (the longer of TDPA_EXTRA and WAVE_EXTRA)
S_SIZE = 64
