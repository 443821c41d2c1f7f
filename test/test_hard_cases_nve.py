"""Hard cases on NVE scenes: long delay, bursty loss, a stiff spring, a light object, and all of them
at once, in 1 and 3 axes. Each is recorded to a real bag and judged from it: every signal finite,
the server passive at every step by the energy balance of the recorded object and HIP signals
(analysis/nve_energy.py), the object's energy bounded by what the HIPs put in, and the force the
client feeds back bounded by its spring times the largest HIP-object distance it saw. Where the
simplest explicit integrator would blow up (omega T >> 2), the same signals show it would.
docs/robustness_nve.md, "NVE scenes", has the cases and the numbers."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.analysis.nve_energy import ClientPort, step_dissipation_j
from haptic_teleop.analysis.nve_summary import nve_rows, summarize_nve
from haptic_teleop.engine.nve_loop import record_nve_run
from haptic_teleop.record.reader import BagReader
from haptic_teleop.scene.load import find_scene, load_scene

# The hard cases run without compensation (the client's spring stays k_h, so its force path is
# exercised whatever the distortion); one case adds seed 000's scheme at the long delay.
NONE_SCHEME = ("nve.clients.0.compensation={scheme: none}",)


LONG_DELAY = (
    "nve.clients.0.up.effects.delay={delay_s: 1.0, jitter_s: 0.05}",
    "nve.clients.0.down.effects.delay={delay_s: 1.0, jitter_s: 0.05}",
)
# Gilbert-Elliott bursts: p = 5 %, r = 20 %: a fifth of the packets lost, in bursts of 5 on average
BURSTY = (
    "nve.clients.0.up.effects.loss={model: gilbert, p: 0.05, r: 0.2}",
    "nve.clients.0.down.effects.loss={model: gilbert, p: 0.05, r: 0.2}",
)
STIFF = ("nve.clients.0.coupling.server_stiffness_n_per_m=1e6", "nve.clients.0.coupling.client_stiffness_n_per_m=1e3")
LIGHT = ("nve.object.mass_kg=1e-6", "nve.clients.0.coupling.server_stiffness_n_per_m=1e3")
FAST = ("nve.clients.0.operator.speed_m_per_s=2.0", "nve.clients.0.operator.distance_m=3.0")

CASES = {
    "long_delay": (*NONE_SCHEME, *LONG_DELAY),
    "long_delay_compensated": LONG_DELAY,
    "bursty_loss": (*NONE_SCHEME, *BURSTY),
    "stiff_spring": (*NONE_SCHEME, *STIFF),
    "light_object": (*NONE_SCHEME, *LIGHT),
    "undamped_light_stiff_delayed_lossy": (
        *NONE_SCHEME,
        *LIGHT[:1],
        *STIFF[:1],
        "nve.object.damping_n_s_per_m=0",
        *LONG_DELAY,
        *BURSTY,
        *FAST,
    ),
}


def _record(tmp_path: Path, scene: str, overrides: tuple[str, ...], seconds: float = 4.0) -> tuple[Path, dict]:
    s = load_scene(find_scene(scene), overrides=[f"scene.duration_s={seconds}", *overrides])
    bag = tmp_path / "bag"
    record_nve_run(s, bag, handle_sigint=False, parallel=False)
    return bag, summarize_nve(bag)


@pytest.mark.parametrize("case", sorted(CASES))
def test_nve_hard_case_finite_and_passive(tmp_path: Path, case: str) -> None:
    bag, summary = _record(tmp_path, "nve_push", CASES[case])
    assert summary["finite"]
    assert summary["clients"]["client"]["force_peak_n"] > 0
    energy = summary["server_energy"]
    assert energy is not None and energy["passive"], energy
    assert energy["dissipated_j"] >= -energy["tolerance_j"]
    with BagReader(bag) as r:
        schema, _, rows = nve_rows(r)
    c = schema.clients[0]
    force = rows[:, schema.client_group(c, "force_n")]
    spring = rows[:, schema.client_group(c, "spring_n_per_m")][:, 0]
    gap = rows[:, schema.client_group(c, "hip_x_m")] - rows[:, schema.client_group(c, "obj_x_m")]
    seen = np.isfinite(gap).all(axis=1)
    assert np.all(np.abs(force[seen]) <= np.abs(spring[seen, None] * gap[seen]) * (1 + 1e-12) + 1e-15)
    # the object's energy never exceeds the springs' work: kinetic <= stored, which the balance bounds
    v = rows[:, schema.group("obj_v_m_per_s")]
    assert np.all(0.5 * float(load_scene(find_scene("nve_push"), overrides=list(CASES[case])).config.nve.object.mass_kg)
                  * np.sum(v * v, axis=1) <= energy["stored_max_j"] * (1 + 1e-9))  # fmt: skip


def test_three_axes_two_clients_hard(tmp_path: Path) -> None:
    over = (
        "nve.object.mass_kg=1e-5",
        "nve.clients.0.coupling.server_stiffness_n_per_m=1e5",
        "nve.clients.1.up.effects.delay={delay_s: 1.5, jitter_s: 0.1}",
        "nve.clients.1.down.effects.loss={model: gilbert, p: 0.1, r: 0.1}",
    )
    _, summary = _record(tmp_path, "nve_two_clients", over, seconds=3.0)
    assert summary["finite"] and summary["server_energy"]["passive"]
    assert all(c["force_peak_n"] > 0 for c in summary["clients"].values())


def test_the_balance_catches_an_integrator_that_makes_energy() -> None:
    """The same balance on the explicit Euler steps of the stiff, light case (omega T = 31):
    steps that make energy, and a growing object: the check can fail."""
    m, k, b, T = 1e-6, 1e3, 0.0025, 0.001
    n = 60
    x = np.zeros((n, 1))
    v = np.zeros((n, 1))
    for i in range(n - 1):
        a = (-b * v[i, 0] + k * (0.01 - x[i, 0])) / m
        x[i + 1, 0] = x[i, 0] + T * v[i, 0]
        v[i + 1, 0] = v[i, 0] + T * a
    hip = np.full((n, 1), 0.01)
    port = ClientPort(k, 0.0, hip, np.zeros((n, 1)), np.arange(n, dtype=float))
    d, _ = step_dissipation_j(m, x, v, [port])
    assert d.min() < 0.0
    assert not math.isfinite(float(np.abs(x).max())) or np.abs(x).max() > 1.0
