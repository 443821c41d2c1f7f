"""`haptic-teleop experiment nve-analysis | nve-compensation` (seed 000's two NVE experiments,
docs/nve_experiments.md): end to end on short runs, the numbers they must reproduce from the model,
and bad arguments (exit 2, one line)."""

import csv
import itertools

import numpy as np
import pytest

from haptic_teleop.cli.main import main
from haptic_teleop.core.nve_transparency import NveModel, distorted_damping_n_s_per_m, distorted_mass_kg
from haptic_teleop.engine.nve_loop import NveEngine
from haptic_teleop.scene.load import find_scene, load_scene
from haptic_teleop.studies.replications.nve import (
    NO_COMPENSATION,
    Case,
    Runner,
    delay_overrides,
    errors,
    push_window,
    write_ramp_trace,
)

# nve_push: m = 0.25 kg, b = 0.0025 N s/m, k_h = k_e = 0.5 N/m, push at 0.1 m/s from 0.5 s for 0.9 m.
KH, V, R = 0.5, 0.1, 0.3
MODEL = NveModel(0.25, 0.0025, KH, 0.5)


def _rows(path):
    with path.open() as fh:
        return list(csv.DictReader(fh))


def _row(rows, tag):
    (row,) = [r for r in rows if r["run"].startswith(tag)]
    return row


def test_the_schema_columns_hold_the_force_hip_and_object(tmp_path):
    """The force column is k_h (hip_x - obj_x)
    of the columns it names (d_h = 0), and the HIP's velocity is the push speed during the push."""
    scene = load_scene(find_scene("nve_push"), overrides=["scene.duration_s=2.0"])
    engine = NveEngine(scene)
    engine.run(handle_sigint=False)
    d = engine.data
    col = {
        g: d[:, engine.schema.index(f"client.{g}")]
        for g in ("hip_x_m", "obj_x_m", "force_n", "spring_n_per_m", "hip_v_m_per_s", "rtt_s")
    }
    seen = ~np.isnan(col["obj_x_m"])
    assert seen.sum() > 1000
    assert np.allclose(
        col["force_n"][seen], col["spring_n_per_m"][seen] * (col["hip_x_m"][seen] - col["obj_x_m"][seen]), atol=1e-12
    )
    assert np.all(col["hip_v_m_per_s"][1000:] == pytest.approx(V))
    assert np.nanmax(col["rtt_s"]) == pytest.approx(R + 0.001)
    assert d[:, engine.schema.index("obj_x_m")][-1] > 0.05  # the server's object moved


def test_each_run_is_a_bag_and_the_trace_read_back_is_the_engines(tmp_path):
    """The runner records each run to bags/NNN_<case> and reads the trace back from it: the same
    columns, bit for bit, as the engine holds in memory for the same scene; index.csv names the
    bag's case. With `discard` the bag is gone once read and no index is written."""
    runner = Runner(("scene.duration_s=2.0",), 2000, 2, True, "test", tmp_path / "bags")
    case = Case("delayed", "(1) delayed", delay_overrides(R), "R = 0.3 s")
    with runner:
        trace = runner.run(case)
    engine = NveEngine(runner.scene(case.overrides))
    engine.run(handle_sigint=False)
    for group, got in (
        ("hip_v_m_per_s", trace.hip_v_m_per_s),
        ("force_n", trace.force_n),
        ("spring_n_per_m", trace.spring_n_per_m),
        ("rtt_s", trace.rtt_s),
    ):
        np.testing.assert_array_equal(got, engine.data[:, engine.schema.index(f"client.{group}")], err_msg=group)
    assert (tmp_path / "bags" / "001_delayed" / "metadata.yaml").is_file()
    assert _rows(tmp_path / "bags" / "index.csv") == [
        {"bag": "001_delayed", "run": "(1) delayed", "settings": "R = 0.3 s", "overrides": " ".join(case.overrides)}
    ]
    gone = Runner(("scene.duration_s=2.0",), 2000, 1, True, "test", tmp_path / "gone", discard=True)
    with gone:
        again = gone.run(case)
    np.testing.assert_array_equal(again.force_n, trace.force_n)
    assert not (tmp_path / "gone").exists()  # the bag and then its empty folder


def test_analysis_runs_end_to_end_and_the_distorted_object_matches_the_delayed_force(tmp_path, capsys):
    """With a hand-like push (velocity ramp), no delay with (m_h, b_h) gives the delayed force within
    a small part of it, and no distortion at all (m_h = m, b_h = b: row (0)) is far worse."""
    out = tmp_path / "a"
    code = main(["experiment", "nve-analysis", "--out", str(out), "--duration-s", "16", "--ramp-s", "6"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "| run | settings | rms_error_n |" in printed and "(2) no delay, m_h = 0.2732 kg" in printed
    assert f"bags:  {out / 'bags'}" in printed and (out / "bags" / "index.csv").is_file()
    for name in ("nve_analysis.png", "nve_analysis.csv", "nve_analysis.md", "hip_trace.csv"):
        assert (out / name).stat().st_size > 100, name
    rows = _rows(out / "nve_analysis.csv")
    distorted = _row(rows, "(2)")
    undistorted = _row(rows, "(0)")
    assert (
        distorted["settings"]
        == f"m_h={distorted_mass_kg(MODEL, R):.6g}, b_h={distorted_damping_n_s_per_m(MODEL, R):.6g}"
    )
    assert float(distorted["relative_rms_error"]) < 0.25
    assert float(undistorted["relative_rms_error"]) > 3 * float(distorted["relative_rms_error"])
    # the spring the rule picks (mass-based: m w = 0.25 >= b) and the other are both in the table
    assert _row(rows, "(3)")["settings"] == "k_hm=0.5465"
    assert _row(rows, "(3')")["settings"] == "k_hb=30.5"


def test_a_wrong_damping_distortion_gives_a_larger_error(tmp_path):
    """The same comparison with b_h from the one-way delay (b + k_e R / 2) instead of the round trip:
    the error more than doubles, so the experiment tells a right distortion from a wrong one."""
    trace = tmp_path / "hip.csv"
    write_ramp_trace(trace, 16.0, 0.5, V, 0.9, 6.0)
    base = ("scene.duration_s=16.0", f"nve.clients.0.operator={{profile: trace, trace_file: {str(trace)!r}}}")
    runner = Runner(base, 16000, 3, True, "test")
    none0 = (*NO_COMPENSATION, *delay_overrides(0.0))
    delayed = runner.run(Case("delay", "", (*NO_COMPENSATION, *delay_overrides(R))))
    window = push_window(delayed)

    def error_with(mass_kg: float, damping: float) -> float:
        tr = runner.run(
            Case("x", "", (*none0, f"nve.object.mass_kg={mass_kg}", f"nve.object.damping_n_s_per_m={damping}"))
        )
        return errors(tr.force_n, delayed.force_n, window)["rms_error_n"]

    right = error_with(distorted_mass_kg(MODEL, R), distorted_damping_n_s_per_m(MODEL, R))
    wrong = error_with(distorted_mass_kg(MODEL, R), MODEL.damping_n_s_per_m + 0.5 * R / 2)
    assert wrong > 2 * right


def test_compensation_runs_end_to_end_and_no_compensation_is_the_kh_v_r_offset(tmp_path, capsys):
    """Row (2)'s error is, at steady state, the analytic offset k_h v R (the delayed force is
    k_h v R + F0(t - R) while pushing, so its mean over the push is k_h v R up to the ends);
    Fujimoto04's spring is K0 - alpha R_measured; one row is marked closest, the smallest."""
    out = tmp_path / "c"
    code = main(["experiment", "nve-compensation", "--out", str(out), "--alpha-sweep-points", "3"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "| run | settings | spring_at_end_n_per_m |" in printed and "Closest to (1):" in printed
    for name in ("nve_compensation.png", "nve_compensation.csv", "nve_compensation.md", "nve_compensation_alpha.csv"):
        assert (out / name).stat().st_size > 100, name
    assert not (out / "nve_compensation_rtt.csv").exists()  # only with --rtt-sweep
    rows = _rows(out / "nve_compensation.csv")
    assert [r["run"][:3] for r in rows] == ["(2)", "(3)", "(4)", "(5)"]
    none = _row(rows, "(2)")
    assert float(none["mean_error_n"]) == pytest.approx(KH * V * R, rel=0.05)
    assert float(none["spring_at_end_n_per_m"]) == KH
    measured = R + 0.001  # the client measures the round trip plus the loop's own period
    assert float(_row(rows, "(3)")["spring_at_end_n_per_m"]) == pytest.approx(KH - 0.25 * measured)
    assert float(_row(rows, "(4)")["spring_at_end_n_per_m"]) == pytest.approx(KH - 1.5 * measured)
    assert float(_row(rows, "(5)")["spring_at_end_n_per_m"]) < KH  # past its allowable delay (0.195 s)
    rms = {r["run"][:3]: float(r["rms_error_n"]) for r in rows}
    (closest,) = [r["run"][:3] for r in rows if r["closest"] == "yes"]
    assert rms[closest] == min(rms.values())
    alpha = _rows(out / "nve_compensation_alpha.csv")
    assert len(alpha) == 3 and float(alpha[0]["alpha_n_per_m_per_s"]) == 0.0
    assert float(alpha[0]["rms_error_n"]) == pytest.approx(rms["(2)"])  # alpha 0 is no compensation
    assert float(alpha[-1]["spring_n_per_m"]) == 0.0  # the sweep reaches the floor


def test_rtt_sweep_error_grows_with_delay_and_the_proposed_scheme_waits_for_its_allowable_delay(tmp_path):
    out = tmp_path / "r"
    argv = ["experiment", "nve-compensation", "--out", str(out), "--duration-s", "2", "--alpha-sweep-points", "0"]
    assert main([*argv, "--rtt-sweep", "--quiet"]) == 0
    assert (out / "nve_compensation_rtt.png").stat().st_size > 100
    assert not (out / "nve_compensation_alpha.csv").exists()
    rows = _rows(out / "nve_compensation_rtt.csv")
    rtts = [float(r["rtt_s"]) for r in rows]
    assert rtts == [0.05, 0.1, 0.2, 0.3, 0.4, 0.5]
    none = [float(r["no_compensation_rms_error_n"]) for r in rows]
    assert all(b > a for a, b in itertools.pairwise(none))
    # nve_push's scheme allows R up to 0.195 s (m_allowable = 0.26 kg): below it, it is no compensation
    for r in rows:
        same = float(r["proposed_rms_error_n"]) == float(r["no_compensation_rms_error_n"])
        assert same == (float(r["rtt_s"]) + 0.001 <= 0.195)


def _bad(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert code == 2, err
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize(
    ("argv", "expect"),
    [
        (["nve-analysis", "--rtt-s", "x"], "--rtt-s: 'x' is not a number; allowed: a number > 0"),
        (["nve-analysis", "--rtt-s", "0"], "allowed: a number > 0"),
        (["nve-analysis", "--duration-s", "nan"], "allowed: a number >= 1"),
        (["nve-compensation", "--alpha-sweep-points", "2.5"], "allowed: a whole number >= 0"),
        (["nve-compensation", "--alpha-low", "-1"], "--alpha-low: -1: allowed"),
        (["nve-analysis", "--bogus"], "unrecognized arguments: --bogus"),
        (["nosuch"], "invalid choice: 'nosuch'"),
        ([], "required: NAME"),
        (["nve-analysis", "--set", "nve.object.mass_kg=-1"], "nve.object.mass_kg"),
        (["nve-compensation", "--set", "nve.clients.0.compensation={scheme: none}"], "allowed: transparency"),
        (["nve-analysis", "--ramp-s", "30"], "--ramp-s 30"),
        (["nve-analysis", "--set", "nve.clients.0.operator.profile=hold"], "allowed: push"),
    ],
)
def test_bad_arguments_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, argv, expect):
    out = tmp_path / "o"
    line = _bad(capsys, ["experiment", *argv, "--out", str(out)] if argv else ["experiment"])
    assert expect in line
    assert not out.exists()


def test_a_non_empty_out_is_refused(tmp_path, capsys):
    (tmp_path / "x").write_text("")
    assert "not empty" in _bad(capsys, ["experiment", "nve-analysis", "--out", str(tmp_path)])
