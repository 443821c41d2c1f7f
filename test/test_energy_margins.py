"""True energy margins per port (haptic_teleop/analysis/energy.py) and the summary's two margins
per side: with the damping the controller was configured with, and with the damping the simulator
really has (the MjModel's dof_damping, written into the bag's run facts by the engine)."""

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from haptic_teleop.analysis import stream
from haptic_teleop.analysis.energy import energy_margins
from haptic_teleop.analysis.metrics import analyze_bag, compute_summary, port_energy, simulator_damping
from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.engine.run import record_run
from haptic_teleop.scene.load import find_scene, load_scene

T = 0.001


@settings(max_examples=100, deadline=None)
@given(
    ticks=st.integers(1, 200),
    ports=st.integers(1, 6),
    seed=st.integers(0, 2**32 - 1),
    e0=st.floats(0.0, 2.0),
)
def test_margins_per_port_and_pooled(ticks, ports, seed, e0):
    """Each port's series is the one-port ledger (`metrics.port_energy`) of its own column, bit for
    bit; the pooled margin is the side's budget plus their sum; a per-port budget adds per port."""
    rng = np.random.default_rng(seed)
    q = np.cumsum(rng.normal(0.0, 1e-3, (ticks, ports)), axis=0)
    tau = rng.normal(0.0, 5.0, (ticks, ports))
    d = rng.uniform(0.0, 10.0, ports)
    m = energy_margins(q, tau, d, T, e0)
    assert m.absorbed_j.shape == (ticks, ports) and m.pooled_margin_j.shape == (ticks,)
    for j in range(ports):
        assert np.array_equal(m.absorbed_j[:, j], port_energy(q[:, j], tau[:, j], d[j], T))
    assert np.allclose(m.pooled_margin_j, e0 + m.absorbed_j.sum(axis=1), rtol=0.0, atol=1e-12)
    assert np.array_equal(m.port_margin_j, m.absorbed_j)  # one reservoir: the ports' own margins start at 0
    assert m.pooled_min_j == float(np.min(m.pooled_margin_j))
    per_port = energy_margins(q, tau, d, T, [e0] * ports)
    assert np.array_equal(per_port.port_margin_j, e0 + m.absorbed_j)
    assert np.array_equal(per_port.port_min_j, np.min(e0 + m.absorbed_j, axis=0))


def test_one_port_gives_the_summary_margin_bits():
    """A (N,) series is one port: E0 + min of the ledger, the bits of summary.json's margin."""
    rng = np.random.default_rng(1)
    x, f = np.cumsum(rng.normal(0, 1e-3, 500)), rng.normal(0, 3.0, 500)
    got = energy_margins(x, f, 2.5, T, [0.5]).pooled_min_j
    assert got == float(0.5 + np.min(port_energy(x, f, 2.5, T)))


def test_a_port_that_pushes_along_its_motion_has_a_negative_margin():
    """F = +10 N held while the port moves +1 mm a tick: it delivers 10 mJ a tick, of which the
    damping d = 1 N s/m can have dissipated only (d/T) dq^2 = 1 mJ: 9 mJ a tick net."""
    q = np.stack([1e-3 * np.arange(11), np.zeros(11)], axis=1)
    tau = np.stack([np.full(11, 10.0), np.full(11, 3.0)], axis=1)
    m = energy_margins(q, tau, [1.0, 1.0], T, 0.05)
    assert m.port_min_j[0] == pytest.approx(-0.09) and m.port_min_j[1] == 0.0
    assert m.pooled_min_j == pytest.approx(0.05 - 0.09)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((np.zeros((3, 2)), np.zeros((3, 3)), 1.0, T), "same shape"),
        ((np.zeros((0, 1)), np.zeros((0, 1)), 1.0, T), "same shape"),
        ((np.zeros((3, 2, 1)), np.zeros((3, 2, 1)), 1.0, T), r"\(N,\) or \(N, n\)"),
        ((np.zeros(3), np.zeros(3), -1.0, T), "damping must be finite and >= 0"),
        ((np.zeros(3), np.zeros(3), math.nan, T), "damping must be finite and >= 0"),
        ((np.zeros(3), np.zeros(3), 1.0, 0.0), "period_s must be > 0"),
    ],
)
def test_bad_input_is_refused(args, message):
    with pytest.raises(ValueError, match=message):
        energy_margins(*args)


# --------------------------------------------------------------------------------------------
# The summary: configured damping against the simulator's.

GEOMETRY = (
    "slave.wall.position_m=0.005",
    "operator.start_s=0.2",
    "operator.speed_m_per_s=1.0",
    "operator.distance_m=0.03",
    "scene.duration_s=3",
    "controllers.master.stiffness_n_per_m=4000",
    "controllers.slave.stiffness_n_per_m=4000",
    "controllers.master.damping_n_s_per_m=40",
    "controllers.slave.damping_n_s_per_m=40",
)
SIM_DAMPING = {"master": ("master_x", 0.01), "slave": ("slave_x", 0.05)}  # configured: 1 and 5 N s/m


def _less_damped_than_configured(engine: Engine) -> None:
    """The simulated devices get 1 % of the damping the controllers assume (written into the
    compiled MjModel after the plants were built, without telling the controllers)."""
    for plant, (joint, d) in ((engine.master, SIM_DAMPING["master"]), (engine.slave, SIM_DAMPING["slave"])):
        model = plant.model  # type: ignore[attr-defined]
        model.dof_damping[model.joint(joint).dofadr[0]] = d


def test_ledger_passes_while_the_true_margin_is_negative(tmp_path: Path) -> None:
    """The issue's point: devices less damped than the controllers believe. Every EBA check that
    trusts the configured damping passes (margins >= 0, the reservoir in the bag equals that
    margin); the margin with the damping the simulator really had is negative, and the summary
    shows both."""
    scene = load_scene(find_scene("wall_contact"), overrides=list(GEOMETRY))
    bag = tmp_path / "bag"
    record_run(scene, bag, parallel=False, handle_sigint=False, on_engine=_less_damped_than_configured)
    s, sig = analyze_bag(bag)
    assert sig.run_info["master_joint_damping"] == [0.01] and sig.run_info["slave_joint_damping"] == [0.05]
    assert s["master_joint_damping_simulator"] == [0.01] and s["slave_joint_damping_simulator"] == [0.05]
    # The ledger-based checks pass: margins with the configured damping, and the reservoir agrees.
    assert s["master_energy_margin_min_j"] >= 0.0 and s["slave_energy_margin_min_j"] >= 0.0
    e0 = scene.config.controllers.master.eba.initial_energy_j
    ledger = e0 + port_energy(sig.master_x_m, sig.master_force_n, scene.config.master.damping_n_s_per_m, T)
    assert sig.master_reservoir_j is not None
    assert np.max(np.abs(ledger - sig.master_reservoir_j)) < 1e-12
    # The truth: the master port delivered energy (measured -8 mJ, far beyond rounding).
    assert s["master_energy_margin_simulator_min_j"] < -1e-3
    # The streaming analysis (what `haptic-teleop analyze` runs) reports the same.
    streamed = stream._summarize(bag)
    for key in ("master_energy_margin_simulator_min_j", "slave_energy_margin_simulator_min_j"):
        assert streamed[key] == s[key]
    # A bag written without the fact (older engines, live runs) reports no true margin: NaN.
    sig.run_info = {}
    old = compute_summary(sig)
    assert math.isnan(old["master_energy_margin_simulator_min_j"]) and old["master_joint_damping_simulator"] is None
    assert old["master_energy_margin_min_j"] == s["master_energy_margin_min_j"]


def test_simulator_damping_includes_viscous_friction(tmp_path: Path) -> None:
    """The simulator's damping is what the model holds: the scene's damping plus a viscous friction
    effect (2 N s/m) on the slave. Damping above the configured one only raises the true margin."""
    scene = load_scene(find_scene("wall_contact"), overrides=[*GEOMETRY, "slave.effects.friction.viscous_n_s_per_m=2"])
    bag = tmp_path / "bag"
    record_run(scene, bag, parallel=False, handle_sigint=False)
    s, _ = analyze_bag(bag)
    assert s["slave_joint_damping_simulator"] == [7.0] and s["master_joint_damping_simulator"] == [1.0]
    assert s["slave_energy_margin_simulator_min_j"] >= s["slave_energy_margin_min_j"]
    assert s["master_energy_margin_simulator_min_j"] == s["master_energy_margin_min_j"]


def test_simulator_damping_from_run_facts() -> None:
    assert simulator_damping({}, "master") is None
    assert simulator_damping({"slave_joint_damping": [5]}, "slave") == [5.0]
