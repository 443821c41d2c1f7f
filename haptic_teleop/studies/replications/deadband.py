"""Seed 001's perceptual deadband on a 3-DoF contact-rich scene: packet-rate reduction and
distortion against the deadband parameter p (docs/codec_deadband_experiments.md, "Deadband rate and distortion").

The scene (default: the Touch master and UR5e slave of `touch_ur5e_wall` with the table 1 cm below
the tool's start and the operator tapping it with a 1 Hz sinusoid of 3 cm around the start: contact
made and broken every second, the tool on the table about a third of the time) is run and
recorded; the two streams seed 001 codes are read back from the bag: the master handle's velocity
(forward, 3 axes) and the contact force at the slave's tool (backward, 3 axes). Each is coded with
the deadband (core/deadband.py: send when |v_i - v_c| > p |v_i|, v_i the last sent vector; the
receiver holds) at every p of seed 001's list, over a lossless channel: the rate and the
distortion the coding alone causes, on the recorded signals (open loop: the channel is not yet in
the engine, docs/codec_deadband_experiments.md). Distortion: RMS and peak of the reconstruction error's norm, and
relative to the just-noticeable difference: |e| / (JND |v|) with a Weber fraction JND (default
0.1 for force and velocity, an assumption: docs/codec_deadband_experiments.md).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.args import number
from haptic_teleop.studies.replications.recorded import BagRuns, bags_line, compression
from haptic_teleop.studies.replications.tables import finish_figure, markdown, write_csv

HELP = (
    "seed 001's perceptual deadband on a 3-DoF contact-rich scene: packet-rate reduction and distortion "
    "(RMS, peak, against the JND) of force and velocity for p from 0 to 40 %; plot, CSV, table"
)
P_LIST = (0.0, 0.025, 0.05, 0.075, 0.10, 0.125, 0.15, 0.20, 0.25, 0.30, 0.35, 0.40)  # seed 001's
TAPPING = (
    "operator.profile=sinusoid",
    "operator.amplitude_m=0.03",
    "operator.frequency_hz=1.0",
    "operator.start_s=0.3",
    "slave.wall.point_m=[-0.49, -0.13, 0.4278]",  # the table 1 cm below the tool's start
)
SEED_001 = {"force": (0.05, 0.90), "velocity": (0.20, 0.75)}  # "almost 90 % at 5 %", "almost 75 % at 20 %"
PERIOD_NS = 1_000_000


def streams(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    """(handle velocity, contact force) per tick, (ticks, 3) each, from the bag."""
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as r:
        fwd = r.read("/forward/sent")
        bwd = r.read("/backward/sent")
    vel = np.stack([fwd.field(f"velocity[master_{a}]") for a in "xyz"], axis=1)
    force = np.stack([bwd.field(f"effort[slave_{a}]") for a in "xyz"], axis=1)
    return vel, force


def code(signal: np.ndarray, p: float, jnd: float, floor: float) -> dict[str, float]:
    """One stream through the deadband at p, lossless: sent fraction and the error of the held
    reconstruction (RMS and peak of |e|; |e| / (JND |v|) where |v| > floor: its mean and the
    fraction of those ticks above 1 JND)."""
    from haptic_teleop.core.deadband import DeadbandConfig, build_deadband

    codec = build_deadband(DeadbandConfig(deadband=p), signal.shape[1], PERIOD_NS, 0)
    enc, dec = codec.encoder, codec.decoder
    rec = np.empty_like(signal)
    sent = 0
    for n, v in enumerate(signal.tolist()):
        for pk in enc.send(n, n * PERIOD_NS, tuple(v)):
            sent += 1
            dec.receive(pk, n * PERIOD_NS)
        s = dec.sample(n, n * PERIOD_NS)
        rec[n] = s if s is not None else v
    e = np.linalg.norm(rec - signal, axis=1)
    mag = np.linalg.norm(signal, axis=1)
    big = mag > floor
    rel = e[big] / (jnd * mag[big]) if big.any() else np.zeros(0)
    return {
        "reduction": 1.0 - sent / len(signal),
        "rms": float(np.sqrt(np.mean(e * e))),
        "peak": float(e.max()),
        "jnd_mean": float(rel.mean()) if rel.size else math.nan,
        "above_jnd": float(np.mean(rel > 1.0)) if rel.size else math.nan,
    }


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="output directory, new or empty (default runs/deadband-NNN)")
    p.add_argument("--scene", default="touch_ur5e_wall", help="an arm scene (default touch_ur5e_wall)")
    p.add_argument("--duration-s", type=number(1.0, 600.0), default=8.0, help="simulated time [s] (default 8)")
    p.add_argument("--jnd", type=number(0.0, 1.0, low_open=True), default=0.1, help="Weber fraction (default 0.1)")
    p.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override a key of the scene")
    p.add_argument(
        "--no-tapping", action="store_true", help="keep the scene's own operator and table (default: 1 Hz tapping)"
    )
    p.add_argument("--discard-bags", action="store_true", help="read the recorded run's bag, then delete it")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def main(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.errors import InputError
    from haptic_teleop.scene.load import find_scene, load_scene

    # the bag zstd-compressed when kept (recorded.compression); a --set may say otherwise
    overrides = [
        compression(args.discard_bags),
        f"scene.duration_s={args.duration_s}",
        *(() if args.no_tapping else TAPPING),
        *(args.set or ()),
    ]
    scene = load_scene(find_scene(args.scene), overrides=overrides)
    if not scene.config.is_arm:
        raise InputError(f"--scene {args.scene}: not an arm scene; allowed: a 3-DoF arm scene (touch_ur5e_wall, ...)")
    out = Path(args.out) if args.out else default_out("deadband")
    check_out_dir(out)
    runs = BagRuns(out / "bags", args.discard_bags)
    with runs.bag("recorded", "the recorded run", f"--scene {args.scene}", overrides) as bag:
        record_run(scene, bag, handle_sigint=False, parallel=False)
        vel, force = streams(bag)
    rows: list[list[Any]] = []
    results: dict[str, list[dict[str, float]]] = {"force": [], "velocity": []}
    bar: Any = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=2 * len(P_LIST), unit="case", desc="deadband", leave=False, file=sys.stderr)
    for name, sig, floor in (("force", force, 0.5), ("velocity", vel, 0.005)):
        for p in P_LIST:
            r = code(sig, p, args.jnd, floor)
            results[name].append(r)
            rows.append([name, p * 100, r["reduction"] * 100, r["rms"], r["peak"], r["jnd_mean"], r["above_jnd"] * 100])
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    header = ["stream", "p [%]", "packets saved [%]", "RMS error", "peak error", "mean |e| / JND", "ticks > 1 JND [%]"]
    write_csv(out / "deadband.csv", header, rows)
    table = markdown(header, rows)
    (out / "deadband.md").write_text(table)
    plot(results, out / "deadband.png", args.jnd)
    if not args.quiet:
        sys.stdout.write(table + f"\n{out / 'deadband.png'}\n{bags_line(out, args.discard_bags)}\n")
    return 0


def plot(results: dict[str, list[dict[str, float]]], path: Path, jnd: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    ps = np.array(P_LIST) * 100
    for name, colour in (("force", "tab:red"), ("velocity", "tab:blue")):
        a1.plot(ps, [r["reduction"] * 100 for r in results[name]], "o-", color=colour, label=f"{name} (this scene)")
        sp, sr = SEED_001[name]
        a1.plot([sp * 100], [sr * 100], "*", ms=14, color=colour, label=f"{name}: seed 001 ({sr:.0%} at {sp:.0%})")
        a2.plot(ps, [r["jnd_mean"] for r in results[name]], "o-", color=colour, label=name)
    a1.set(xlabel="deadband p [%]", ylabel="packets saved [%]", title="Packet-rate reduction", ylim=(0, 100))
    a2.axhline(1.0, color="0.5", ls=":", label="1 JND")
    a2.set(xlabel="deadband p [%]", ylabel=f"mean |error| / (JND |signal|), JND = {jnd:g}", title="Distortion")
    finish_figure(fig, (a1, a2), path, fontsize=8)
