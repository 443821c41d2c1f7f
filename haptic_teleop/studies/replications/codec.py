"""Seed 000's transmission control simulation as a command (docs/codec_error_control.md, "Seed 000's
simulation").

Both follow seed 000's set-up (slides 49 to 51): the haptic device is fixed at 0 and a virtual
object moves back and forth between -0.1 m and 0 (so the device penetrates it by 0 to 10 cm); the
object's position is the stream, sent from the server to the client at 1 kHz through a codec, a
lossy link (the project's `core.link.Link`, seed 000's 20 % loss by default as a Gilbert channel)
and the codec's decoder; the client renders F = k d, d the penetration of the object as it
reconstructs it. The "transparent" force is that of the true object at the tick the decoder plays
(each decoder plays a fixed number of ticks behind: the link's delay, and N_HLI1 more for the HLI
decoder, which the tables give as latency). Everything runs in simulated time on the core objects
(deterministic: the same arguments, the same numbers).

- `haptic-teleop experiment hli-filtering`: priority-based filtering under an allowed bandwidth
  (seed: 70 kbit/s) against deadband filtering at 0.7 mm and 2.5 mm: rate on the wire and force error.

- `haptic-teleop experiment error-control`: seed 000's experiment, peak force error over the lossy
  link: prediction-based filtering alone, with FEC over its events, with ARQ over its events
  (mu = 25 ms, nu = 4 and mu = 4 ms, nu = 1), and priority-based filtering (core/event_codec.py).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.args import number
from haptic_teleop.studies.replications.codec_run import PERIOD_NS, PERIOD_S, Result, object_position_m
from haptic_teleop.studies.replications.recorded import BagRuns, bags_line
from haptic_teleop.studies.replications.tables import finish_figure, markdown, rms, write_csv

ERROR_CONTROL_HELP = (
    "seed 000's experiment: peak force error over a 20 % lossy link of prediction-based filtering alone, "
    "with FEC or ARQ over its events, and priority-based filtering; plot, CSV, table"
)
FILTERING_HELP = (
    "seed 000's simulation: priority-based (HLI) filtering under an allowed bandwidth against deadband "
    "filtering at 0.7 and 2.5 mm, over a 20 % lossy link: wire rate and force error; plot, CSV, table"
)


def _links(args: argparse.Namespace) -> tuple[Any, Any]:
    """The forward (server -> client) and reverse (acknowledgements) links, the same effects."""
    from haptic_teleop.core.netconfig import DelayConfig, LossConfig, NetworkEffectsConfig, build_link

    loss = (
        LossConfig(model="bernoulli", probability=args.loss)
        if args.burst_packets <= 1.0
        else LossConfig(model="gilbert", p=_gilbert_p(args.loss, args.burst_packets), r=1.0 / args.burst_packets)
    )
    cfg = NetworkEffectsConfig(loss=loss, delay=DelayConfig(delay_s=args.delay_s))
    return build_link(cfg, args.seed, "object"), build_link(cfg, args.seed, "ack")


def _gilbert_p(loss: float, burst: float) -> float:
    """P(good -> bad) of a simple Gilbert channel with stationary loss `loss` and mean burst `burst`:
    loss = p / (p + r), r = 1 / burst."""
    r = 1.0 / burst
    return loss * r / (1.0 - loss)


def simulate(
    label: str,
    codec: tuple[Any, Any],
    args: argparse.Namespace,
    latency_ticks: int,
    progress: Callable[[int], None] | None = None,
) -> Result:
    """The object's stream through one codec over the lossy link, tick by tick."""
    enc, dec = codec
    link, back = _links(args)
    n_ticks = round(args.duration_s / PERIOD_S)
    t = np.arange(n_ticks) * PERIOD_S
    x = object_position_m(t, args.object_period_s)
    played = np.full(n_ticks, math.nan)
    for n in range(n_ticks):
        now = n * PERIOD_NS
        for p in enc.send(n, now, (float(x[n]),)):
            link.send(p)
        for p in link.deliver(now):
            for ack in dec.receive(p, now):
                back.send(ack)
        for a in back.deliver(now):
            enc.feedback(a, now)
        s = dec.sample(n, now)
        if s is not None:
            played[n] = s[0]
        if progress is not None and n % 1000 == 999:
            progress(1000)
    return Result(label, t, x, played, args.stiffness_n_per_m, latency_ticks, _delay_ticks(args), link.log, back.log)


def _size_of(floats: int) -> int:
    from haptic_teleop.record.layouts import joint_state_size

    return joint_state_size(1, floats)


def _delay_ticks(args: argparse.Namespace) -> int:
    return round(float(args.delay_s) / PERIOD_S)


def deadband(args: argparse.Namespace, threshold_m: float) -> tuple[Any, Any]:
    """Deadband filtering with an absolute threshold (Hirche05's, as the seed compares): p = 0 and
    the floor = the threshold; the receiver holds."""
    from haptic_teleop.core.deadband import DeadbandConfig, build_deadband
    from haptic_teleop.record.layouts import joint_state_size

    cfg = DeadbandConfig(deadband=0.0, min_threshold=threshold_m)
    codec = build_deadband(cfg, 1, PERIOD_NS, joint_state_size(1, 1))
    return codec.encoder, codec.decoder


def hli(args: argparse.Namespace) -> tuple[tuple[Any, Any], int]:
    """Priority-based filtering on the link's own Gilbert channel, under the allowed bandwidth."""
    from haptic_teleop.core.hli_codec import HliConfig, build_hli_codec

    burst = max(args.burst_packets, 1.0)
    p = _gilbert_p(args.loss, burst) if burst > 1.0 else args.loss
    r = 1.0 / burst if burst > 1.0 else 1.0 - args.loss
    cfg = HliConfig(
        threshold_m=args.threshold_m,
        p=p,
        r=r,
        clock="packet",  # the link draws its loss per packet that reaches it (docs/codec.md)
        allowed_bandwidth_bps=args.bandwidth_bps,
        filtering=args.filtering,
    )
    enc, dec = build_hli_codec(cfg, PERIOD_NS, 1)
    return (enc, dec), dec.delay_ticks


def prediction(args: argparse.Namespace) -> tuple[Any, Any]:
    """Every sample sent; the receiver predicts over losses (the reference)."""
    from haptic_teleop.core.prediction import PredictionConfig, build_prediction

    return build_prediction(PredictionConfig(), PERIOD_NS, size_of=_size_of)


def prediction_filtering(args: argparse.Namespace) -> tuple[tuple[Any, Any], int]:
    """Prediction-based filtering without error control (Kanbara04, Clarke08 in seed 000): send
    only when the receiver's prediction misses by TH_HLI, no redundant followers (the HLI codec
    with alpha so large that N_HLI1 = 0)."""
    from haptic_teleop.core.hli_codec import HliConfig, build_hli_codec

    cfg = HliConfig(threshold_m=args.threshold_m, p=args.loss, r=1.0 - args.loss, alpha=0.99, p_allowable=0.99)
    enc, dec = build_hli_codec(cfg, PERIOD_NS, 1)
    return (enc, dec), dec.delay_ticks


def event_codec(args: argparse.Namespace, error_control: str, **kw: Any) -> tuple[tuple[Any, Any], int]:
    """Prediction-based filtering (the same filter as `prediction_filtering`) with `error_control`
    over its events (core/event_codec.py); messages as std_msgs/Float64MultiArray (its default)."""
    from haptic_teleop.core.event_codec import EventCodecConfig, build_event_codec

    cfg = EventCodecConfig(threshold_m=args.threshold_m, error_control=error_control, **kw)
    enc, dec = build_event_codec(cfg, PERIOD_NS, 1)
    return (enc, dec), dec.delay_ticks


def row(r: Result, warmup_s: float = 1.0, present: bool = False) -> list[Any]:
    """One line of the table (HEADER, and PRESENT_HEADER's two with `present`), from the run alone."""
    w = (r.t_s >= warmup_s) & np.isfinite(r.force_n) & np.isfinite(r.true_n)
    e = r.force_n[w] - r.true_n[w]
    dur = r.t_s.size * PERIOD_S
    extra: list[Any] = []
    if present:
        ep = r.force_n[w] - r.present_n[w]
        extra = [rms(ep), float(np.max(np.abs(ep))) if len(ep) else math.nan]
    return [
        r.label,
        r.packets / dur,
        r.ros_bytes * 8 / dur / 1e3,
        r.compact_bytes * 8 / dur / 1e3,
        r.reverse_ros_bytes * 8 / dur / 1e3,
        rms(e),
        float(np.max(np.abs(e))) if len(e) else math.nan,
        r.latency_ticks * PERIOD_S * 1e3,
        *extra,
    ]


HEADER = [
    "scheme",
    "packets/s",
    "wire kbit/s (ROS)",
    "wire kbit/s (compact)",
    "acks kbit/s (ROS)",
    "RMS force error [N]",
    "peak force error [N]",
    "latency [ms]",
]
PRESENT_HEADER = ["RMS force error incl. latency [N]", "peak force error incl. latency [N]"]


def _run_all(
    args: argparse.Namespace, cases: list[tuple[str, Callable[[argparse.Namespace], Any]]], name: str
) -> tuple[list[Result], Path]:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out

    out = Path(args.out) if args.out else default_out(name)
    check_out_dir(out)
    n_ticks = round(args.duration_s / PERIOD_S)
    bar: Any = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=n_ticks * len(cases), unit="tick", unit_scale=True, desc=name, leave=False, file=sys.stderr)
    from haptic_teleop.studies.replications.codec_bags import read_bag, slug, write_bag

    plain = {k: v for k, v in sorted(vars(args).items()) if v is None or isinstance(v, (bool, int, float, str))}
    runs = BagRuns(out / "bags", args.discard_bags)
    results = []
    try:
        for label, make in cases:
            built = make(args)
            if isinstance(built, tuple) and len(built) == 2 and isinstance(built[1], int):
                codec, extra = built
            else:
                codec, extra = built, 0
            ran = simulate(label, codec, args, _delay_ticks(args) + extra, bar.update if bar else None)
            # the table is computed from the bag read back: every figure can be checked from data
            with runs.bag(slug(label), label) as bag:
                write_bag(bag, ran, name, plain, "none" if args.discard_bags else "zstd")
                results.append(read_bag(bag)[0])
    finally:
        if bar is not None:
            bar.close()
    return results, out


def _plot(results: list[Result], path: Path, title: str, window_s: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    t0 = results[0].t_s
    view = (t0 >= 1.0) & (t0 <= 1.0 + window_s)
    a1.plot(t0[view], results[0].true_n[view], color="0.6", lw=3, label="transparent (true object)")
    for r in results:
        a1.plot(r.t_s[view], r.force_n[view], lw=1, label=r.label)
        a2.plot(r.t_s[view], (r.force_n - r.true_n)[view], lw=1, label=r.label)
    a1.set(ylabel="force fed back [N]", title=title)
    a2.set(xlabel="time [s]", ylabel="force error [N]")
    finish_figure(fig, (a1, a2), path, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)


def peak_ranking(rows: list[list[Any]]) -> str:
    """The schemes by peak force error, smallest first (seed 000 compares peaks), RMS beside."""
    ip, ir = HEADER.index("peak force error [N]"), HEADER.index("RMS force error [N]")
    ranked = sorted(rows, key=lambda r: (r[ip], r[ir]))
    return "By peak force error (seed 000's measure), RMS beside: " + "; ".join(
        f"{i}. {r[0]} {r[ip]:.3g} N ({r[ir]:.3g} N RMS)" for i, r in enumerate(ranked, start=1)
    )


def _finish(
    args: argparse.Namespace, results: list[Result], out: Path, name: str, title: str, present: bool = False
) -> int:
    """CSV, markdown and plot; `present`: two more columns, the force error against the object one
    link delay ago (the codec's added latency counted as error)."""
    rows = [row(r, present=present) for r in results]
    header = HEADER + PRESENT_HEADER if present else HEADER
    write_csv(out / f"{name}.csv", header, rows)
    table = markdown(header, rows) + "\n" + peak_ranking(rows) + "\n"
    (out / f"{name}.md").write_text(table)
    _plot(results, out / f"{name}.png", title, args.plot_window_s)
    if not args.quiet:
        sys.stdout.write(table)
        sys.stdout.write(f"\n{out / (name + '.png')}\n{bags_line(out, args.discard_bags)}\n")
    return 0


def add_common_arguments(p: argparse.ArgumentParser, name: str) -> None:
    p.add_argument("--out", help=f"output directory, new or empty (default runs/{name}-NNN)")
    p.add_argument("--duration-s", type=number(2.0, 3600.0), default=20.0, help="simulated time [s] (default 20)")
    p.add_argument("--seed", type=number(0, 2**31, kind=int), default=1, help="the loss draws' seed (default 1)")
    p.add_argument("--loss", type=number(0.0, 0.9), default=0.2, help="stationary loss (default 0.2, the seed's)")
    p.add_argument(
        "--burst-packets",
        type=number(1.0, 1000.0),
        default=2.0,
        help="mean loss burst (Gilbert, r = 1/burst; 1: independent losses) (default 2)",
    )
    p.add_argument("--delay-s", type=number(0.0, 1.0), default=0.005, help="one-way delay [s] (default 0.005)")
    p.add_argument(
        "--stiffness-n-per-m",
        type=number(0.0, 1e5, low_open=True),
        default=100.0,
        help="the object's stiffness k [N/m] (default 100: 10 N at 10 cm)",
    )
    p.add_argument(
        "--object-period-s", type=number(0.1, 100.0), default=2.0, help="the object's back-and-forth period [s]"
    )
    p.add_argument("--threshold-m", type=number(0.0, 1.0, low_open=True), default=0.0004, help="TH_HLI [m] (0.4 mm)")
    p.add_argument(
        "--bandwidth-bps",
        type=number(1.0, 1e10),
        default=70e3,
        help="the allowed bandwidth of priority-based filtering, on the ROS wire [bit/s] (default 70e3)",
    )
    p.add_argument("--filtering", choices=("sequential", "alternate"), default="sequential")
    p.add_argument("--plot-window-s", type=number(0.1, 3600.0), default=2.0, help="seconds shown in the plot")
    p.add_argument("--discard-bags", action="store_true", help="read each scheme's bag for the table, then delete it")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def add_filtering_arguments(p: argparse.ArgumentParser) -> None:
    add_common_arguments(p, "hli-filtering")
    p.add_argument("--fine-m", type=number(0.0, 1.0, low_open=True), default=0.0007, help="fine deadband [m]")
    p.add_argument("--coarse-m", type=number(0.0, 1.0, low_open=True), default=0.0025, help="coarse deadband [m]")


def main_filtering(args: argparse.Namespace) -> int:
    cases: list[tuple[str, Callable[[argparse.Namespace], Any]]] = [
        ("every sample (prediction)", prediction),
        ("prediction-based filtering", prediction_filtering),
        (f"priority-based, {args.bandwidth_bps / 1e3:g} kbit/s", hli),
        (f"deadband {args.fine_m * 1e3:g} mm", lambda a: deadband(a, a.fine_m)),
        (f"deadband {args.coarse_m * 1e3:g} mm", lambda a: deadband(a, a.coarse_m)),
    ]
    results, out = _run_all(args, cases, "hli-filtering")
    title = (
        f"object -0.1..0 m, {args.loss:.0%} loss (bursts of {args.burst_packets:g}), k = {args.stiffness_n_per_m:g} N/m"
    )
    return _finish(args, results, out, "hli_filtering", title)


def add_error_control_arguments(p: argparse.ArgumentParser) -> None:
    add_common_arguments(p, "error-control")
    p.add_argument(
        "--fec-k",
        type=number(1, 64, kind=int),
        default=2,
        help="previous events each FEC packet copies (default 2: a burst of two lost events)",
    )
    p.add_argument(
        "--fec-wait-s",
        type=number(0.0, 1.0),
        default=0.05,
        help="also run FEC with the receiver playing this much later, so copies of lost events can come "
        "in time (default 0.05; 0: no such row)",
    )


def _arq_case(arq: Any) -> Callable[[argparse.Namespace], Any]:
    return lambda a: event_codec(a, "arq", timeout_s=arq.timeout_s, max_retransmissions=arq.max_retransmissions)


def main_error_control(args: argparse.Namespace) -> int:
    from haptic_teleop.core.arq import SEED_000_EXPERIMENT

    k = args.fec_k
    cases: list[tuple[str, Callable[[argparse.Namespace], Any]]] = [
        ("prediction-based filtering only", lambda a: event_codec(a, "none")),
        (f"+ FEC (k = {k})", lambda a: event_codec(a, "fec", fec_k=k)),
    ]
    wait = round(args.fec_wait_s / PERIOD_S)
    if wait > 0:
        cases.append(
            (f"+ FEC (k = {k}), playing {wait} ms later", lambda a: event_codec(a, "fec", fec_k=k, wait_ticks=wait))
        )
    for arq in SEED_000_EXPERIMENT:
        cases.append((f"+ ARQ (mu = {arq.timeout_s * 1e3:g} ms, nu = {arq.max_retransmissions})", _arq_case(arq)))
    cases.append((f"priority-based, {args.bandwidth_bps / 1e3:g} kbit/s", hli))
    results, out = _run_all(args, cases, "error-control")
    title = (
        f"error control: object -0.1..0 m, {args.loss:.0%} loss (bursts of {args.burst_packets:g}), "
        f"k = {args.stiffness_n_per_m:g} N/m"
    )
    return _finish(args, results, out, "error_control", title, present=True)
