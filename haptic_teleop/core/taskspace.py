"""Teleoperation in task space: the workspace mapping, the coupling laws on vectors, joint torques.

Conventions (docs/eba_many_joints.md, "Many joints"): the task frame is the slave's world frame, 3-D
Cartesian, metres. The master's handle point lives in the master device's base frame and
`WorkspaceMapping` maps it over; forces come back the other way. The coupling law gives a task
force (and, for a 6-DoF slave, a moment from the orientation coupling); `jacobian_transpose`
turns it into joint torques, `null_space_damping` damps the self-motion of a redundant arm, and
the caller adds gravity compensation. The torque vector then goes through the joints' pooled
energy bound (`haptic_teleop.core.eba_coupled.CoupledEnergyBound`).

The per-tick functions work in place on float64 numpy arrays with plain loops and no Python
objects: the same definitions run interpreted and compiled by numba (each formula exists once).
Arrays: vectors are 1-D; a Jacobian is a C-ordered (m, n) array (m = 3 rows of `mj_jacSite`'s
`jacp`, or 6 = `jacp` over `jacr`), n the joints; rotation matrices are (3, 3) and map a vector
of the rotated frame into the reference frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from haptic_teleop.core import eba, eba_coupled
from haptic_teleop.core.eba import coupling1

Vec = npt.NDArray[np.float64]
Mat = npt.NDArray[np.float64]

TASK_LAWS = ("position", "force")
ORIENTATIONS = ("free", "hold")

# Damping factor of the pseudo-inverse in the null-space projector (metres: the Jacobian's position
# rows are m/rad). Directions whose task gain (singular value of J) is well above it count as task
# directions and are not damped; directions well below it count as self-motion and are. A damped
# projector is continuous through singularities, where the undamped one jumps (docs/eba_many_joints.md).
PINV_DAMPING_M = 0.01

_ROTATION_TOL = 1e-9


def _identity(d: int) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(1.0 if i == j else 0.0 for j in range(d)) for i in range(d))


def rotation_from_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> tuple[tuple[float, ...], ...]:
    """R = Rz(yaw) Ry(pitch) Rx(roll) as nested tuples (a convenience to build `WorkspaceMapping.rotation`)."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


# --------------------------------------------------------------------------------------------
# Per-tick functions: plain loops over float64 arrays, results written into `out`.


def map_point(out: Vec, rot: Mat, scale: float, offset: Vec, x: Vec) -> None:
    """out = scale * rot @ x + offset (master position -> task position)."""
    d = x.shape[0]
    for i in range(d):
        s = 0.0
        for j in range(d):
            s += rot[i, j] * x[j]
        out[i] = scale * s + offset[i]


def unmap_point(out: Vec, rot: Mat, scale: float, offset: Vec, x: Vec) -> None:
    """out = rot.T @ (x - offset) / scale (task position -> master position)."""
    d = x.shape[0]
    for i in range(d):
        s = 0.0
        for j in range(d):
            s += rot[j, i] * (x[j] - offset[j])
        out[i] = s / scale


def map_vector(out: Vec, rot: Mat, scale: float, x: Vec) -> None:
    """out = scale * rot @ x (master velocity -> task velocity; task force -> master with `map_vector_back`)."""
    d = x.shape[0]
    for i in range(d):
        s = 0.0
        for j in range(d):
            s += rot[i, j] * x[j]
        out[i] = scale * s


def map_vector_back(out: Vec, rot: Mat, scale: float, x: Vec) -> None:
    """out = scale * rot.T @ x (task force -> master force with scale = force_scale)."""
    d = x.shape[0]
    for i in range(d):
        s = 0.0
        for j in range(d):
            s += rot[j, i] * x[j]
        out[i] = scale * s


def coupling(out: Vec, c1: Vec, c2: Vec, remote_x: Vec, remote_v: Vec, x: Vec, v: Vec) -> None:
    """Spring c1 and damper c2 per axis towards the remote sample: `eba.coupling1` on every axis."""
    for i in range(x.shape[0]):
        out[i] = coupling1(c1[i], c2[i], remote_x[i], remote_v[i], x[i], v[i])


def force_feedback(out: Vec, gain: float, remote_force: Vec) -> None:
    """Force reflection: out = gain * remote force (the `force` law of `TeleopController`)."""
    for i in range(remote_force.shape[0]):
        out[i] = gain * remote_force[i]


def tick_scratch(rows: int, joints: int) -> Mat:
    """The work array of the tick's functions that need matrices of their own (`null_space_damping`,
    `task_force_of`, `orientation_coupling`), for a Jacobian of `rows` x `joints`: K + 2 rows of K
    values, K = max(rows, joints, 3). They allocate nothing, so the compiled loops run them without
    numba's reference counting."""
    k = max(rows, joints, 3)
    return np.zeros((k + 2, k))


def orientation_error(out: Vec, r_hold: Mat, r_tool: Mat, work: Mat) -> None:
    """Rotation vector (axis * angle, rad, world frame) that turns the tool's orientation into the held one.

    The log map of R = r_hold @ r_tool.T, exact for every angle in [0, pi]: away from pi from the
    skew part (sin(theta) * axis), near pi (where the skew part vanishes) from the symmetric part.
    work: `tick_scratch` (R in its first 3 x 3, the axis near pi in its fourth row).
    """
    r = work[:3, :3]
    for i in range(3):
        for j in range(3):
            s = 0.0
            for k in range(3):
                s += r_hold[i, k] * r_tool[j, k]
            r[i, j] = s
    wx = 0.5 * (r[2, 1] - r[1, 2])
    wy = 0.5 * (r[0, 2] - r[2, 0])
    wz = 0.5 * (r[1, 0] - r[0, 1])
    sin_t = math.sqrt(wx * wx + wy * wy + wz * wz)
    cos_t = 0.5 * (r[0, 0] + r[1, 1] + r[2, 2] - 1.0)
    theta = math.atan2(sin_t, cos_t)
    if cos_t > -0.9:
        # theta / sin(theta) -> 1 as theta -> 0 (series below 1e-6 rad: no 0 / 0).
        f = 1.0 + theta * theta / 6.0 if sin_t < 1e-6 else theta / sin_t
        out[0] = f * wx
        out[1] = f * wy
        out[2] = f * wz
        return
    # Near pi: R + R.T = 2 cos(t) I + 2 (1 - cos(t)) a a.T; take the largest diagonal entry's column.
    k = 0
    if r[1, 1] > r[k, k]:
        k = 1
    if r[2, 2] > r[k, k]:
        k = 2
    one_c = 1.0 - cos_t
    a = work[3, :3]
    for i in range(3):
        a[i] = 0.5 * (r[i, k] + r[k, i]) / one_c
    a[k] = math.sqrt(max((r[k, k] - cos_t) / one_c, 0.0))
    for i in range(3):
        if i != k:
            a[i] /= a[k]
    norm = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    # The skew part fixes the sign (a and -a are the same rotation at exactly pi).
    sign = -1.0 if a[0] * wx + a[1] * wy + a[2] * wz < 0.0 else 1.0
    for i in range(3):
        out[i] = sign * theta * a[i] / norm


def orientation_coupling(out: Vec, k_rot: Vec, d_rot: Vec, r_hold: Mat, r_tool: Mat, omega: Vec, work: Mat) -> None:
    """Moment (N m, world frame) holding the tool at r_hold: k_rot * error - d_rot * omega per axis
    (work: `tick_scratch`)."""
    orientation_error(out, r_hold, r_tool, work)
    for i in range(3):
        out[i] = k_rot[i] * out[i] - d_rot[i] * omega[i]


def jacobian_times(out: Vec, jac: Mat, qd: Vec) -> None:
    """out = jac @ qd (task velocity of the point from joint velocities)."""
    m, n = jac.shape
    for i in range(m):
        s = 0.0
        for j in range(n):
            s += jac[i, j] * qd[j]
        out[i] = s


def jacobian_transpose(out: Vec, jac: Mat, wrench: Vec) -> None:
    """out = jac.T @ wrench (joint torques that exert the task force/wrench at the point)."""
    m, n = jac.shape
    for j in range(n):
        s = 0.0
        for i in range(m):
            s += jac[i, j] * wrench[i]
        out[j] = s


def _cholesky(a: Mat) -> None:
    """In place: the lower triangle of `a` (symmetric positive definite) becomes L with a = L L.T,
    its diagonal stored as 1 / L[j, j] (`_cholesky_solve` multiplies by it: one division a column
    instead of one an entry and two a solved row; 0.32 -> 0.27 us for the 6 x 6 null-space damping)."""
    m = a.shape[0]
    for j in range(m):
        s = a[j, j]
        for k in range(j):
            s -= a[j, k] * a[j, k]
        r = 1.0 / math.sqrt(s)
        a[j, j] = r
        for i in range(j + 1, m):
            s = a[i, j]
            for k in range(j):
                s -= a[i, k] * a[j, k]
            a[i, j] = s * r


def _cholesky_solve(low: Mat, b: Vec) -> None:
    """In place: b becomes x with (L L.T) x = b, `low` as `_cholesky` leaves it (L's lower triangle,
    its diagonal inverted)."""
    m = low.shape[0]
    for i in range(m):
        s = b[i]
        for k in range(i):
            s -= low[i, k] * b[k]
        b[i] = s * low[i, i]
    for i in range(m - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, m):
            s -= low[k, i] * b[k]
        b[i] = s * low[i, i]


def _gram_of_rows(a: Mat, jac: Mat) -> None:
    """a (m x m) = J J.T, each entry summed over the joints in order (symmetric: computed once)."""
    m, n = jac.shape
    for i in range(m):
        for k in range(i + 1):
            s = 0.0
            for j in range(n):
                s += jac[i, j] * jac[k, j]
            a[i, k] = s
            a[k, i] = s


def _gram_of_columns(b: Mat, jac: Mat) -> None:
    """b (n x n) = J.T J, each entry summed over the task rows in order (symmetric: computed once)."""
    m, n = jac.shape
    for i in range(n):
        for k in range(i + 1):
            s = 0.0
            for j in range(m):
                s += jac[j, i] * jac[j, k]
            b[i, k] = s
            b[k, i] = s


def _project(out: Vec, jac: Mat, low: Mat, x: Vec, tmp: Vec) -> None:
    """out = N x with N = I - J.T (J J.T + mu^2 I)^-1 J, `low` the Cholesky factor of J J.T + mu^2 I."""
    jacobian_times(tmp, jac, x)
    _cholesky_solve(low, tmp)
    jacobian_transpose(out, jac, tmp)
    for j in range(x.shape[0]):
        out[j] = x[j] - out[j]


def null_space_damping(out: Vec, jac: Mat, qd: Vec, d_null: Vec, mu: float, work: Mat) -> None:
    """Damping of the self-motion of a redundant arm: out = -N D N qd (N.T = N), D = diag(d_null).

    N = I - J.T J.T+ with the damped pseudo-inverse J.T+ = (J J.T + mu^2 I)^-1 J, that is
    N = mu^2 (J.T J + mu^2 I)^-1: symmetric, eigenvalues mu^2 / (sigma^2 + mu^2) in (0, 1].
    Dissipative for any J and qd: qd.T out = -(N qd).T D (N qd) <= 0. (The form -N D qd is not,
    unless D is a multiple of I: N D is not symmetric.)

    Computed in the smaller of the two forms: with fewer task rows than joints (m < n) from the
    m x m factor of J J.T + mu^2 I (`_project`); otherwise (a square Jacobian, the UR5e's 6 x 6)
    as -mu^4 B^-1 D B^-1 qd with B = J.T J + mu^2 I, two solves with one n x n factor and no
    products with J (0.32 against 0.50 us for a 6 x 6 Jacobian; the two agree to 1e-12 relative).
    work: `tick_scratch` (the factor in its top left, the projections' vectors in the rows below).
    """
    m, n = jac.shape
    if m >= n:
        b = work[:n, :n]
        _gram_of_columns(b, jac)
        for i in range(n):
            b[i, i] += mu * mu
        _cholesky(b)
        for j in range(n):
            out[j] = qd[j]
        _cholesky_solve(b, out)
        mu4 = mu * mu * mu * mu
        for j in range(n):
            out[j] *= d_null[j] * mu4
        _cholesky_solve(b, out)
        for j in range(n):
            out[j] = -out[j]
        return
    a = work[:m, :m]
    _gram_of_rows(a, jac)
    for i in range(m):
        a[i, i] += mu * mu
    _cholesky(a)
    tmp = work[m, :m]
    p = work[m + 1, :n]
    _project(p, jac, a, qd, tmp)
    for j in range(n):
        p[j] *= d_null[j]
    _project(out, jac, a, p, tmp)
    for j in range(n):
        out[j] = -out[j]


def task_force_of(out: Vec, jac: Mat, tau: Vec, work: Mat) -> None:
    """out (m values) = the task force (or wrench) F whose J.T F is closest to tau: least squares,
    from the normal equations (J J.T + eps I) F = J tau with this module's Cholesky; eps = 1e-12
    trace(J J.T) / m keeps a rank-deficient J solvable (its F then the damped solution) and moves a
    full-rank one's by about 1e-12 relative. What a torque that is no scaled copy of the desired one
    renders at the point (TDPA's velocity controller on an arm, docs/stabilizers_arms.md). work:
    `tick_scratch` (the factor in its top left)."""
    m = jac.shape[0]
    a = work[:m, :m]
    _gram_of_rows(a, jac)
    trace = 0.0
    for i in range(m):
        trace += a[i, i]
    eps = 1e-12 * trace / m if trace > 0.0 else 1e-300
    for i in range(m):
        a[i, i] += eps
    _cholesky(a)
    jacobian_times(out, jac, tau)
    _cholesky_solve(a, out)


def add_into(out: Vec, x: Vec) -> None:
    """out += x (gravity compensation added to the bounded torque, for example)."""
    for i in range(out.shape[0]):
        out[i] += x[i]


# --------------------------------------------------------------------------------------------
# Compiling the per-tick functions.

# Every array function of the n-joint tick (eba's bound, this module's laws) that the Python arm
# tick calls by name; the caller compiles each with its callees (compiling.compile_tree: core does
# not import numba).
KERNEL_FUNCTIONS: tuple[Callable[..., Any], ...] = (
    eba.reservoir1,
    eba.bounded1,
    eba.ramp_limit1,
    eba.actuator_bounded1,
    eba.coupling1,
    eba_coupled.coupled_reservoir,
    eba_coupled.coupled_demand,
    eba_coupled.descent_cost1,
    eba_coupled.coupled_descent_cost,
    eba_coupled.coupled_scale,
    eba_coupled.coupled_bounded,
    eba_coupled.joint_limited,
    eba_coupled.slew_bounded,
    eba_coupled.task_demand,
    map_point,
    unmap_point,
    map_vector,
    map_vector_back,
    coupling,
    force_feedback,
    orientation_error,
    orientation_coupling,
    jacobian_times,
    jacobian_transpose,
    null_space_damping,
    task_force_of,
    add_into,
)


# --------------------------------------------------------------------------------------------
# Configuration and a per-side object for the Python loop.


def _vector(name: str, values: Sequence[float], size: int, positive: bool) -> None:
    if len(values) != size:
        raise ValueError(f"{name} must have {size} values, got {len(values)}")
    for v in values:
        if not math.isfinite(v) or (positive and not v > 0.0):
            raise ValueError(f"{name} must be finite{' and > 0' if positive else ''}, got {tuple(values)}")


@dataclass(frozen=True)
class WorkspaceMapping:
    """Master device frame -> task frame (the slave's world frame).

    x_s = scale * R @ x_m + offset_m,  v_s = scale * R @ v_m,  f_m = force_scale * R.T @ f_s,
    and the inverses. `rotation` is the 3x3 matrix R (rows of nested tuples, proper: R R.T = I and
    det R = +1 within 1e-9); `rotation_from_rpy` builds one from roll-pitch-yaw. `dim=1` is the
    one-axis special case (R = [[1]], offset (0,)): with scale 1 and force_scale 1 every map is the
    identity, so the 1-DoF law is unchanged.
    """

    scale: float = 1.0
    rotation: tuple[tuple[float, ...], ...] = field(default_factory=lambda: _identity(3))
    offset_m: tuple[float, ...] = (0.0, 0.0, 0.0)
    force_scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("scale", "force_scale"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"workspace mapping: {name} must be finite and > 0, got {v}")
        d = len(self.rotation)
        if d not in (1, 3) or any(len(row) != d for row in self.rotation):
            raise ValueError(f"workspace mapping: rotation must be a 3x3 (or 1x1) matrix, got {self.rotation}")
        r = np.array(self.rotation, dtype=float)
        if not np.all(np.isfinite(r)):
            raise ValueError(f"workspace mapping: rotation must be finite, got {self.rotation}")
        if not np.allclose(r @ r.T, np.eye(d), rtol=0.0, atol=_ROTATION_TOL) or not (
            abs(float(np.linalg.det(r)) - 1.0) <= _ROTATION_TOL
        ):
            raise ValueError(
                "workspace mapping: rotation must be a proper rotation matrix (R R^T = I, det R = +1 "
                f"within {_ROTATION_TOL}), got {self.rotation}"
            )
        if len(self.offset_m) != d:
            raise ValueError(f"workspace mapping: offset_m must have {d} values, got {self.offset_m}")
        _vector("workspace mapping: offset_m", self.offset_m, d, positive=False)
        object.__setattr__(self, "_r", r)
        object.__setattr__(self, "_o", np.array(self.offset_m, dtype=float))

    @classmethod
    def identity(cls, dim: int = 3) -> WorkspaceMapping:
        """The identity map in `dim` (1 or 3) dimensions."""
        return cls(rotation=_identity(dim), offset_m=(0.0,) * dim)

    @property
    def dim(self) -> int:
        return len(self.rotation)

    @property
    def matrix(self) -> Mat:
        """R as a (d, d) float64 array (do not modify)."""
        r: Mat = self.__dict__["_r"]
        return r

    @property
    def offset(self) -> Vec:
        """offset_m as a float64 array (do not modify)."""
        o: Vec = self.__dict__["_o"]
        return o

    def position_to_task(self, x_m: Vec) -> Vec:
        out = np.empty(self.dim)
        map_point(out, self.matrix, self.scale, self.offset, x_m)
        return out

    def position_to_master(self, x_s: Vec) -> Vec:
        out = np.empty(self.dim)
        unmap_point(out, self.matrix, self.scale, self.offset, x_s)
        return out

    def velocity_to_task(self, v_m: Vec) -> Vec:
        out = np.empty(self.dim)
        map_vector(out, self.matrix, self.scale, v_m)
        return out

    def velocity_to_master(self, v_s: Vec) -> Vec:
        out = np.empty(self.dim)
        map_vector_back(out, self.matrix, 1.0 / self.scale, v_s)
        return out

    def force_to_master(self, f_s: Vec) -> Vec:
        out = np.empty(self.dim)
        map_vector_back(out, self.matrix, self.force_scale, f_s)
        return out

    def force_to_task(self, f_m: Vec) -> Vec:
        out = np.empty(self.dim)
        map_vector(out, self.matrix, 1.0 / self.force_scale, f_m)
        return out


@dataclass(frozen=True)
class TaskCouplingParams:
    """One side's task-space law (before the energy bound).

    law "position": F = c1 (x_remote - x) + c2 (v_remote - v) per task axis (the scalar
    `coupling1` of the 1-DoF controller on each axis); law "force" (master only):
    F = force_gain * f_remote. orientation (6-DoF slave): "free" (3 x n Jacobian, the
    orientation is left to the arm and the null-space damping) or "hold" (6 x n Jacobian, moment
    k_rot * error - d_rot * omega towards a held orientation: the start orientation unless the
    caller sets another). null_damping_nm_s_per_rad: per joint (empty: none) for redundant arms.
    """

    law: str = "position"
    stiffness_n_per_m: tuple[float, ...] = (1000.0, 1000.0, 1000.0)
    damping_n_s_per_m: tuple[float, ...] = (10.0, 10.0, 10.0)
    force_gain: float = 1.0
    orientation: str = "free"
    rot_stiffness_nm_per_rad: tuple[float, ...] = (0.0, 0.0, 0.0)
    rot_damping_nm_s_per_rad: tuple[float, ...] = (0.0, 0.0, 0.0)
    null_damping_nm_s_per_rad: tuple[float, ...] = ()
    pinv_damping_m: float = PINV_DAMPING_M

    def __post_init__(self) -> None:
        if self.law not in TASK_LAWS:
            raise ValueError(f"law must be one of {TASK_LAWS}, got {self.law!r}")
        if self.orientation not in ORIENTATIONS:
            raise ValueError(f"orientation must be one of {ORIENTATIONS}, got {self.orientation!r}")
        d = len(self.stiffness_n_per_m)
        if d not in (1, 3):
            raise ValueError(f"stiffness_n_per_m must have 1 or 3 values (task axes), got {self.stiffness_n_per_m}")
        _vector("damping_n_s_per_m", self.damping_n_s_per_m, d, positive=False)
        for name in ("stiffness_n_per_m", "damping_n_s_per_m", "rot_stiffness_nm_per_rad", "rot_damping_nm_s_per_rad"):
            values = getattr(self, name)
            if any(not (math.isfinite(v) and v >= 0.0) for v in values):
                raise ValueError(f"{name} must be finite and >= 0, got {values}")
        for name in ("rot_stiffness_nm_per_rad", "rot_damping_nm_s_per_rad"):
            if len(getattr(self, name)) != 3:
                raise ValueError(f"{name} must have 3 values, got {getattr(self, name)}")
        if self.orientation == "hold" and d != 3:
            raise ValueError("orientation 'hold' needs a 3-axis task")
        if any(not (math.isfinite(v) and v >= 0.0) for v in self.null_damping_nm_s_per_rad):
            raise ValueError(f"null_damping_nm_s_per_rad must be finite and >= 0, got {self.null_damping_nm_s_per_rad}")
        if not (math.isfinite(self.force_gain)):
            raise ValueError(f"force_gain must be finite, got {self.force_gain}")
        if not (math.isfinite(self.pinv_damping_m) and self.pinv_damping_m > 0.0):
            raise ValueError(f"pinv_damping_m must be finite and > 0, got {self.pinv_damping_m}")

    @property
    def axes(self) -> int:
        return len(self.stiffness_n_per_m)

    @property
    def wrench_rows(self) -> int:
        """Rows of the Jacobian this law needs: 3 (or 1) for the point, 6 with the orientation held."""
        return 6 if self.orientation == "hold" else self.axes


@dataclass(frozen=True)
class TaskLawConstants:
    """The arrays a `TaskSpaceLaw` builds from its parameters once and uses every tick (copies:
    `TaskSpaceLaw.constants`); the compiled arm loop (engine/compiled/arm_host.py) takes them from here.

    stiffness/damping: c1, c2 per task axis (`coupling`); rot_stiffness/rot_damping: k_rot, d_rot
    (`orientation_coupling`); null_damping: per joint (zeros without); null_space: whether the
    null-space damping runs at all.
    """

    stiffness_n_per_m: Vec
    damping_n_s_per_m: Vec
    rot_stiffness_nm_per_rad: Vec
    rot_damping_nm_s_per_rad: Vec
    null_damping_nm_s_per_rad: Vec
    null_space: bool


class TaskSpaceLaw:
    """One side's task-space law for `joints` joints: wrench, then joint torques, every tick.

    `torque(...)` returns the desired joint torque J.T @ wrench + null-space damping (before the
    energy bound; the caller bounds it with `CoupledEnergyBound` and then adds gravity
    compensation, which is the plant's own potential and not part of the port). The returned
    arrays are the object's own, overwritten every tick. kernels: the array functions by name
    (assembly.parts.arm_kernels gives them compiled); None: this module's, interpreted.
    """

    __slots__ = (
        "_c1",
        "_c2",
        "_d_rot",
        "_f",
        "_k_rot",
        "_null",
        "_null_d",
        "_omega",
        "_tmp",
        "_work",
        "joints",
        "params",
        "r_hold",
        "torque_nm",
        "wrench",
    )

    def __init__(
        self, params: TaskCouplingParams, joints: int, kernels: Mapping[str, Callable[..., Any]] | None = None
    ) -> None:
        if joints < 1:
            raise ValueError(f"joints must be >= 1, got {joints}")
        if params.null_damping_nm_s_per_rad and len(params.null_damping_nm_s_per_rad) != joints:
            raise ValueError(
                f"null_damping_nm_s_per_rad must have one value per joint ({joints}), "
                f"got {params.null_damping_nm_s_per_rad}"
            )
        self.params = params
        self.joints = joints
        self._c1 = np.array(params.stiffness_n_per_m, dtype=float)
        self._c2 = np.array(params.damping_n_s_per_m, dtype=float)
        self._k_rot = np.array(params.rot_stiffness_nm_per_rad, dtype=float)
        self._d_rot = np.array(params.rot_damping_nm_s_per_rad, dtype=float)
        self._null = bool(params.null_damping_nm_s_per_rad) and any(params.null_damping_nm_s_per_rad)
        self._null_d = np.array(params.null_damping_nm_s_per_rad or (0.0,) * joints, dtype=float)
        self.wrench = np.zeros(params.wrench_rows)
        self.torque_nm = np.zeros(joints)
        self._tmp = np.zeros(joints)
        self._work = tick_scratch(params.wrench_rows, joints)
        self._omega = np.zeros(3)
        self.r_hold: Mat | None = None  # the held orientation; None: taken from the first tick
        plain = {fn.__name__: fn for fn in KERNEL_FUNCTIONS}
        self._f = {**plain, **(kernels or {})}

    def constants(self) -> TaskLawConstants:
        """The law's per-axis and per-joint arrays, as the tick uses them (copies)."""
        return TaskLawConstants(
            self._c1.copy(), self._c2.copy(), self._k_rot.copy(), self._d_rot.copy(), self._null_d.copy(), self._null
        )

    def torque(
        self,
        jac: Mat,
        qd: Vec,
        x: Vec,
        v: Vec,
        remote_x: Vec | None,
        remote_v: Vec | None,
        remote_force: Vec | None = None,
        r_tool: Mat | None = None,
        port_force: Vec | None = None,
    ) -> Vec:
        """Desired joint torques for one tick.

        jac: (wrench_rows, joints) Jacobian of the handle/tool point (with the rotational rows
        under the positional ones when the orientation is held); x, v: the point's position and
        velocity in the frame of the remote sample; remote_x/remote_v (law "position") or
        remote_force (law "force"): the newest remote sample, None before the first one (no
        coupling force then); r_tool: the tool's orientation (orientation "hold"); port_force: the
        task force made elsewhere (wave variables' ports, core/wave_coupled.py) in place of the law's.
        """
        p = self.params
        w = self.wrench
        f = self._f
        d = p.axes
        if port_force is not None:
            w[:d] = port_force
        elif p.law == "force":
            if remote_force is None:
                w[:d] = 0.0
            else:
                f["force_feedback"](w, p.force_gain, remote_force)
        elif remote_x is None or remote_v is None:
            w[:d] = 0.0
        else:
            f["coupling"](w, self._c1, self._c2, remote_x, remote_v, x, v)
        if p.orientation == "hold":
            if r_tool is None:
                raise ValueError("orientation 'hold' needs the tool's orientation r_tool")
            if self.r_hold is None:
                self.r_hold = np.array(r_tool, dtype=float)
            f["jacobian_times"](self._omega, jac[3:6], qd)
            f["orientation_coupling"](w[3:6], self._k_rot, self._d_rot, self.r_hold, r_tool, self._omega, self._work)
        f["jacobian_transpose"](self.torque_nm, jac, w)
        if self._null:
            f["null_space_damping"](self._tmp, jac, qd, self._null_d, p.pinv_damping_m, self._work)
            f["add_into"](self.torque_nm, self._tmp)
        return self.torque_nm


def dot(a: Vec, b: Vec) -> float:
    """a.T @ b summed in index order (numpy's `@` may sum in another order: not the compiled loop's bits)."""
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


def rendered_ratio(applied: Vec, desired: Vec, force_limit: float, norm: float) -> float:
    """The factor on the desired task force that a torque scaled along the desired one renders:
    (applied . desired) / |desired|^2 (0 without a desired torque) times the force limit's
    saturation min(1, force_limit / norm) of the desired force's norm (0 without a force). The arm
    tick's felt force (`SideTick.ratio`) and TDPA's admittance slip use it."""
    tt = dot(desired, desired)
    ratio = dot(applied, desired) / tt if tt > 0.0 else 0.0
    sat = min(1.0, force_limit / norm) if norm > 0.0 else 0.0
    return ratio * sat


def matrix_times(out: Mat, a: Mat, b: Mat) -> None:
    """out = a @ b for matrices, each entry summed in index order (`out` must not be `b`)."""
    m, k = a.shape
    n = b.shape[1]
    for i in range(m):
        for j in range(n):
            s = 0.0
            for r in range(k):
                s += a[i, r] * b[r, j]
            out[i, j] = s


def cross(out: Vec, a: Vec, b: Vec) -> None:
    """out = a x b (3-vectors), numpy.cross's formula."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
