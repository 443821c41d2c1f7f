"""What the stabilizer experiments share (`experiment stabilizers`: stabilizers.py's grid over
delay and loss, zwidth.py's sweep over walls): the laws, the one-axis contact scene and its
geometry, the networks, one run recorded to a bag and measured from it, the felt stiffness, and
the option lists' parsing.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

BASE_SCENE = "wall_contact"
GEOMETRY = (
    "slave.wall.position_m=0.005",
    "operator.start_s=0.2",
    "operator.speed_m_per_s=0.05",
    "operator.distance_m=0.03",
)
_TDPA = ("controllers.master.eba.law=tdpa", "controllers.slave.eba.law=tdpa")
LAWS: dict[str, tuple[str, tuple[str, ...]]] = {
    "reservoir": ("EBA, reservoir", ()),
    "two_condition": (
        "EBA, two conditions",
        ("controllers.master.eba.law=two_condition", "controllers.slave.eba.law=two_condition"),
    ),
    "tdpa_zoh": (
        "TDPA, ZOH-exact controller",
        (*_TDPA, "controllers.master.eba.tdpa_controller=zoh", "controllers.slave.eba.tdpa_controller=zoh"),
    ),
    "tdpa_zoh_reflect": (
        "TDPA, ZOH-exact, keeping half its input",
        (
            *_TDPA,
            "controllers.master.eba.tdpa_controller=zoh",
            "controllers.slave.eba.tdpa_controller=zoh",
            "controllers.master.eba.tdpa_reflection=0.5",
            "controllers.slave.eba.tdpa_reflection=0.5",
        ),
    ),
    "tdpa_zoh_admittance": (
        "TDPA, ZOH-exact, the slave's on its reference",
        (
            *_TDPA,
            "controllers.master.eba.tdpa_controller=zoh",
            "controllers.slave.eba.tdpa_controller=zoh",
            "controllers.slave.eba.tdpa_placement=admittance",
            "controllers.slave.eba.tdpa_drift_gain_per_s=2",
        ),
    ),
    "tdpa_velocity": ("TDPA, velocity controller", _TDPA),
    "wave": ("wave variables, b 20 N s/m", ("controllers.master.eba.law=wave", "controllers.slave.eba.law=wave")),
    "wave_matched": (
        "wave variables, the slave matched",
        (
            "controllers.master.eba.law=wave",
            "controllers.slave.eba.law=wave",
            "controllers.slave.eba.wave_matched=true",
        ),
    ),
    "wave_filtered": (
        "wave variables, 50 Hz wave filter, drift 5/s",
        (
            "controllers.master.eba.law=wave",
            "controllers.slave.eba.law=wave",
            "controllers.master.eba.wave_filter_hz=50",
            "controllers.slave.eba.wave_filter_hz=50",
            "controllers.slave.eba.wave_drift_gain_per_s=5",
        ),
    ),
}
DIRS = ("forward", "backward")
# name -> the loss effect's YAML (both directions); None: no loss.
LOSSES: dict[str, str | None] = {
    "none": None,
    "bernoulli_10": "{model: bernoulli, probability: 0.1}",
    "bernoulli_30": "{model: bernoulli, probability: 0.3}",
    # Gilbert-Elliott, stationary loss 30 %: p = 0.03, r = 0.07, all lost in the bad state.
    "bursty_30": "{model: gilbert_elliott, p: 0.03, r: 0.07, one_minus_h: 1.0, one_minus_k: 0.0}",
}
CONTACT_N = 0.1  # the slave touches the wall while its contact force exceeds this


# The arm scene of the comparison and the laws it runs: the scene's own geometry (the table 3 cm
# below the tool, the hand pushing down from 0.3 s at 5 cm/s toward 2 cm into it). Wave variables
# and the two-condition law are one-axis only; TDPA's velocity controller runs on arms but is not
# compared here: the damper it adds along the joints' motion is no task force (through the Touch's
# Jacobian it reads as 1e5 N), so its force columns would not be forces (docs/stabilizers_compared.md).
ARM_SCENE = "touch_ur5e_wall"
ARM_LAWS = ("reservoir", "two_condition", "tdpa_zoh", "tdpa_zoh_reflect", "wave", "wave_matched", "wave_filtered")


def scene(overrides: Sequence[str], base: str = BASE_SCENE) -> Any:
    """The scene `base` (the one-axis contact scene by default) with `overrides`."""
    from haptic_teleop.scene.load import find_scene, load_scene

    return load_scene(find_scene(base), overrides=list(overrides))


def network_overrides(delay_s: float, loss: str) -> list[str]:
    """The grid's network, both directions: no other effect than this delay and this loss."""
    out = [f"network.{d}.effects={{}}" for d in DIRS]
    if delay_s > 0.0:
        out += [f"network.{d}.effects.delay={{delay_s: {delay_s}}}" for d in DIRS]
    spec = LOSSES[loss]
    if spec is not None:
        out += [f"network.{d}.effects.loss={spec}" for d in DIRS]
    return out


def measure(bag: Path) -> dict[str, Any]:
    """What the comparison needs of one run, from its bag alone."""
    from haptic_teleop.analysis.metrics import analyze_bag

    summary, sig = analyze_bag(bag)
    return {
        "felt_n": np.asarray(sig.master_force_n, dtype=float),
        "offset_m": float(sig.master_x_m[-1] - sig.slave_x_m[-1]),
        "wall_rms_n": float(summary["force_rms_error_n"]),
        "margin_j": float(summary["two_port_energy_margin_min_j"]),
        "stiffness": felt_stiffness(sig.master_x_m, sig.master_force_n, sig.contact_n),
        "contact_max_n": float(summary["contact_force_max_n"]),
    }


def measure_task(bag: Path) -> dict[str, Any]:
    """`measure` for an arm scene's bag: the felt force vector (task frame), the master-slave offset
    vector at the end, the summary's errors and margins, and the felt stiffness along the wall's
    normal (the handle's depth along -normal against its force along the normal)."""
    from haptic_teleop.analysis.stream import summarize_bag
    from haptic_teleop.analysis.taskmetrics import load_task_signals

    summary = summarize_bag(bag)
    sig = load_task_signals(bag)
    normal = np.asarray(sig.scene["slave"]["wall"]["normal"], dtype=float)
    normal = normal / np.linalg.norm(normal)
    return {
        "felt_n": np.asarray(sig.master_force_n, dtype=float),
        "offset_m": np.asarray(sig.master_x_m[-1] - sig.slave_x_m[-1], dtype=float),
        "wall_rms_n": float(summary["force_rms_error_n"]),
        "margin_j": float(summary["two_port_energy_margin_min_j"]),
        "stiffness": felt_stiffness(
            -(sig.master_x_m @ normal), sig.master_force_n @ normal, np.linalg.norm(sig.contact_n, axis=1)
        ),
        "contact_max_n": float(summary["contact_force_max_n"]),
    }


def drift_m(offset_m: Any, reference_m: Any) -> float:
    """The change of the master-slave offset against the undisturbed run's: signed on one axis, its
    norm on an arm (m)."""
    d = np.asarray(offset_m, dtype=float) - np.asarray(reference_m, dtype=float)
    return float(d) if d.ndim == 0 else float(np.linalg.norm(d))


def felt_stiffness(x_m: np.ndarray, force_n: np.ndarray, contact_n: np.ndarray) -> float:
    """Least-squares slope of the master's force magnitude over its position while the slave
    touches the wall (N/m; NaN with fewer than 10 such ticks)."""
    touching = np.abs(np.asarray(contact_n)) > CONTACT_N
    if np.count_nonzero(touching) < 10:
        return math.nan
    x = np.asarray(x_m)[touching]
    f = np.abs(np.asarray(force_n)[touching])
    if np.ptp(x) <= 0.0:
        return math.nan
    return float(np.polyfit(x, f, 1)[0])


def record(
    overrides: Sequence[str],
    bag: Path,
    measure_bag: Callable[[Path], dict[str, Any]] = measure,
    base: str = BASE_SCENE,
) -> dict[str, Any]:
    """Run the scene `base` with `overrides` into `bag`, then measure it (`measure_bag`)."""
    from haptic_teleop.engine.run import record_run

    bag.parent.mkdir(parents=True, exist_ok=True)
    record_run(scene(overrides, base), bag, parallel=False, handle_sigint=False)
    return measure_bag(bag)


def number_list(text: str, flag: str, low: float, high: float, unit: str = "") -> list[float]:
    """A comma-separated list of numbers in [low, high] (in `unit`, if given); anything else is one
    line naming the flag, what was given and what is allowed."""
    from haptic_teleop.errors import InputError

    try:
        xs = [float(c) for c in text.split(",") if c.strip()]
    except ValueError:
        xs = []
    if not xs or any(not low <= x <= high for x in xs):
        within = f"from {low:g} to {high:g}" + (f" {unit}" if unit else "")
        raise InputError(f"{flag} {text}: allowed: comma-separated numbers {within}")
    return xs
