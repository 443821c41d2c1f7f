"""A live arm bag's sent velocities (the handle's on /forward/sent, the tool's on /backward/sent),
checked against the rate of change of the positions recorded beside them: shared by the plain
(test_live_arm) and codec (test_live_codec) live arm tests."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def check_sent_velocities(out: Path, source: dict[str, str]) -> None:
    """The bag of the live run in `out`: each direction's sent velocity is not zero and follows its
    position's rate of change over 25 ms windows (correlation > 0.7: 0.88-0.95 seen; zero, another
    axis or a sign flip give <= 0); `source`: direction -> the live topic the recorder filled them
    from, whose held-over rows live_run.json counts (samples_filled). Where more than a tenth of the
    rows are held over (the recorder missed the samples on a loaded machine) only the first holds:
    a held row repeats a velocity beside a position of another tick."""
    from haptic_teleop.record.reader import BagReader

    with BagReader(out / "bag") as r:
        sent = r.read("/forward/sent")
        rows = {"forward": sent.values, "backward": r.read("/backward/sent").values}
    period = float(np.median(np.diff(np.asarray(sent.stamp_ns)))) * 1e-9
    info = json.loads((out / "live_run.json").read_text())
    assert set(source.values()) <= set(info["samples_filled"]), info["samples_filled"]
    for d, name in (("forward", "handle"), ("backward", "tool")):
        x, v = rows[d][:, 0:3], rows[d][:, 3:6]
        assert np.abs(v).max() > 1e-3, f"{name} velocity all zero"
        filled = info["samples_filled"][source[d]]
        if filled > 0.1 * len(x):  # mostly held rows (a loaded machine: 1,666 of 1,976 seen): not judged
            print(f"{name}: {filled} of {len(x)} rows held over; the rate is not compared")
            continue
        axis = int(np.argmax(np.ptp(x, axis=0)))  # the axis it moved along most
        # A sample lost on its way to the recorder holds the previous row, which puts a step into a
        # tick-by-tick difference (counted in samples_filled): hence the windows.
        box = np.ones(25) / 25
        rate = np.convolve(np.gradient(x[:, axis], period), box, mode="valid")
        corr = np.corrcoef(rate, np.convolve(v[:, axis], box, mode="valid"))[0, 1]
        print(f"{name}: peak speed {np.abs(v[:, axis]).max():.4f} m/s, correlation with dx/dt {corr:.3f}")
        assert corr > 0.7, (name, corr)
