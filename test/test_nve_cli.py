"""`haptic-teleop run` and `analyze` on NVE scenes: outputs from the bag, the same seed the same
bag bytes, Ctrl-C mid-loop leaves a closed bag and an interrupted summary, bad keys exit 2."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.analysis.nve_summary import PLOT_FILES, samples_missing, topics_missing
from haptic_teleop.interrupt import TEST_PAUSE_ENV
from haptic_teleop.record.nve_columns import nve_topics
from haptic_teleop.record.reader import BagReader, TopicData

CLI = [sys.executable, "-m", "haptic_teleop.cli"]


def _run(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300, env=env, check=False)


def test_run_nve_push_writes_summary_plots_and_bag(tmp_path: Path) -> None:
    out = tmp_path / "push"
    r = _run("run", "nve_push", "--out", str(out), "--set", "scene.duration_s=3", "--quiet")
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "nve" and summary["ticks"] == 3000 and not summary["interrupted"]
    client = summary["clients"]["client"]
    assert client["round_trip_s"]["median"] == pytest.approx(0.301, abs=1e-9)
    assert summary["server_energy"]["passive"] and summary["messages_missing"] == {}
    for name in PLOT_FILES:
        assert (out / "plots" / name).stat().st_size > 10_000
    with BagReader(out / "bag") as reader:
        assert reader.nve_schema is not None and reader.nve_schema.clients == ("client",)
        topics = [(t.topic, reader.read(t.topic)) for t in nve_topics(reader.nve_schema)]
    _missing_messages_are_found(topics)
    # `analyze` recomputes the same summary from the bag alone
    again = tmp_path / "again"
    r2 = _run("analyze", str(out / "bag"), "--out", str(again), "--no-plots", "--quiet")
    assert r2.returncode == 0, r2.stderr
    assert json.loads((again / "summary.json").read_text())["clients"] == summary["clients"]


def _without(data: TopicData, ticks: list[int]) -> TopicData:
    keep = np.ones(len(data.log_ns), dtype=bool)
    keep[ticks] = False
    stamps = None if data.stamp_ns is None else data.stamp_ns[keep]
    return TopicData(data.log_ns[keep], stamps, data.values[keep], data.fields)


def _missing_messages_are_found(topics: list[tuple[str, TopicData]]) -> None:
    """A live recorder may miss per-tick messages (best effort): found per topic, by the stamps
    where the messages have a header (the HIP's, the object's own gaps), by the count where not
    (the coupling's: one message short is taken for a killed run's last tick, which is not a loss)."""
    names = [t for t, _ in topics]
    assert topics_missing(topics) == {}
    hip, coupling = names.index("/nve/client/hip/joint_states"), names.index("/nve/client/coupling")
    lossy = list(topics)
    lossy[hip] = (names[hip], _without(topics[hip][1], [1200, 1201]))
    lossy[coupling] = (names[coupling], _without(topics[coupling][1], [40, 41]))
    lossy[0] = (names[0], _without(topics[0][1], [2000, 2500, 2501]))
    assert topics_missing(lossy) == {names[0]: 3, names[hip]: 2, names[coupling]: 2}
    killed = [(t, _without(d, [len(d.log_ns) - 1]) if i else d) for i, (t, d) in enumerate(topics)]
    assert topics_missing(killed) == {}
    # a live recorder's filled ticks (run_info) count too, the larger count where both see a topic
    filled = {"samples_filled": {names[hip]: 5, names[0]: 0, names[coupling]: 1}}
    assert samples_missing({names[hip]: 2}, filled) == {names[hip]: 5, names[coupling]: 1}
    assert samples_missing({}, {}) == {}


def test_nve_same_seed_same_bag_other_seed_other_bag(tmp_path: Path) -> None:
    def digest(name: str, seed: int) -> str:
        out = tmp_path / name
        r = _run(
            "run", "nve_two_clients", "--out", str(out), "--seed", str(seed),
            "--set", "scene.duration_s=1.5", "--quiet", "--no-plots",
        )  # fmt: skip
        assert r.returncode == 0, r.stderr
        return hashlib.sha256((out / "bag" / "bag.mcap").read_bytes()).hexdigest()

    a, b, c = digest("a", 1), digest("b", 1), digest("c", 2)
    assert a == b != c


def test_ctrl_c_mid_loop_closes_the_bag(tmp_path: Path) -> None:
    out = tmp_path / "stopped"
    env = {**os.environ, TEST_PAUSE_ENV: "loop"}
    p = subprocess.Popen(
        [*CLI, "run", "nve_push", "--out", str(out), "--set", "scene.duration_s=600", "--quiet", "--no-plots"],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert p.stderr is not None
    line = p.stderr.readline()
    assert "phase loop" in line, line
    p.send_signal(signal.SIGINT)
    assert p.wait(timeout=120) == 130
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] and 0 < summary["ticks"] < 600_000
    with BagReader(out / "bag") as reader:
        assert reader.nve_schema is not None


@pytest.mark.parametrize(
    "setting",
    ["nve.clients.0.coupling.client_stiffness_n_per_m=-1", "nve.axes=2", "master.mass_kg=1"],
)
def test_bad_nve_input_is_one_line_and_exit_2(tmp_path: Path, setting: str) -> None:
    r = _run("run", "nve_push", "--out", str(tmp_path / "x"), "--set", setting)
    assert r.returncode == 2
    lines = [x for x in r.stderr.strip().splitlines() if x]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "x").exists()


def test_a_constant_round_trip_is_drawn_flat_with_plain_labels():
    """The round-trip panel of a run whose measured round trip never changes: a flat line in a
    +-10 % range and plain tick labels, not "1e-10+3.01e2" over round-off magnified to fill the axis;
    a changing signal keeps matplotlib's own limits."""
    import numpy as np
    from matplotlib.figure import Figure

    from haptic_teleop.analysis.nve_summary import _readable_y

    ax = Figure().subplots()
    ax.plot(np.arange(5), 301.0 + np.array([0.0, 1e-13, 0.0, -1e-13, 0.0]))
    _readable_y(ax)
    assert ax.get_ylim() == pytest.approx((270.9, 331.1))
    ax.figure.canvas.draw()
    assert ax.yaxis.get_major_formatter().get_offset() == ""
    moving = Figure().subplots()
    moving.plot(np.arange(5), [0.0, 1.0, 2.0, 3.0, 4.0])
    before = moving.get_ylim()
    _readable_y(moving)
    assert moving.get_ylim() == before
