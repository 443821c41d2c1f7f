"""Checked arguments of the ur_rtde commands the UR driver sends (docs/ur.md): pure, no SDK.

forceMode(task_frame, selection_vector, wrench, type, limits) in ur_rtde 1.6.5 goes to the
control script as: input_int_register_1 = type, input_int_register_2..7 = selection,
input_double_register_0..5 = task frame, 6..11 = wrench, 12..17 = limits (docs/ur_protocols.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from haptic_teleop.errors import InputError

FORCE_MODE_TYPES = (1, 2, 3)  # UR force_mode type: 2 = the task frame is used as given


def _vec(name: str, values: Sequence[float], n: int = 6) -> tuple[float, ...]:
    out = tuple(float(v) for v in values)
    if len(out) != n:
        raise InputError(f"{name} needs {n} values, got {len(out)}")
    if not all(math.isfinite(v) for v in out):
        raise InputError(f"{name} must be finite, got {out}")
    return out


@dataclass(frozen=True)
class ForceModeArgs:
    """forceMode's five arguments, checked: wrench (N, N m) and limits in the task frame; selection 0/1
    per axis (1 = compliant); limits: the largest speed (m/s, rad/s) along compliant axes and the
    largest deviation (m, rad) along the others."""

    task_frame: tuple[float, ...]
    selection: tuple[int, ...]
    wrench: tuple[float, ...]
    mode_type: int
    limits: tuple[float, ...]

    def sdk_args(self) -> tuple[list[float], list[int], list[float], int, list[float]]:
        return list(self.task_frame), list(self.selection), list(self.wrench), self.mode_type, list(self.limits)


def force_mode_args(
    wrench: Sequence[float],
    task_frame: Sequence[float] = (0.0,) * 6,
    selection: Sequence[int] = (0, 0, 1, 0, 0, 0),
    limits: Sequence[float] = (0.1, 0.1, 0.1, 0.5, 0.5, 0.5),
    mode_type: int = 2,
    max_force_n: float = 100.0,
    max_torque_nm: float = 10.0,
) -> ForceModeArgs:
    w = _vec("wrench", wrench)
    sel = tuple(int(s) for s in selection)
    if len(sel) != 6 or any(s not in (0, 1) for s in sel):
        raise InputError(f"selection needs 6 values of 0 or 1 (1 = compliant axis), got {tuple(selection)}")
    lim = _vec("limits", limits)
    if any(v <= 0.0 for v in lim):
        raise InputError(f"limits must be > 0 (speed along compliant axes, deviation along the others), got {lim}")
    if mode_type not in FORCE_MODE_TYPES:
        raise InputError(f"force mode type must be one of {FORCE_MODE_TYPES}, got {mode_type}")
    if max(abs(v) for v in w[:3]) > max_force_n or max(abs(v) for v in w[3:]) > max_torque_nm:
        raise InputError(f"wrench {w} is beyond the driver's limits ({max_force_n} N, {max_torque_nm} N m)")
    return ForceModeArgs(_vec("task_frame", task_frame), sel, w, mode_type, lim)


def clip_twist(twist: Sequence[float], max_linear_m_per_s: float, max_angular_rad_per_s: float) -> list[float]:
    """speedL's twist with its linear and angular parts each scaled down to their limit."""
    t = _vec("twist", twist)
    lin = math.sqrt(sum(v * v for v in t[:3]))
    ang = math.sqrt(sum(v * v for v in t[3:]))
    s_l = 1.0 if lin <= max_linear_m_per_s else max_linear_m_per_s / lin
    s_a = 1.0 if ang <= max_angular_rad_per_s else max_angular_rad_per_s / ang
    return [v * s_l for v in t[:3]] + [v * s_a for v in t[3:]]


def version_at_least(version: tuple[int, ...], needed: tuple[int, int]) -> bool:
    return (version[0], version[1]) >= needed


def direct_torque_supported(version: tuple[int, ...]) -> bool:
    """Whether ur_rtde 1.6.5's control script calls direct_torque() on this controller: its script
    keeps the call only from 5.26 on ("$5.26" lines); PolyScope X (10.x) from 10.10."""
    if version[0] >= 10:
        return version_at_least(version, (10, 10))
    return version_at_least(version, (5, 26))
