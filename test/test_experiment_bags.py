"""Experiment runs as bags (studies/replications/recorded.py): a run's tick rows read back from its
bag are the engine's, bit for bit; BagRuns names, indexes and discards the bags."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from haptic_teleop.engine.lockstep import COL, Engine
from haptic_teleop.scene.load import find_scene, load_scene
from haptic_teleop.studies.replications.recorded import BagRuns, record_ticks

NOT_RECORDED = {"fwd_occupancy", "bwd_occupancy"}  # no topic holds the buffers' occupancy


@pytest.mark.parametrize(
    ("name", "overrides"),
    [("seed_contact_playout", ["scene.duration_s=1.5"]), ("wall_contact", ["scene.duration_s=1.0"])],
)
def test_tick_rows_read_back_from_a_bag_are_the_engines(tmp_path: Path, name: str, overrides: list[str]) -> None:
    """Every column a topic holds comes back exactly (the released samples' ticks included, with
    reordering and loss in seed_contact_playout), the others are NaN; the packet records are the
    engine's, by seq."""
    scene = load_scene(find_scene(name), overrides=overrides)
    r = Engine(scene).run(handle_sigint=False)  # the same scene in memory, no recorder
    data = r.data[: r.ticks]
    t = record_ticks(scene, tmp_path / "bag")
    assert t.rows.shape == data.shape
    for column, i in COL.items():
        got = t.column(column)
        if column in NOT_RECORDED:
            assert np.isnan(got).all(), column
        else:
            np.testing.assert_array_equal(got, data[:, i], err_msg=column)
    assert (t.column("bwd_rx_seq") >= 0).sum() > 100
    for got, log in ((t.forward_log, r.forward_log), (t.backward_log, r.backward_log)):
        assert len(log) > 100
        np.testing.assert_array_equal(got, log[np.argsort(log[:, 0], kind="stable")])


def test_bag_runs_name_index_and_discard(tmp_path: Path) -> None:
    scene = load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=0.2"])
    runs = BagRuns(tmp_path / "bags")
    for key in ("a", "b"):
        with runs.bag(key, f"run {key}", "s", ("x=1", "y=2")) as bag:
            record_ticks(scene, bag)
    runs.write_index()
    with (tmp_path / "bags" / "index.csv").open() as fh:
        index = list(csv.DictReader(fh))
    assert [r["bag"] for r in index] == ["001_a", "002_b"]
    assert index[1] == {"bag": "002_b", "run": "run b", "settings": "s", "overrides": "x=1 y=2"}
    assert (tmp_path / "bags" / "002_b" / "metadata.yaml").is_file()
    gone = BagRuns(tmp_path / "gone", discard=True)
    with gone.bag("a") as bag:
        record_ticks(scene, bag)
    gone.write_index()
    assert not (tmp_path / "gone").exists()  # the bag and then its empty folder
    temp = BagRuns()
    with temp.bag("a") as bag:
        record_ticks(scene, bag)
        assert bag.is_dir()
    assert not bag.exists() and temp.index[0][0] == "001_a"


def test_a_run_stopped_by_ctrl_c_is_in_the_index_and_its_bag_is_readable(tmp_path: Path) -> None:
    """A KeyboardInterrupt inside a run (after its bag closed) still leaves bags/index.csv naming
    every bag written, the stopped run's too."""
    from haptic_teleop.record.reader import BagReader

    scene = load_scene(find_scene("wall_contact"), overrides=["scene.duration_s=0.2"])
    runs = BagRuns(tmp_path / "bags")
    with runs.bag("first") as bag:
        record_ticks(scene, bag)
    with pytest.raises(KeyboardInterrupt), runs.bag("stopped") as bag:
        record_ticks(scene, bag)
        raise KeyboardInterrupt
    with (tmp_path / "bags" / "index.csv").open() as fh:
        assert [r["bag"] for r in csv.DictReader(fh)] == ["001_first", "002_stopped"]
    with BagReader(tmp_path / "bags" / "002_stopped") as reader:
        assert reader.read_ticks().shape[0] == 200
