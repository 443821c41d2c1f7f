"""Sweeps that scale: sweep files (grid, random), local worker processes, a Dask cluster of worker
processes, resume by run hash, the Parquet table and its CSV twin (docs/sweep.md)."""

import json
import math
import sys
from pathlib import Path

import pytest

from haptic_teleop.cli.main import main
from haptic_teleop.scene.load import find_scene, load_scene
from haptic_teleop.studies.batch.plan import key_value, load_sweep_file, resolve, run_hash
from haptic_teleop.studies.batch.store import LEDGER, read_csv

LOSS = "network.forward.effects.loss.probability"
DELAY = "network.forward.effects.delay.delay_s+network.backward.effects.delay.delay_s"
# Timing of the machine, not of the run: differs between any two runs of the same point.
WALL_CLOCK = {"realtime_factor"}


def _sweep_file(path: Path, losses: list[float], extra: str = "") -> Path:
    path.write_text(
        "scene: wall_contact\n"
        "set: {scene.duration_s: 0.3}\n"
        f"grid:\n  {LOSS}: {json.dumps(losses)}\n"
        "seeds: [3]\n"
        "metrics: [force_rms_error_n, packets_lost_forward]\n" + extra
    )
    return path


def _ledger(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / LEDGER).read_text().splitlines()]


# --- sweep files: errors ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("body", "blamed"),
    [
        ("grid: {scene.seed: [1]}\n", "scene = None: required"),
        ("scene: wall_contact\n", "grid = None: a sweep file needs a grid or a random section"),
        ("scene: wall_contact\ngrid: {scene.seed: [1]}\nsedes: [1]\n", "sedes = [1]: unknown key; allowed: scene,"),
        ("scene: wall_contact\ngrid: {scene.seed: []}\n", "grid.scene.seed = []: allowed: a non-empty list"),
        ("scene: wall_contact\ngrid: {scene.seed: [1, 1]}\n", "grid.scene.seed = [1, 1]: allowed: each value once"),
        ("scene: wall_contact\ngrid: {a..b: [1]}\n", "grid.a..b = [1]: allowed: a dotted key path"),
        ("scene: wall_contact\ngrid: {scene.seed: [1]}\nseeds: [1, -2]\n", "seeds = -2: allowed: a non-empty list"),
        ("scene: wall_contact\ngrid: {scene.seed: [1]}\nkeep_bags: yes please\n", "keep_bags = 'yes please'"),
        (
            "scene: wall_contact\nrandom: {count: 0, params: {scene.seed: {integers: [1, 9]}}}\n",
            "random.count = 0: required; allowed: a whole number >= 1",
        ),
        (
            "scene: wall_contact\nrandom: {count: 2, params: {scene.seed: {gauss: [1, 9]}}}\n",
            "random.params.scene.seed: allowed: one of {uniform:",
        ),
        (
            "scene: wall_contact\nrandom: {count: 2, params: {scene.seed: {uniform: [2, 1]}}}\n",
            "with low <= high",
        ),
        # a key the scene does not have: the scene's own check, blamed on the sweep file's section
        (
            "scene: wall_contact\ngrid: {network.forward.buffer.no_such_key: [1]}\n",
            ": grid.network.forward.buffer.no_such_key: network.forward.buffer.no_such_key",
        ),
        ("scene: no_such_scene\ngrid: {scene.seed: [1]}\n", "no_such_scene"),
    ],
)
def test_a_bad_sweep_file_is_one_line_naming_the_key_exit_2(tmp_path, capsys, body, blamed):
    f = tmp_path / "s.yaml"
    f.write_text(body)
    out = tmp_path / "o"
    assert main(["sweep", str(f), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("haptic-teleop: config error: "), err
    assert blamed in lines[0], lines[0]
    assert not out.exists()


def test_a_scene_without_param_names_both_ways(tmp_path, capsys):
    assert main(["sweep", "wall_contact", "--out", str(tmp_path / "o")]) == 2
    assert "--param" in capsys.readouterr().err


# --- plans -----------------------------------------------------------------------------------------


def test_grid_is_every_combination_tied_keys_set_together(tmp_path):
    f = tmp_path / "g.yaml"
    f.write_text(f"scene: wall_contact\ngrid:\n  {DELAY}: [0.0, 0.1]\n  {LOSS}: [0, 0.05, 0.2]\nseeds: [4, 5]\n")
    spec = load_sweep_file(f)
    assert len(spec.combos) == 6 and spec.combos[0] == ("0.0", "0") and spec.combos[-1] == ("0.1", "0.2")
    points = resolve(spec)
    assert [(p.combo, p.seed) for p in points[:3]] == [(("0.0", "0"), 4), (("0.0", "0"), 5), (("0.0", "0.05"), 4)]
    last = points[-1].scene.config.network
    assert last.forward.effects.delay.delay_s == last.backward.effects.delay.delay_s == 0.1
    assert points[-1].keys["network.backward.effects.delay.delay_s"] == 0.1
    assert len({p.run_hash for p in points}) == 12
    # the hash is of the resolved scene: the same scene and seed reached another way hash the same
    assert run_hash(points[-1].scene.config, 5) == points[-1].run_hash
    # a key path through a list of sections (an NVE scene's clients) names its cell too
    nve = load_scene(find_scene("nve_push"), overrides=["nve.clients.0.up.effects.delay.delay_s=0.07"])
    assert key_value(nve.config, "nve.clients.0.up.effects.delay.delay_s") == 0.07


def test_random_sample_is_reproducible_within_its_ranges(tmp_path):
    f = tmp_path / "r.yaml"
    body = (
        "scene: wall_contact\nrandom:\n  count: 40\n  seed: SEED\n  params:\n"
        f"    {DELAY}: {{uniform: [0.01, 0.2]}}\n"
        "    network.forward.buffer.policy: {choice: [none, fixed]}\n"
        "    scene.seed: {integers: [1, 3]}\n"
        "    network.forward.effects.loss.probability: {loguniform: [0.001, 0.1]}\n"
    )
    f.write_text(body.replace("SEED", "11"))
    a, b = load_sweep_file(f).combos, load_sweep_file(f).combos
    assert a == b and len(a) == 40
    f.write_text(body.replace("SEED", "12"))
    assert load_sweep_file(f).combos != a
    delays = [float(c[0]) for c in a]
    assert all(0.01 <= d <= 0.2 for d in delays) and max(delays) - min(delays) > 0.1
    assert {c[1] for c in a} == {"none", "fixed"}
    assert {c[2] for c in a} == {"1", "2", "3"}  # both ends included
    losses = [float(c[3]) for c in a]
    assert all(0.001 <= x <= 0.1 for x in losses)
    assert sum(x < 0.01 for x in losses) > 10  # log-uniform: about half the draws below the geometric mean


# --- running: local processes, resume, Dask, the tables --------------------------------------------


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory):
    """Two points in two local worker processes, then the same directory resumed with three."""
    base = tmp_path_factory.mktemp("sweep")
    out = base / "local"
    two = _sweep_file(base / "two.yaml", [0.0, 0.2])
    assert main(["sweep", str(two), "--out", str(out), "--workers", "2", "--quiet", "--no-plots"]) == 0
    first = {r["run_hash"]: (out / "runs" / r["run_hash"] / "summary.json").stat().st_mtime_ns for r in _ledger(out)}
    three = _sweep_file(base / "three.yaml", [0.0, 0.2, 0.4])
    return base, out, first, three


def test_resume_skips_the_finished_points(local_sweep, capsys):
    _, out, first, three = local_sweep
    assert len(first) == 2
    assert main(["sweep", str(three), "--out", str(out), "--workers", "1", "--no-plots", "--keep-bags"]) == 0
    assert "2 of 3 points already done" in capsys.readouterr().err
    ledger = _ledger(out)
    assert len(ledger) == 3  # one line per point ever finished: only the new one was added
    new = [r for r in ledger if r["run_hash"] not in first]
    assert len(new) == 1 and (Path(new[0]["bag_path"]) / "metadata.yaml").is_file()  # kept on request
    assert [r["bag_path"] for r in ledger if r["run_hash"] in first] == [None, None]
    for h, mtime in first.items():  # the finished ones were not run again
        assert (out / "runs" / h / "summary.json").stat().st_mtime_ns == mtime
    assert sorted(p.name for p in (out / "runs").iterdir()) == sorted(r["run_hash"] for r in ledger)
    assert main(["sweep", str(three), "--out", str(out), "--quiet", "--no-plots"]) == 0  # nothing left to run
    assert len(_ledger(out)) == 3


def test_a_local_dask_cluster_gives_the_same_results(local_sweep):
    distributed = pytest.importorskip("distributed")
    base, local, _, three = local_sweep
    if len(_ledger(local)) < 3:
        assert main(["sweep", str(three), "--out", str(local), "--workers", "1", "--quiet", "--no-plots"]) == 0
    out = base / "dask"
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cluster:
        argv = ["sweep", str(three), "--out", str(out), "--scheduler", cluster.scheduler_address]
        assert main([*argv, "--quiet", "--no-plots"]) == 0
    here = {r["run_hash"]: r for r in _ledger(local)}
    there = {r["run_hash"]: r for r in _ledger(out)}
    assert set(here) == set(there) and len(here) == 3  # the same resolved scenes, the same hashes
    for h, r in here.items():
        a = {k: v for k, v in r["summary"].items() if k not in WALL_CLOCK}
        b = {k: v for k, v in there[h]["summary"].items() if k not in WALL_CLOCK}
        assert a == b, h
    lost = sorted(r["summary"]["packets_lost_forward"] for r in here.values())
    assert lost[0] == 0 and lost[1] < lost[2]  # the swept loss reached the runs


def test_parquet_and_csv_hold_the_same_table(local_sweep):
    pq = pytest.importorskip("pyarrow.parquet")
    _, out, _, _ = local_sweep
    table = pq.read_table(out / "sweep.parquet")
    rows = read_csv(out / "sweep.csv")
    cols = table.column_names
    assert cols == list(rows[0].keys())
    assert cols[:3] == [LOSS, "seed", "run_hash"] and cols[-1] == "bag_path"
    ledger = {r["run_hash"]: r for r in _ledger(out)}
    summary_keys = {k for r in ledger.values() for k, v in r["summary"].items() if not isinstance(v, (list, dict))}
    assert summary_keys - {"seed"} <= set(cols)  # every scalar of summary.json, not only --metrics
    assert table.schema.field("force_rms_error_n").type == "double"
    assert table.schema.field("packets_lost_forward").type == "int64"
    assert table.schema.field("all_finite").type == "bool"
    for pr, cr in zip(table.to_pylist(), rows, strict=True):
        summary = json.loads((out / "runs" / pr["run_hash"] / "summary.json").read_text())
        for c in cols:
            p, v = pr[c], cr[c]
            if p is None:
                assert v == ""
            elif isinstance(p, bool):
                assert v == str(p)
            elif isinstance(p, float):
                assert float(v) == p or (math.isnan(p) and v == "")
            else:
                assert v == str(p)
            if c in summary and c != "seed":
                assert p == summary[c] or (math.isnan(p) and math.isnan(summary[c])), c


def test_parquet_without_pyarrow_is_one_line_naming_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # `import pyarrow` fails as if not installed
    f = _sweep_file(tmp_path / "s.yaml", [0.0])
    assert main(["sweep", str(f), "--out", str(tmp_path / "o"), "--format", "parquet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("haptic-teleop: --format parquet: pyarrow is not installed") and "[sweep]" in err
    assert "\n" not in err and not (tmp_path / "o").exists()


def test_scheduler_without_dask_is_one_line_naming_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    f = _sweep_file(tmp_path / "s.yaml", [0.0])
    assert main(["sweep", str(f), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "dask.distributed is not installed" in err and "[sweep]" in err and "\n" not in err
    assert not (tmp_path / "o").exists()


def test_sweeping_scene_seed_and_seeds_at_once_is_refused(tmp_path, capsys):
    argv = ["sweep", "wall_contact", "--param", "scene.seed=1,2", "--seeds", "3", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert "config error: --seeds: scene.seed = [3]: scene.seed is swept too" in capsys.readouterr().err


def test_a_point_failing_in_a_worker_is_reported_and_the_others_run(tmp_path):
    from haptic_teleop.studies.batch.runner import LocalPool, Task

    pool = LocalPool(2)
    bad = Task("bad", "scene: {duration_s: -1}\n", str(tmp_path / "runs" / "bad"))
    good = Task("good", "scene: {duration_s: 0.2}\n", str(tmp_path / "runs" / "good"))
    try:
        pool.submit([bad, good])
        got = {t.run_hash: (r, e) for t, r, e in pool.results(lambda: False)}
    finally:
        pool.close()
    assert got["bad"][1] is None and "ConfigError" in got["bad"][0]["error"]
    assert "scene.duration_s = -1.0" in got["bad"][0]["error"]
    assert got["good"][0]["summary"]["ticks"] == 200  # the pool survived the other point's error


def test_sigint_in_a_parallel_sweep_keeps_what_finished_and_resume_redoes_none_of_it(tmp_path, capsys):
    import os
    import signal
    import subprocess

    f = _sweep_file(tmp_path / "s.yaml", [0.0, 0.1, 0.2, 0.3, 0.4, 0.5])
    out = tmp_path / "o"
    env = dict(os.environ, PYTHONUNBUFFERED="1", HAPTIC_TELEOP_TEST_PAUSE="sweep-run")
    argv = [sys.executable, "-m", "haptic_teleop.cli", "sweep", str(f), "--out", str(out), "--workers", "2"]
    p = subprocess.Popen([*argv, "--no-plots"], stderr=subprocess.PIPE, text=True, env=env)
    assert p.stderr is not None
    for line in p.stderr:  # the first point is stored; the other worker is running or done
        if "phase sweep-run" in line:
            break
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "Traceback" not in err and "sweep interrupted after" in err
    kept = {r["run_hash"] for r in _ledger(out)}
    assert 1 <= len(kept) < 6
    assert {d.name for d in (out / "runs").iterdir()} == kept  # no folder of a cut point
    assert len(read_csv(out / "sweep.csv")) == len(kept)
    mtimes = {h: (out / "runs" / h / "summary.json").stat().st_mtime_ns for h in kept}
    assert main(["sweep", str(f), "--out", str(out), "--workers", "1", "--no-plots"]) == 0
    assert f"{len(kept)} of 6 points already done" in capsys.readouterr().err
    assert len(_ledger(out)) == 6 and len(read_csv(out / "sweep.csv")) == 6
    assert all((out / "runs" / h / "summary.json").stat().st_mtime_ns == m for h, m in mtimes.items())


def test_an_nve_sweep_tables_each_clients_figures_under_dotted_names(tmp_path):
    """An NVE summary keeps its per-client figures in sections: the table flattens them into
    dotted names and the sweep's default metrics are each client's force and round trip."""
    out = tmp_path / "nve"
    argv = ["sweep", "nve_push", "--param", "nve.clients.0.up.effects.delay.delay_s=0.05,0.1",
            "--set", "scene.duration_s=0.3", "--workers", "1", "--out", str(out), "--quiet", "--no-plots"]  # fmt: skip
    assert main(argv) == 0
    rows = read_csv(out / "sweep.csv")
    summaries = [json.loads((out / "runs" / r["run_hash"] / "summary.json").read_text()) for r in rows]
    for r, s in zip(rows, summaries, strict=True):
        client = s["clients"]["client"]
        assert float(r["clients.client.force_rms_n"]) == client["force_rms_n"]
        assert float(r["clients.client.round_trip_s.median"]) == client["round_trip_s"]["median"]
    # the longer up-link delay shows in the measured round trip the table carries
    assert float(rows[1]["clients.client.round_trip_s.median"]) > float(rows[0]["clients.client.round_trip_s.median"])
    md = (out / "sweep.md").read_text()
    assert "clients.client.force_rms_n" in md and "clients.client.round_trip_s.median" in md
