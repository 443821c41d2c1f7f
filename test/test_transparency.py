"""Seed 000's scenario and transparency analysis (docs/transparency.md): the in-contact start is an
equilibrium, the imposed profile moves the master exactly, the formulas of core/transparency.py
agree with short simulated runs, summary.json carries the predicted/measured pairs (and nothing
for scenes the analysis does not apply to), and bad values are one-line errors."""

from __future__ import annotations

import csv
import dataclasses
import json
import math

import numpy as np
import pytest

from haptic_teleop.analysis.stream import summarize_bag
from haptic_teleop.analysis.transparency import longest_hold, rise_ticks
from haptic_teleop.cli.main import main
from haptic_teleop.core.transparency import (
    ContactModel,
    allowable_delay,
    allowable_loss_time,
    force_drop,
    force_slope,
    transparent_loss_time,
)
from haptic_teleop.engine.lockstep import COL, Engine
from haptic_teleop.engine.run import record_run
from haptic_teleop.errors import ConfigError
from haptic_teleop.live.launcher import node_plan
from haptic_teleop.scene.load import find_scene, load_scene

SHORT = ("operator.duration_s=1.0", "scene.duration_s=1.6", "operator.speed_m_per_s=0.01")
T = 0.001
V = 0.01


def _delay(d: float) -> tuple[str, ...]:
    return tuple(f"network.{k}.effects={{delay: {{delay_s: {d!r}}}}}" for k in ("forward", "backward"))


def _run(*overrides: str) -> np.ndarray:
    scene = load_scene(find_scene("seed_contact"), overrides=[*SHORT, *overrides])
    r = Engine(scene).run(handle_sigint=False)
    return r.data[: r.ticks]


def _model(law: str, b_m: float, gain: float = 1.0) -> ContactModel:
    return ContactModel(
        period_s=T, speed_m_per_s=V, master_law=law, master_stiffness_n_per_m=500.0, master_damping_n_s_per_m=20.0,
        master_force_gain=gain, master_physical_damping_n_s_per_m=b_m, master_force_limit_n=20.0,
        slave_stiffness_n_per_m=500.0, wall_stiffness_n_per_m=1e4, contact_force_n=5.0,
        slave_damping_n_s_per_m=20.0, slave_physical_damping_n_s_per_m=5.0, wall_damping_n_s_per_m=10.0,
    )  # fmt: skip


def test_in_contact_start_rests_and_the_imposed_master_moves_exactly():
    d = _run()
    rest = slice(0, 500)  # before operator.start_s
    f0 = 5.0
    # the wall force, the robot and the master hold still at the equilibrium of F0 = 5 N
    assert np.allclose(d[rest, COL["s_contact_n"]], -f0, atol=1e-9)
    assert np.allclose(d[rest, COL["s_x_m"]], 0.02 + f0 / 1e4, atol=1e-12)
    assert np.allclose(d[rest, COL["m_force_n"]], -f0, atol=1e-9)  # c1m F0 / c1s
    # the master's reservoir starts at the holding energy F^2 T / (4 b_m) (+ E0 = 0)
    assert d[0, COL["m_energy_j"]] == pytest.approx(f0 * f0 * T / (4 * 0.1), rel=1e-12)
    # imposed: the master is on the trajectory, x0 + v (t - start) for 1 s, then held
    t = np.arange(len(d)) * T
    x0 = 0.02 + f0 / 1e4 + f0 / 500.0
    want = x0 + V * np.clip(t - 0.5, 0.0, 1.0)
    assert np.max(np.abs(d[:, COL["m_x_m"]] - want)) < 1e-12


def test_force_slope_and_drop_match_simulation():
    # position law, bound binding (2 b_m / T = 200 N/m < 476 N/m): slope 2 b_m v / T, delay changes nothing
    pp = {dly: np.abs(_run("master.damping_n_s_per_m=0.1", *_delay(dly))[:, COL["m_force_n"]]) for dly in (0.0, 0.1)}
    m = _model("position", 0.1)
    assert m.binding
    slope = np.polyfit(np.arange(1000, 1501) * T, pp[0.0][1000:1501], 1)[0]
    assert slope == pytest.approx(force_slope(m), rel=1e-6)
    assert pp[0.0][1500] - pp[0.1][1500] == pytest.approx(force_drop(m, 0.1, 0.1).drop_n, abs=1e-6)
    # force reflection, bound not binding: the seed's drop s R (R the round trip)
    fr = {
        dly: np.abs(
            _run("controllers.master.law=force", "master.damping_n_s_per_m=1.0", *_delay(dly))[:, COL["m_force_n"]]
        )
        for dly in (0.0, 0.05)
    }
    m = _model("force", 1.0)
    assert not m.binding
    drop = force_drop(m, 0.05, 0.05, at_s=1.0).drop_n
    assert drop == pytest.approx(force_slope(m) * 0.1)
    assert fr[0.0][1500] - fr[0.05][1500] == pytest.approx(drop, rel=1e-3)


def test_transparent_loss_time_of_a_held_sample_matches_simulation():
    """Force reflection with the bound binding (g 0.5): after a backward blackout starts the felt
    force still rises for gap / s_b, then holds; the formula's time within one period."""
    blackout = "network.backward.effects.blackout={starts_s: [1.2], ends_s: [1.4]}"
    d = _run("controllers.master.law=force", "controllers.master.force_gain=0.5", "master.damping_n_s_per_m=0.1",
             "operator.duration_s=1.2", "scene.duration_s=1.8", blackout)  # fmt: skip
    released = np.flatnonzero(d[:, COL["bwd_rx_seq"]] >= 0) * T
    hold = longest_hold(released, T, 500, 1700)
    assert hold is not None
    a, b = hold
    felt, desired = np.abs(d[:, COL["m_force_n"]]), np.abs(d[:, COL["m_force_desired_n"]])
    m = _model("force", 0.1, gain=0.5)
    predicted = transparent_loss_time(m, desired[a + 1] - felt[a + 1], felt[a + 1])
    measured = rise_ticks(felt, a, b) * T
    assert 0.01 < predicted < (b - a - 1) * T  # it stops inside the hold: not a vacuous comparison
    assert abs(measured - predicted) <= T


def test_allowable_delay_and_loss_time_formulas():
    m = _model("force", 1.0)
    d = allowable_delay(m, 0.1)
    assert abs(force_drop(m, d, d).drop_n) == pytest.approx(0.1, rel=1e-9)  # E = s 2 d
    assert allowable_delay(_model("position", 0.1), 0.1) == math.inf  # the bound's ramp ignores delay
    assert allowable_loss_time(m, 0.1, 0.0) == pytest.approx(0.1 / force_slope(m))
    with pytest.raises(ValueError, match="reservoir"):
        force_slope(m, law="pooled")


@pytest.fixture(scope="module")
def seed_summary(tmp_path_factory):
    out = tmp_path_factory.mktemp("seed")
    blackout = "network.backward.effects.blackout={starts_s: [1.2], ends_s: [1.25]}"
    law = ("controllers.master.law=force", "controllers.master.force_gain=0.5")
    scene = load_scene(find_scene("seed_contact"), overrides=[*SHORT, *law, blackout])
    record_run(scene, out / "bag", parallel=False, handle_sigint=False)
    return summarize_bag(out / "bag")


def test_summary_has_the_predicted_and_measured_pairs(seed_summary):
    s = seed_summary
    for stem, unit in (("force_slope", "n_per_s"), ("force_drop", "n"), ("transparent_loss_time", "s")):
        assert isinstance(s[f"{stem}_predicted_{unit}"], float)
        assert isinstance(s[f"{stem}_measured_{unit}"], float)
    assert s["force_slope_measured_n_per_s"] == pytest.approx(s["force_slope_predicted_n_per_s"], rel=0.02)
    assert s["force_drop_measured_n"] == pytest.approx(s["force_drop_predicted_n"], abs=0.01)
    assert abs(s["transparent_loss_time_measured_s"] - s["transparent_loss_time_predicted_s"]) <= 0.0011
    assert s["force_peak_error_vs_reference_n"] >= s["force_rms_error_vs_reference_n"] > 0.0
    assert s["allowable_delay_s"] > 0.0 and s["allowable_loss_time_s"] > 0.0
    # the energy margins start from the reservoirs' start values: the holding energy (g F0 = 2.5 N
    # on the master, F0 = 5 N on the slave) on top of eba.initial_energy_j (0, 0.5 J)
    assert s["master_initial_energy_j"] == pytest.approx(2.5**2 * T / (4 * 0.1), rel=1e-12)
    assert s["slave_initial_energy_j"] == pytest.approx(0.5 + 5.0**2 * T / (4 * 5.0), rel=1e-12)
    # every predicted key has its measured twin (the report pairs them by stem)
    predicted = {k.split("_predicted_")[0] + "|" + k.split("_predicted_")[1] for k in s if "_predicted_" in k}
    measured = {k.split("_measured_")[0] + "|" + k.split("_measured_")[1] for k in s if "_measured_" in k}
    assert predicted == measured
    json.dumps(s)  # summary.json takes it


def test_scenes_the_analysis_does_not_apply_to_get_no_keys(tmp_path):
    """A hold with an analysis section, and the default push without one: no transparency key."""
    for i, ov in enumerate((["operator.profile=hold", "analysis.allowed_force_error_n=0.2"], [])):
        scene = load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=0.3", *ov])
        record_run(scene, tmp_path / f"bag{i}", parallel=False, handle_sigint=False)
        s = summarize_bag(tmp_path / f"bag{i}")
        assert not [k for k in s if "_predicted_" in k or "vs_reference" in k or k.startswith("transparen")]


@pytest.mark.parametrize(
    ("overrides", "key", "allowed"),
    [
        (["slave.initial_contact_force_n=3"], "slave", "go together"),
        (["slave.start=in_contact"], "slave", "go together"),
        (["slave.start=touching", "slave.initial_contact_force_n=3"], "slave.start", "free, in_contact"),
        (["slave.start=in_contact", "slave.initial_contact_force_n=-1"], "slave.initial_contact_force_n", "> 0"),
        (["slave.start=in_contact", "slave.initial_contact_force_n=45"], "", "force_limit_n"),
        (["operator.profile=imposed"], "operator", "needs duration_s"),
        (["operator.duration_s=1"], "operator", "only used with profile 'imposed'"),
        (["operator.profile=imposed", "operator.duration_s=-1"], "operator.duration_s", ">= 0"),
    ],
)
def test_bad_seed_keys_are_one_line_config_errors(overrides, key, allowed):
    with pytest.raises(ConfigError) as exc:
        load_scene(find_scene("wall_contact"), overrides=overrides)
    text = str(exc.value)
    assert "\n" not in text and key in text and allowed in text


def test_arm_scenes_and_the_command_line_refuse_the_keys_in_one_line(tmp_path, capsys):
    with pytest.raises(ConfigError, match="one-axis scenes"):
        load_scene(find_scene("touch_ur5e_wall"), overrides=["operator.profile=imposed", "operator.duration_s=1"])
    with pytest.raises(ConfigError, match="run` only"):  # live nodes: the engine only
        node_plan(load_scene(find_scene("seed_contact")), None)
    code = main(["run", "seed_contact", "--set", "slave.initial_contact_force_n=0", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "initial_contact_force_n" in err
    code = main(["experiment", "transparency", "--configs", "nope", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--configs" in err


def test_experiment_writes_tables_whose_predictions_hold(tmp_path):
    out = tmp_path / "tx"
    argv = ["experiment", "transparency", "--out", str(out), "--configs", "fr_free", "--delays-ms", "0,50"]
    assert main([*argv, "--bursts-ms", "20", "--quiet", "--after-s", "0.1"]) == 0
    rows = list(csv.reader((out / "transparency_delay.csv").read_text().splitlines()))
    assert len(rows) == 3  # header, 0 and 50 ms
    last = rows[-1]
    assert float(last[6]) == pytest.approx(float(last[5]), rel=1e-3)  # drop measured = predicted (s R)
    assert (out / "transparency.png").stat().st_size > 1000


def test_two_condition_law_gives_the_seeds_drop_and_the_reservoir_law_less():
    """Force reflection with the bound binding (g 0.5: 238 N/m asked, 200 N/m allowed): under the
    two-condition law the ZOH cap ramps the felt force at s_b from the delayed onset, so the drop is
    the seed's s_b R exactly; the reservoir law charged its reservoir while the delayed force was
    flat and drops less (docs/transparency.md, "Force drop")."""
    m = _model("force", 0.1, gain=0.5)
    assert m.binding
    felt = {}
    for law in ("two_condition", "reservoir"):
        base = ("controllers.master.law=force", "controllers.master.force_gain=0.5", "master.damping_n_s_per_m=0.1",
                f"controllers.master.eba.law={law}")  # fmt: skip
        felt[law] = {d: np.abs(_run(*base, *_delay(d))[:, COL["m_force_n"]]) for d in (0.0, 0.05)}
    i = 1500  # 1 s after the master starts
    two = felt["two_condition"][0.0][i] - felt["two_condition"][0.05][i]
    res = felt["reservoir"][0.0][i] - felt["reservoir"][0.05][i]
    assert force_drop(m, 0.05, 0.05, "two_condition", at_s=1.0).drop_n == pytest.approx(force_slope(m) * 0.1)
    assert two == pytest.approx(force_drop(m, 0.05, 0.05, "two_condition", at_s=1.0).drop_n, rel=1e-6)
    assert res == pytest.approx(force_drop(m, 0.05, 0.05, "reservoir", at_s=1.0).drop_n, abs=2e-3)
    assert res < 0.5 * two


def test_predictions_name_the_network_effects_they_do_not_model(tmp_path):
    """A blackout on the backward link: the measured slope and drop include it, the predicted ones
    are for the constant delay alone, and the summary says which effects they leave out."""
    from haptic_teleop.analysis.transparency import transparency_summary, unmodelled_effects
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.scene.load import find_scene, load_scene

    blackout = "network.backward.effects.blackout={starts_s: [1.0], ends_s: [1.3]}"
    jitter = "network.forward.effects.delay={delay_s: 0.05, jitter_s: 0.002}"
    scene = load_scene(find_scene("seed_contact"), overrides=[blackout, jitter])
    bag = tmp_path / "bag"
    record_run(scene, bag, parallel=False, handle_sigint=False)
    out = transparency_summary(bag)
    assert out["transparency_unmodelled_effects"] == [
        "network.forward.effects.delay (jitter_s)",
        "network.backward.effects.blackout",
    ]
    plain = load_scene(find_scene("seed_contact"))
    assert unmodelled_effects(dataclasses.asdict(plain.config)) == []
