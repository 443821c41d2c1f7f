"""Engine: determinism, Ctrl-C and crashes leave a complete bag, EBA keeps a stiff delayed wall passive."""

import filecmp
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.analysis.metrics import analyze_bag, port_energy
from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.engine.run import record_run
from haptic_teleop.record.reader import BagReader
from haptic_teleop.scene.load import find_scene, load_scene

DEFAULT = find_scene("wall_contact")
SHORT = ["scene.duration_s=3.0"]


def _record(tmp_path: Path, name: str, overrides=(), seed=None, parallel=True):
    scene = load_scene(DEFAULT, overrides=[*SHORT, *overrides], seed=seed)
    bag = tmp_path / name / "bag"
    bag.parent.mkdir(parents=True)
    engine, timing = record_run(scene, bag, parallel=parallel, handle_sigint=False)
    return bag, engine, timing


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    lossy = ["network.forward.effects.loss.probability=0.1"]
    a, _, _ = _record(tmp_path, "a", lossy, seed=3)
    b, _, _ = _record(tmp_path, "b", lossy, seed=3)
    c, _, _ = _record(tmp_path, "c", lossy, seed=4)
    assert filecmp.cmp(a / "bag.mcap", b / "bag.mcap", shallow=False)
    assert (a / "metadata.yaml").read_text() == (b / "metadata.yaml").read_text()
    assert not filecmp.cmp(a / "bag.mcap", c / "bag.mcap", shallow=False)


def test_stop_request_leaves_a_complete_bag(tmp_path):
    scene = load_scene(DEFAULT, overrides=SHORT)
    bag = tmp_path / "bag"
    engine = Engine(scene, loop="python")  # wraps the Python loop; the compiled one: test_compiled_loop.py
    original = engine._python_loop

    def stop_midway(progress, sink):
        def progress_and_stop(n):
            if n >= 1234:
                engine.request_stop()

        return original(progress_and_stop, sink)

    engine._python_loop = stop_midway  # type: ignore[method-assign]
    from haptic_teleop.engine.lockstep import COLUMNS
    from haptic_teleop.record.recorder import RunRecorder

    rec = RunRecorder(bag, scene.to_yaml(), engine.period_ns, True, True, len(COLUMNS))
    result = engine.run(sink=rec, handle_sigint=False)
    rec.close({"interrupted": True})
    assert result.interrupted and 1234 <= result.ticks < 1400
    with BagReader(bag) as r:
        assert len(r.read("/master/joint_states").log_ns) == result.ticks
        assert json.loads(r.string("/haptic_teleop/run_info"))["interrupted"] is True


def test_exception_in_a_tick_still_closes_the_bag(tmp_path, monkeypatch):
    scene = load_scene(DEFAULT, overrides=SHORT)
    calls = {"n": 0}
    from haptic_teleop.plants import mujoco_plant

    original = mujoco_plant.MujocoWallRobot.step

    def failing_step(self, f, ext=None):
        calls["n"] += 1
        if calls["n"] == 1500:
            raise RuntimeError("servo bus fault")
        return original(self, f, ext)

    monkeypatch.setattr(mujoco_plant.MujocoWallRobot, "step", failing_step)
    with pytest.raises(RuntimeError, match="servo bus fault"):
        record_run(scene, tmp_path / "bag", handle_sigint=False, loop="python")  # the loop that calls step
    with BagReader(tmp_path / "bag") as r:
        assert len(r.read("/slave/joint_states").log_ns) == 1499
        assert json.loads(r.string("/haptic_teleop/run_info"))["failed"] is True


def test_exception_between_compiled_chunks_still_closes_the_bag(tmp_path):
    """The compiled loop returns to Python every 100 ticks; whatever raises there (here the
    progress callback) ends the run with a closed bag holding the ticks that ran."""
    scene = load_scene(DEFAULT, overrides=SHORT)

    def progress(n):
        if n == 1500:
            raise RuntimeError("display gone")

    with pytest.raises(RuntimeError, match="display gone"):
        record_run(scene, tmp_path / "bag", progress=progress, handle_sigint=False, loop="compiled")
    with BagReader(tmp_path / "bag") as r:
        assert len(r.read("/slave/joint_states").log_ns) == 1500
        info = json.loads(r.string("/haptic_teleop/run_info"))
        assert info["failed"] is True and info["ticks"] == 1500
        assert r.packets("/forward/packets").shape[0] == 1500


def test_stiff_wall_long_delay_eba_holds_unprotected_fails(tmp_path):
    """1e5 N/m wall, 200 ms each way, stiff coupling: EBA keeps both ports passive; without it, energy grows."""
    hard = [
        "scene.duration_s=8.0",
        "slave.wall.stiffness_n_per_m=1e5",
        "network.forward.effects.delay.delay_s=0.2",
        "network.backward.effects.delay.delay_s=0.2",
        "controllers.master.stiffness_n_per_m=4000",
        "controllers.slave.stiffness_n_per_m=4000",
        "controllers.master.damping_n_s_per_m=40",
        "controllers.slave.damping_n_s_per_m=40",
    ]
    on, _, _ = _record(tmp_path, "on", hard)
    off, _, _ = _record(
        tmp_path, "off", [*hard, "controllers.master.eba.enabled=false", "controllers.slave.eba.enabled=false"]
    )
    s_on, _ = analyze_bag(on)
    s_off, _ = analyze_bag(off)
    assert s_on["all_finite"]
    assert s_on["master_energy_margin_min_j"] >= -1e-9
    assert s_on["slave_energy_margin_min_j"] >= -1e-9
    assert min(s_off["master_energy_margin_min_j"], s_off["slave_energy_margin_min_j"]) < -1.0


def test_reservoir_in_bag_equals_margin_from_plant_signals(tmp_path):
    bag, _, _ = _record(tmp_path, "r")
    _, sig = analyze_bag(bag)
    b = float(sig.scene["master"]["damping_n_s_per_m"])
    margin = port_energy(sig.master_x_m, sig.master_force_n, b, sig.period_s)
    assert sig.master_reservoir_j is not None
    assert np.allclose(margin, sig.master_reservoir_j, atol=1e-9)
    assert sig.master_reservoir_j.max() > 0.01  # the test is not vacuous: energy flowed


def test_summary_matches_transparency_expectations(tmp_path):
    bag, _, timing = _record(tmp_path, "s")
    s, _ = analyze_bag(bag)
    assert s["packets_sent_forward"] == s["packets_sent_backward"] == 3000
    assert s["packets_lost_forward"] == 0
    assert s["delay_forward_p50_s"] == pytest.approx(0.05)
    assert s["force_alignment_lag_s"] == pytest.approx(0.051)
    assert s["contact_force_max_n"] > 1.0  # the robot reached the wall
    assert s["master_energy_margin_min_j"] >= 0.0 and s["slave_energy_margin_min_j"] >= 0.0
    assert timing.realtime_factor > 0 and not timing.interrupted


def test_cli_run_then_analyze_gives_the_same_numbers(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "haptic_teleop.cli"]
    r = subprocess.run(
        [*cmd, "run", "wall_contact", "--out", str(out), "--set", "scene.duration_s=2"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert "force RMS error" in r.stdout
    first = json.loads((out / "summary.json").read_text())
    assert (out / "plots" / "forces.png").stat().st_size > 10_000
    (out / "summary.json").unlink()
    r2 = subprocess.run([*cmd, "analyze", str(out / "bag"), "--no-plots"], capture_output=True, text=True, timeout=300)
    assert r2.returncode == 0, r2.stderr
    second = json.loads((out / "summary.json").read_text())
    assert first == second
    assert math.isfinite(first["realtime_factor"])


def test_cli_sigint_finishes_the_bag(tmp_path):
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "haptic_teleop.cli.main",
            "run",
            "wall_contact",
            "--out",
            str(out),
            "--no-plots",
            "--set",
            "scene.duration_s=3600",  # the compiled loop runs 600 s of scene in about a second
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    deadline = time.monotonic() + 60
    while not (out / "bag").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=120)
    assert p.returncode == 130, stderr
    assert "(interrupted)" in stdout
    with BagReader(out / "bag") as r:
        n = len(r.read("/master/joint_states").log_ns)
        assert 0 < n < 3_600_000
        assert json.loads(r.string("/haptic_teleop/run_info"))["interrupted"] is True


def test_run_pauses_the_cycle_collector_and_restores_it(monkeypatch):
    """The loop runs with gc paused (it makes no cycles); afterwards gc is as it was, also after
    a failing tick."""
    import gc

    scene = load_scene(DEFAULT, overrides=["scene.duration_s=0.2"])
    seen = []
    engine = Engine(scene)
    engine.run(progress=lambda n: seen.append(gc.isenabled()), handle_sigint=False)
    assert seen and not any(seen)
    assert gc.isenabled()
    gc.disable()
    try:
        Engine(scene).run(handle_sigint=False)
        assert not gc.isenabled()
    finally:
        gc.enable()
    failing = Engine(scene, loop="python")
    monkeypatch.setattr(failing.slave, "step", None)  # the loop calls it: the first tick fails
    with pytest.raises(TypeError):
        failing.run(handle_sigint=False)
    assert gc.isenabled()
