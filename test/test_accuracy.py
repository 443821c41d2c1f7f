"""`haptic-teleop bench accuracy`: Pareto front, error metric, energy balance, the CLI's outputs."""

from __future__ import annotations

import csv
import math
from dataclasses import replace

import numpy as np
import pytest

from haptic_teleop.cli.bench import BENCHMARKS
from haptic_teleop.cli.main import main as cli_main
from haptic_teleop.errors import HapticTeleopError
from haptic_teleop.scene.load import find_scene, load_scene
from haptic_teleop.studies.benchmarks.accuracy import (
    INTEGRATORS,
    Signals,
    base_setting,
    build_plan,
    compare,
    energy_residual_j,
    on_grid,
    pareto_front,
    reference_setting,
    run_setting,
)


def test_pareto_front_against_a_hand_made_set():
    cost = [1.0, 2.0, 3.0, 2.0, 4.0, 5.0, 1.0, math.nan, 0.5]
    error = [10.0, 5.0, 5.0, 6.0, 1.0, 2.0, 10.0, 0.0, math.inf]
    # (3,5) and (2,6) are dominated by (2,5); (5,2) by (4,1); the two (1,10) tie and both stay;
    # the NaN-cost and infinite-error points are never on the front.
    assert pareto_front(cost, error) == [True, True, False, False, True, False, True, False, False]
    assert pareto_front([1.0], [0.0]) == [True]
    with pytest.raises(ValueError, match="equal length"):
        pareto_front([1.0, 2.0], [1.0])


def test_on_grid_aligns_past_held_and_state_signals_analytically():
    # f(t) = t. A "past" sample at tick n averages f over [(n-1)T, nT] = (n - 1/2) T, a "held" one
    # over [nT, (n+1)T] = (n + 1/2) T, a "state" one is f(nT). On a grid of G = k T every kind
    # must give the same numbers whatever T is: block j covers [jG, (j+1)G], state at jG.
    g = 0.004
    for period in (0.001, 0.002, 0.004):
        k = round(g / period)
        n = np.arange(40)
        past = on_grid((n - 0.5) * period, k, "past", 8)
        held = on_grid((n + 0.5) * period, k, "held", 8)
        state = on_grid(n * period, k, "state", 8)
        j = np.arange(8)
        np.testing.assert_allclose(past, (j + 0.5) * g, rtol=0, atol=1e-15)
        np.testing.assert_allclose(held, (j + 0.5) * g, rtol=0, atol=1e-15)
        np.testing.assert_allclose(state, j * g, rtol=0, atol=1e-15)


@pytest.fixture(scope="module")
def wall_runs():
    """Reference, a second reference run, the scene default and a 2 ms control rate, 2.2 s window
    (the slave touches the wall at about 1.84 s)."""
    path = find_scene("wall_contact")
    base = base_setting(load_scene(path))
    ref = reference_setting(base)
    duration = 2.2
    return {
        "ref": run_setting(path, ref, duration, 1),
        "ref_again": run_setting(path, ref, duration, 1),
        "default": run_setting(path, base, duration, 1),
        "slow": run_setting(path, replace(base, period_s=0.002), duration, 1),
    }


def test_error_is_exactly_zero_for_the_reference_and_positive_for_coarser_settings(wall_runs):
    ref = wall_runs["ref"]
    assert np.min(ref.columns["s_contact_n"]) < -0.5, "window must include wall contact"
    for other in ("ref", "ref_again"):
        errors = compare(wall_runs[other], ref)
        assert errors["grid_period_s"] == 0.001
        for key, value in errors.items():
            if key != "grid_period_s":
                assert value == 0.0, key
    for coarse in ("default", "slow"):
        errors = compare(wall_runs[coarse], ref)
        for key, value in errors.items():
            assert math.isfinite(value) and value > 0.0, (coarse, key)
    assert compare(wall_runs["slow"], ref)["grid_period_s"] == 0.002
    # A smaller timestep is closer to the reference than the scene default's 1 ms.
    assert compare(wall_runs["default"], ref)["slave_position_rms_error_m"] > 1e-8


def test_energy_residual_is_zero_for_an_exact_trajectory_and_sees_missing_damping():
    # Mass m, damping b, a random actuator force held over each period (seeded), no contact. The
    # exact sampled motion of m dv/dt = F_i - b v over one period, with a = exp(-b T / m):
    #   v_{i+1} = F_i/b + (v_i - F_i/b) a,   x_{i+1} = x_i + (F_i/b) T + (v_i - F_i/b)(m/b)(1 - a).
    # The balance must close to the damping term's quadrature error (trapezoid, O(T^2)); with the
    # damping left out, or the force paired with the wrong period, it must not.
    m, b, period, n = 1.0, 5.0, 0.001, 3000
    rng = np.random.default_rng(7)
    force = 1.0 + rng.uniform(-2.0, 2.0, n)
    a = math.exp(-b * period / m)
    x, v = np.zeros(n), np.zeros(n)
    for i in range(n - 1):
        c = v[i] - force[i] / b
        v[i + 1] = force[i] / b + c * a
        x[i + 1] = x[i] + force[i] / b * period + c * m / b * (1 - a)
    cols = {"s_x_m": x, "s_v_m_per_s": v, "s_force_n": force, "s_contact_n": np.zeros(n)}
    setting = base_setting(load_scene(find_scene("wall_contact")))
    work = float(np.sum(np.abs(force[:-1] * np.diff(x))))
    residual = energy_residual_j(Signals(setting, period, cols, m, b, True, [1.0]))
    assert np.max(np.abs(residual)) < 1e-5 * work
    undamped = energy_residual_j(Signals(setting, period, cols, m, 0.0, True, [1.0]))
    assert np.max(np.abs(undamped)) > 0.1 * work
    shifted = dict(cols, s_force_n=np.roll(force, 1))  # force of the period before
    assert np.max(np.abs(energy_residual_j(Signals(setting, period, shifted, m, b, True, [1.0])))) > 1e-3 * work


def test_plan_covers_the_issue_and_the_reference_is_rk4_at_the_smallest_step():
    base = base_setting(load_scene(find_scene("wall_contact")))
    plan = build_plan(base)
    ref = plan[0]
    assert (ref.integrator, ref.timestep_s, ref.period_s) == ("RK4", 0.000125, base.period_s)
    assert len({s.key() for s in plan}) == len(plan)
    for integ in INTEGRATORS:
        steps = {round(s.timestep_s * 1e6, 3) for s in plan if s.integrator == integ}
        assert {125.0, 250.0, 500.0, 1000.0, 2000.0} <= steps
    assert {s.period_s for s in plan} == {0.0005, 0.001, 0.002}
    assert {s.solver_iterations for s in plan} >= {1, 100}
    assert any(s.solref_timeconst_s is not None for s in plan)
    assert base.key() in {s.key() for s in plan}
    with pytest.raises(HapticTeleopError, match="must divide"):
        reference_setting(replace(base, period_s=0.0003))


def test_cli_quick_writes_csv_table_and_plot(tmp_path, capsys):
    assert "accuracy" in BENCHMARKS
    out = tmp_path / "acc"
    argv = ["bench", "accuracy", "--quick", "--duration-s", "0.7", "--out", str(out), "--quiet"]
    assert cli_main(argv) == 0
    rows = list(csv.DictReader((out / "accuracy.csv").open()))
    assert len(rows) == 7
    assert rows[0]["reference"] == "True" and float(rows[0]["contact_force_rms_error_n"]) == 0.0
    assert sum(r["scene_default"] == "True" for r in rows) == 1
    assert any(float(r["slave_position_rms_error_m"]) > 0 for r in rows[1:])
    assert all(float(r["cpu_s_per_sim_s"]) > 0 for r in rows)
    assert any(r["pareto_force"] == "True" for r in rows)
    assert (out / "pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| reference |" in (out / "accuracy.md").read_text()
    # A second run into the same, now non-empty, directory is refused with a clear message (input: 2).
    assert cli_main(argv) == 2
    assert "exists and is not empty" in capsys.readouterr().err
