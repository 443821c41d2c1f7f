"""Seed 001's perceptual deadband in the loop: the tapping scene of `experiment deadband` run through
the engine with the deadband in the channel, on the forward direction, the backward one or both, at
every p of seed 001's list (docs/codec_deadband_experiments.md, "In the loop").

Each case is a whole run of the scene (same seed) with `network.<d>.codec: {kind: deadband,
deadband: p}` (assembly/channel.py: forward triggers on the handle's velocity, backward on the
contact force and the tool's velocity; the position rides along; the receiver holds). Per run: the
packet-rate reduction of each coded direction (the encoder's counters: 1 - sent / offered, the
`codec_packet_reduction_<d>` of summary.json for a deadband), and against the reference run of
the same scene and seed without a codec, tick by tick: the force the master applies to the
operator's hand (RMS and peak of the difference's norm, and |e| / (JND |F_ref|) where |F_ref| >
0.5 N, as the open-loop table), the slave tool's position and the contact force. The reference
run's own streams (the handle's velocity, the contact force) are also coded open loop (the
`deadband` experiment's coding) for the comparison. The runs go to `--jobs` processes (spawned:
each loads the scene and builds its own engine); every run is seeded by the scene's seed, so the
table does not depend on the number of processes.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.args import number
from haptic_teleop.studies.replications.deadband import P_LIST, SEED_001, TAPPING, code
from haptic_teleop.studies.replications.recorded import BagRuns, bags_line, compression
from haptic_teleop.studies.replications.tables import markdown, write_csv

HELP = (
    "seed 001's perceptual deadband in the loop: the tapping arm scene run with the deadband on the forward, "
    "backward or both channel directions for p from 0 to 40 %; packets saved and the change of the master's "
    "force, the tool's position and the contact force against the uncoded run; plot, CSV, table"
)
CASES = ("forward", "backward", "both")
DIRS = ("forward", "backward")
EBA_TOL_N = 1e-6  # a tick whose applied master force is below the desired one by more: EBA scaled it
FORCE_FLOOR_N = 0.5  # the open-loop table's floor of the JND-relative force error
HEADER = [
    "coded",
    "p [%]",
    "forward saved [%]",
    "backward saved [%]",
    "coded velocity RMS error [m/s]",
    "coded velocity mean error / JND",
    "coded force RMS error [N]",
    "coded force mean error / JND",
    "master force RMS diff [N]",
    "master force peak diff [N]",
    "master force mean error / JND",
    "master ticks > 1 JND [%]",
    "tool position RMS diff [mm]",
    "tool position peak diff [mm]",
    "contact force RMS diff [N]",
    "contact force peak diff [N]",
    "contact force max [N]",
    "master EBA-scaled ticks [%]",
    "master force EBA removed RMS [N]",
]
OPEN_HEADER = [
    "stream",
    "p [%]",
    "packets saved [%]",
    "RMS error",
    "peak error",
    "mean error / JND",
    "ticks > 1 JND [%]",
]


def p_list(text: str) -> tuple[float, ...]:
    """`--p`: comma-separated percents, each in [0, 100)."""
    allowed = "allowed: comma-separated percents, each >= 0 and < 100 (e.g. 0,5,20)"
    out: list[float] = []
    for part in text.split(","):
        try:
            x = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{part!r} is not a number; {allowed}") from None
        if not math.isfinite(x) or not 0.0 <= x < 100.0:
            raise argparse.ArgumentTypeError(f"{part}: {allowed}")
        out.append(x / 100.0)
    if len(set(out)) != len(out):
        raise argparse.ArgumentTypeError(f"{text}: a p appears twice; {allowed}")
    return tuple(sorted(out))


def case_list(text: str) -> tuple[str, ...]:
    """`--coded`: comma-separated directions to code, each one of CASES."""
    got = tuple(dict.fromkeys(s.strip() for s in text.split(",")))
    bad = [s for s in got if s not in CASES]
    if bad or not got:
        raise argparse.ArgumentTypeError(f"{','.join(bad) or text!r}: allowed: comma-separated {', '.join(CASES)}")
    return got


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="output directory, new or empty (default runs/deadband-loop-NNN)")
    p.add_argument("--scene", default="touch_ur5e_wall", help="an arm scene (default touch_ur5e_wall)")
    p.add_argument("--duration-s", type=number(1.0, 600.0), default=8.0, help="simulated time [s] (default 8)")
    p.add_argument("--seed", type=number(0, 2**31 - 1, kind=int), help="the scene's seed (default: the scene's own)")
    p.add_argument("--jnd", type=number(0.0, 1.0, low_open=True), default=0.1, help="Weber fraction (default 0.1)")
    p.add_argument(
        "--p", type=p_list, default=P_LIST, metavar="P1,P2,...", help="deadband p in percent (default seed 001's list)"
    )
    p.add_argument(
        "--coded",
        type=case_list,
        default=CASES,
        metavar="CASES",
        help="which directions carry the deadband, comma-separated: forward, backward, both (default all three)",
    )
    p.add_argument(
        "--jobs", type=number(1, 64, kind=int), default=min(2, os.cpu_count() or 1), help="processes (default 2)"
    )
    p.add_argument(
        "--reconstruction",
        choices=("hold", "extrapolate"),
        default="hold",
        help="the receiver's reconstruction (default hold, seed 001's; extrapolate: no held-sample error columns)",
    )
    p.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override a key of the scene")
    p.add_argument(
        "--no-tapping", action="store_true", help="keep the scene's own operator and table (default: 1 Hz tapping)"
    )
    p.add_argument("--discard-bags", action="store_true", help="read each run's bag, then delete it")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def codec_overrides(case: str | None, p: float, reconstruction: str = "hold") -> list[str]:
    """The scene overrides that put the deadband at p on the case's directions (none: reference)."""
    if case is None:
        return []
    dirs = ("forward", "backward") if case == "both" else (case,)
    return [f"network.{d}.codec={{kind: deadband, deadband: {p!r}, reconstruction: {reconstruction}}}" for d in dirs]


def run_case(scene_name: str, overrides: Sequence[str], seed: int | None, bag: str) -> dict[str, Any]:
    """One run in the Python arm loop (the loop that runs an arm scene's codecs) recorded to `bag`;
    the columns the table compares and the codec counters, read back from the bag."""
    from haptic_teleop.analysis.metrics import read_run_info
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.record.reader import BagReader
    from haptic_teleop.scene.load import find_scene, load_scene

    scene = load_scene(find_scene(scene_name), overrides=list(overrides), seed=seed)
    record_run(scene, Path(bag), parallel=False, handle_sigint=False, loop="python")
    with BagReader(bag) as reader:
        rows = reader.read_ticks()
        s = reader.schema
        info = read_run_info(reader)
    out: dict[str, Any] = {
        g: np.array(rows[:, s.group(g)])
        for g in ("m_force_n", "m_force_desired_n", "m_v_m_per_s", "s_x_m", "s_contact_n")
    }
    for d, col in (("forward", "fwd_rx_seq"), ("backward", "bwd_rx_seq")):
        out[f"held_{d}"] = held(rows[:, s.col[col]])
    out["facts"] = {k: v for k, v in info.items() if k.startswith("codec_")}
    return out


def held(rx_seq: np.ndarray) -> np.ndarray:
    """Per tick, the tick of the sample the receiver plays (hold: the newest arrival so far; -1
    before the first), from the run's `received` column (the newest arrival's seq, -1 when none)."""
    idx = np.where(rx_seq >= 0, np.arange(len(rx_seq)), -1)
    last = np.maximum.accumulate(idx)
    out = np.full(len(rx_seq), -1, dtype=np.int64)
    ok = last >= 0
    out[ok] = rx_seq[last[ok]].astype(np.int64)
    return out


def coding_error(run: dict[str, Any], ref: dict[str, Any], d: str, jnd: float) -> tuple[float, float]:
    """The coded stream's own error in the run (the open-loop table's distortion, in the loop): at
    each tick, the stream's value in the sample the receiver holds against its value in the sample
    an uncoded channel would deliver (the reference run's delay), both from this run. (RMS of the
    error's norm, mean |e| / (JND |signal|) over the ticks where |signal| is above the open-loop
    floor.) The reconstruction is hold: an extrapolating codec would need its decoder's output."""
    sig, floor = (run["m_v_m_per_s"], 0.005) if d == "forward" else (run["s_contact_n"], FORCE_FLOOR_N)
    got, plain = run[f"held_{d}"], ref[f"held_{d}"]
    ok = (got >= 0) & (plain >= 0)
    e = np.linalg.norm(sig[got[ok]] - sig[plain[ok]], axis=1)
    mag = np.linalg.norm(sig[plain[ok]], axis=1)
    big = mag > floor
    rel = e[big] / (jnd * mag[big])
    return float(np.sqrt(np.mean(e * e))), float(rel.mean()) if rel.size else math.nan


def _job(job: tuple[str, Sequence[str], int | None, str]) -> dict[str, Any]:
    return run_case(*job)


def saved(facts: dict[str, Any], direction: str) -> float:
    """1 - sent / offered of the direction's encoder (NaN when the direction has no codec)."""
    f = facts.get(f"codec_{direction}")
    if not f:
        return math.nan
    return 1.0 - float(f["encoder_sent"]) / float(f["encoder_offered"])


def compare(run: dict[str, Any], ref: dict[str, Any], jnd: float, held_error: bool = True) -> dict[str, float]:
    """A coded run against the reference: the norm of the per-tick difference of the master's force,
    the tool's position and the contact force (RMS, peak), the master force's |e| / (JND |F_ref|)."""
    ef = np.linalg.norm(run["m_force_n"] - ref["m_force_n"], axis=1)
    ex = np.linalg.norm(run["s_x_m"] - ref["s_x_m"], axis=1)
    ec = np.linalg.norm(run["s_contact_n"] - ref["s_contact_n"], axis=1)
    mag = np.linalg.norm(ref["m_force_n"], axis=1)
    big = mag > FORCE_FLOOR_N
    applied = np.linalg.norm(run["m_force_n"], axis=1)
    desired = np.linalg.norm(run["m_force_desired_n"], axis=1)
    rel = ef[big] / (jnd * mag[big]) if big.any() else np.zeros(0)

    def rms(e: np.ndarray) -> float:
        return float(np.sqrt(np.mean(e * e)))

    own = {
        d: coding_error(run, ref, d, jnd) if held_error and f"codec_{d}" in run["facts"] else (math.nan, math.nan)
        for d in DIRS
    }
    return {
        "velocity_rms": own["forward"][0],
        "velocity_jnd": own["forward"][1],
        "coded_force_rms": own["backward"][0],
        "coded_force_jnd": own["backward"][1],
        "forward_saved": saved(run["facts"], "forward"),
        "backward_saved": saved(run["facts"], "backward"),
        "force_rms": rms(ef),
        "force_peak": float(ef.max()),
        "jnd_mean": float(rel.mean()) if rel.size else math.nan,
        "above_jnd": float(np.mean(rel > 1.0)) if rel.size else math.nan,
        "x_rms_mm": rms(ex) * 1e3,
        "x_peak_mm": float(ex.max()) * 1e3,
        "contact_rms": rms(ec),
        "contact_peak": float(ec.max()),
        "contact_max": float(np.linalg.norm(run["s_contact_n"], axis=1).max()),
        "eba_scaled": float(np.mean(applied < desired - EBA_TOL_N)),
        "eba_removed": rms(desired - applied),
    }


def main(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.errors import InputError
    from haptic_teleop.scene.load import find_scene, load_scene

    # the runs' bags zstd-compressed when kept (recorded.compression); a --set may say otherwise
    base = [
        compression(args.discard_bags),
        f"scene.duration_s={args.duration_s}",
        *(() if args.no_tapping else TAPPING),
        *(args.set or ()),
    ]
    path = find_scene(args.scene)
    scene = load_scene(path, overrides=base, seed=args.seed)
    if not scene.config.is_arm:
        raise InputError(f"--scene {args.scene}: not an arm scene; allowed: a 3-DoF arm scene (touch_ur5e_wall, ...)")
    # A coded case loads too (a --set that contradicts the codec is one line now, not in a worker).
    load_scene(path, overrides=[*base, *codec_overrides("both", args.p[-1], args.reconstruction)], seed=args.seed)
    out = Path(args.out) if args.out else default_out("deadband-loop")
    check_out_dir(out)
    cases: list[tuple[str, float]] = [(c, p) for c in args.coded for p in args.p]
    bags = BagRuns(out / "bags", args.discard_bags)
    jobs = [(args.scene, base, args.seed, str(bags.reserve("uncoded", "uncoded", "reference", base)))]
    for c, p in cases:
        ov = [*base, *codec_overrides(c, p, args.reconstruction)]
        jobs.append((args.scene, ov, args.seed, str(bags.reserve(f"{c}_p{p * 100:g}", c, f"p = {p:g}", ov))))
    results = _run_all(jobs, args.jobs, args.quiet)
    for job in jobs:
        bags.drop(Path(job[3]))
    ref, runs = results[0], results[1:]
    rows: list[list[Any]] = []
    table: dict[str, list[dict[str, float]]] = {c: [] for c in args.coded}
    for (c, p), run in zip(cases, runs, strict=True):
        m = compare(run, ref, args.jnd, held_error=args.reconstruction == "hold")
        table[c].append(m)
        rows.append(
            [
                c,
                p * 100,
                m["forward_saved"] * 100,
                m["backward_saved"] * 100,
                m["velocity_rms"],
                m["velocity_jnd"],
                m["coded_force_rms"],
                m["coded_force_jnd"],
                m["force_rms"],
                m["force_peak"],
                m["jnd_mean"],
                m["above_jnd"] * 100,
                m["x_rms_mm"],
                m["x_peak_mm"],
                m["contact_rms"],
                m["contact_peak"],
                m["contact_max"],
                m["eba_scaled"] * 100,
                m["eba_removed"],
            ]
        )
    # Open loop on the reference run's own streams (the `deadband` experiment's coding).
    open_rows: list[list[Any]] = []
    open_loop: dict[str, list[dict[str, float]]] = {"force": [], "velocity": []}
    for name, sig, floor in (("force", ref["s_contact_n"], FORCE_FLOOR_N), ("velocity", ref["m_v_m_per_s"], 0.005)):
        for p in args.p:
            r = code(sig, p, args.jnd, floor)
            open_loop[name].append(r)
            open_rows.append(
                [name, p * 100, r["reduction"] * 100, r["rms"], r["peak"], r["jnd_mean"], r["above_jnd"] * 100]
            )
    write_csv(out / "deadband_loop.csv", HEADER, rows)
    write_csv(out / "deadband_loop_open.csv", OPEN_HEADER, open_rows)
    text = (
        "In the loop (against the uncoded run of the same scene and seed):\n\n"
        + markdown(HEADER, rows)
        + "\nOpen loop (the uncoded run's streams coded offline):\n\n"
        + markdown(OPEN_HEADER, open_rows)
    )
    (out / "deadband_loop.md").write_text(text)
    plot(args.p, table, open_loop, out / "deadband_loop.png", args.jnd)
    if not args.quiet:
        sys.stdout.write(text + f"\n{out / 'deadband_loop.png'}\n{bags_line(out, args.discard_bags)}\n")
    return 0


def _run_all(
    jobs: Sequence[tuple[str, Sequence[str], int | None, str]], n_proc: int, quiet: bool
) -> list[dict[str, Any]]:
    """Every run, in order; in `n_proc` spawned processes when more than one, with a progress bar."""
    bar: Any = None
    if not quiet:
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), unit="run", desc="deadband-loop", leave=False, file=sys.stderr)
    results: list[dict[str, Any] | None] = [None] * len(jobs)
    try:
        if n_proc <= 1:
            for i, job in enumerate(jobs):
                results[i] = _job(job)
                if bar is not None:
                    bar.update(1)
        else:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor, as_completed

            with ProcessPoolExecutor(max_workers=n_proc, mp_context=mp.get_context("spawn")) as pool:
                futures = {pool.submit(_job, job): i for i, job in enumerate(jobs)}
                try:
                    for fut in as_completed(futures):
                        results[futures[fut]] = fut.result()
                        if bar is not None:
                            bar.update(1)
                except BaseException:
                    for f in futures:
                        f.cancel()
                    raise
    finally:
        if bar is not None:
            bar.close()
    return [r for r in results if r is not None]


def plot(
    ps: Sequence[float],
    table: dict[str, list[dict[str, float]]],
    open_loop: dict[str, list[dict[str, float]]],
    path: Path,
    jnd: float,
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ((a1, a2, a3), (a4, a5, a6)) = plt.subplots(2, 3, figsize=(17, 9))
    x = np.array(ps) * 100
    colour = {"forward": "tab:blue", "backward": "tab:red", "both": "tab:purple"}
    stream_colour = {"velocity": "tab:blue", "force": "tab:red"}
    # packets saved: open loop (dashed) against in the loop (solid: one direction coded, dotted: both)
    for name in ("velocity", "force"):
        a1.plot(x, [r["reduction"] * 100 for r in open_loop[name]], "s--", color=stream_colour[name], alpha=0.6,
                label=f"{name}, open loop")  # fmt: skip
    for c, rs in table.items():
        for d, stream in (("forward", "velocity"), ("backward", "force")):
            if c in (d, "both"):
                a1.plot(x, [r[f"{d}_saved"] * 100 for r in rs], "o-" if c == d else "^:", color=stream_colour[stream],
                        label=f"{d} ({stream} trigger), in the loop, {c} coded")  # fmt: skip
    for name in ("velocity", "force"):
        sp, sr = SEED_001[name]
        a1.plot([sp * 100], [sr * 100], "*", ms=14, color=stream_colour[name],
                label=f"{name}: seed 001 ({sr:.0%} at {sp:.0%})")  # fmt: skip
    a1.set(xlabel="deadband p [%]", ylabel="packets saved [%]", title="Packet-rate reduction", ylim=(0, 100))
    # the coded stream's own error: open loop against in the loop
    for name in ("velocity", "force"):
        a2.plot(x, [r["jnd_mean"] for r in open_loop[name]], "s--", color=stream_colour[name], alpha=0.6,
                label=f"{name}, open loop")  # fmt: skip
    for c, rs in table.items():
        for key, stream, d in (("velocity_jnd", "velocity", "forward"), ("coded_force_jnd", "force", "backward")):
            if c in (d, "both"):
                a2.plot(x, [r[key] for r in rs], "o-" if c == d else "^:", color=stream_colour[stream],
                        label=f"{stream}, in the loop, {c} coded")  # fmt: skip
    a2.axhline(1.0, color="0.5", ls=":", label="1 JND")
    a2.set(
        xlabel="deadband p [%]",
        ylabel=f"mean |e| / (JND |signal|), JND = {jnd:g}",
        title="The coded stream's own error (held vs. sent)",
    )
    for c, rs in table.items():
        a3.plot(x, [r["jnd_mean"] for r in rs], "o-", color=colour[c], label=f"{c} coded")
    a3.axhline(1.0, color="0.5", ls=":", label="1 JND")
    a3.set(
        xlabel="deadband p [%]",
        ylabel=f"mean |F_m - F_m,ref| / (JND |F_m,ref|), JND = {jnd:g}",
        title="Force at the operator's hand vs. the uncoded run",
    )
    for c, rs in table.items():
        a4.plot(x, [r["x_rms_mm"] for r in rs], "o-", color=colour[c], label=f"RMS, {c} coded")
        a4.plot(x, [r["x_peak_mm"] for r in rs], "^:", color=colour[c], alpha=0.7, label=f"peak, {c} coded")
    a4.set(xlabel="deadband p [%]", ylabel="|x_s - x_s,ref| [mm]", title="Slave tool position vs. the uncoded run")
    for c, rs in table.items():
        a5.plot(x, [r["contact_rms"] for r in rs], "o-", color=colour[c], label=f"RMS, {c} coded")
        a5.plot(x, [r["contact_peak"] for r in rs], "^:", color=colour[c], alpha=0.7, label=f"peak, {c} coded")
    a5.set(xlabel="deadband p [%]", ylabel="|f_c - f_c,ref| [N]", title="Contact force vs. the uncoded run")
    for c, rs in table.items():
        a6.plot(x, [r["contact_max"] for r in rs], "o-", color=colour[c], label=f"{c} coded")
    a6.set(xlabel="deadband p [%]", ylabel="max |f_c| [N]", title="Largest contact force of the run (p = 0: uncoded)")
    for a in (a1, a2, a3, a4, a5, a6):
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
