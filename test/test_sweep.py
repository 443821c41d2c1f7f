"""`haptic-teleop sweep`: every combination and seed runs like `run`, the table aggregates them, bad input exits 2."""

import csv
import json
import statistics

import pytest

from haptic_teleop.cli.main import main
from haptic_teleop.studies.batch.plan import parse_param, split_values

SHORT = ["--set", "scene.duration_s=0.5", "--set", "network.forward.effects.loss.probability=0.1"]
POLICIES = "network.forward.buffer.policy+network.backward.buffer.policy=none,fixed"
METRICS = "force_rms_error_n,buffering_delay_forward_mean_s,packets_lost_forward"


def test_sweep_runs_every_combination_like_run(tmp_path, capsys):
    out = tmp_path / "sweep"
    argv = ["sweep", "wall_contact", *SHORT, "--param", POLICIES, "--seeds", "1,2", "--out", str(out), "--workers", "1"]
    assert main([*argv, "--quiet", "--metrics", METRICS]) == 0
    with (out / "sweep.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    keys = ("network.forward.buffer.policy", "network.backward.buffer.policy")
    cells = [(r[keys[0]], r[keys[1]], r["seed"]) for r in rows]  # one column per swept key, in plan order
    assert cells == [("none", "none", "1"), ("none", "none", "2"), ("fixed", "fixed", "1"), ("fixed", "fixed", "2")]
    # Each row is that run's summary.json, and a plain `run` with the same settings gives the same numbers.
    for r in rows:
        summary = json.loads((out / "runs" / r["run_hash"] / "summary.json").read_text())
        assert float(r["force_rms_error_n"]) == summary["force_rms_error_n"]
    run_out = tmp_path / "run"
    set_fixed = ["--set", "network.forward.buffer.policy=fixed", "--set", "network.backward.buffer.policy=fixed"]
    argv_run = ["run", "wall_contact", *SHORT, *set_fixed, "--seed", "2", "--out", str(run_out)]
    assert main([*argv_run, "--quiet", "--no-plots"]) == 0
    single = json.loads((run_out / "summary.json").read_text())
    assert float(rows[3]["force_rms_error_n"]) == single["force_rms_error_n"]
    assert float(rows[3]["packets_lost_forward"]) == single["packets_lost_forward"]
    # The swept value reached the engine: the fixed buffer holds samples its 10 ms, `none` does not.
    assert float(rows[0]["buffering_delay_forward_mean_s"]) < 0.001
    assert float(rows[2]["buffering_delay_forward_mean_s"]) == pytest.approx(0.010, abs=0.002)
    # Seeds differ (random loss), and the table is their mean ± sample std.
    lost = [float(r["packets_lost_forward"]) for r in rows[:2]]
    assert lost[0] != lost[1]
    table = (out / "sweep.md").read_text()
    line = next(x for x in table.splitlines() if x.startswith("| none |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1] == "2"
    mean, std = (float(x) for x in cells[4].split("±"))
    assert mean == pytest.approx(statistics.mean(lost), rel=1e-3)
    assert std == pytest.approx(statistics.stdev(lost), rel=1e-3)
    assert (out / "sweep.png").stat().st_size > 0
    assert not (out / "runs" / rows[0]["run_hash"] / "bag").exists()  # bags dropped unless --keep-bags
    assert rows[0]["bag_path"] == ""


@pytest.mark.parametrize(
    ("param", "as_set"),
    [
        ("network.forward.buffer.policy=none,bogus", "network.forward.buffer.policy=bogus"),
        ("network.forward.buffer.no_such_key=1,2", "network.forward.buffer.no_such_key=1"),
        ("network.forward.buffer.quantile=0.5,1.5", "network.forward.buffer.quantile=1.5"),
    ],
)
def test_bad_param_is_the_same_config_error_as_run_set(tmp_path, capsys, param, as_set):
    out = tmp_path / "sweep"
    assert main(["sweep", "wall_contact", "--param", param, "--out", str(out), "--quiet"]) == 2
    sweep_err = capsys.readouterr().err
    assert main(["run", "wall_contact", "--set", as_set, "--out", str(tmp_path / "run"), "--quiet"]) == 2
    run_err = capsys.readouterr().err
    assert sweep_err == run_err and "config error" in sweep_err
    assert not out.exists()  # validated before anything ran


@pytest.mark.parametrize("param", ["no_equals_sign", "a..b=1", "a.b=1,,2", "a.b=1,1", "+a=1"])
def test_malformed_param_exits_2(tmp_path, capsys, param):
    assert main(["sweep", "wall_contact", "--param", param, "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "config error: --param" in capsys.readouterr().err


def test_unknown_metric_exits_2_naming_the_allowed_keys(tmp_path, capsys):
    argv = ["sweep", "wall_contact", "--set", "scene.duration_s=0.2", "--param", "scene.seed=1"]
    assert main([*argv, "--metrics", "force_rms_eror_n", "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "force_rms_eror_n" in err and "force_rms_error_n" in err


def test_values_split_at_top_level_commas_only():
    assert split_values("a, b,[1, 2],{x: 1, y: 2}") == ["a", "b", "[1, 2]", "{x: 1, y: 2}"]
    p = parse_param("network.forward.effects.blackout.starts_s+x.y=[1.0],[2.0, 3.0]")
    assert p.keys == ("network.forward.effects.blackout.starts_s", "x.y")
    assert p.values == ("[1.0]", "[2.0, 3.0]")


@pytest.mark.parametrize("seeds", ["-1", str(2**63), "x"])
def test_seeds_out_of_range_are_blamed_on_the_seeds_flag(tmp_path, capsys, seeds):
    argv = ["sweep", "wall_contact", "--param", "scene.duration_s=0.2", "--seeds", seeds, "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"config error: --seeds: scene.seed = '{seeds}'" in err
    assert not (tmp_path / "o").exists()
