"""Seed 000's two NVE experiments as commands (docs/nve_experiments.md).

`haptic-teleop experiment nve-analysis`: the verification of the transparency analysis. The user
pushes the object of the bundled scene nve_push (compensation none) at constant velocity; the
force fed back is compared between
  (1) round trip R (R/2 each way) with the original coefficients (m, b, k_h),
  (2) no delay with the distorted mass and damping (m_h, b_h at R),
  (3) no delay with the distorted spring the rule picks (k_hm if m w >= b, else k_hb),
and, for reference, (0) no delay with the original coefficients and (3') the other spring
distortion. The table gives the RMS, peak and mean error of each against (1) over the push.

`haptic-teleop experiment nve-compensation`: the same push with round trip R under
  (1) no delay, (2) no compensation, (3) and (4) Fujimoto04 with two settings of alpha,
  (5) seed 000's transparency scheme (nve_push's settings);
the table gives each one's error against (1). A sweep over Fujimoto04's alpha (the setting its
user finds by trial and error) goes in the plot beside the forces; `--rtt-sweep` adds each
scheme's error against R (a second plot).

Every run is the NVE engine (engine/nve_loop.py) recorded to a bag, and what the tables use is read
back from the bags (`Runner`); deterministic: the same arguments give the same numbers.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.args import number
from haptic_teleop.studies.replications.recorded import BagRuns, bags_line, compression
from haptic_teleop.studies.replications.tables import markdown, rms, write_csv

BASE_SCENE = "nve_push"


CLIENT = 0  # the experiments push with the scene's first client


ANALYSIS_HELP = (
    "seed 000's verification of the NVE transparency analysis: the force with round trip R against no delay "
    "with the distorted mass and damping, and with the distorted spring; plot, CSV and table"
)


@dataclass(frozen=True)
class Trace:
    """What an experiment uses of one run: time, the HIP's velocity, the force fed back, the spring
    the client used and the round trip it measured, per tick."""

    t_s: np.ndarray
    hip_v_m_per_s: np.ndarray
    force_n: np.ndarray
    spring_n_per_m: np.ndarray
    rtt_s: np.ndarray


@dataclass(frozen=True)
class Case:
    """One run of an experiment: its label in plot and table, what it changes in the base scene."""

    key: str
    label: str
    overrides: tuple[str, ...]
    settings: str = ""


@dataclass
class Runner:
    """Runs the cases of one command against its base scene, with one progress bar over all ticks.

    Each run is recorded to a bag, `bags/NNN_<case>` (NNN: the run's place in the command), and its
    trace is read back from that bag, so every figure can be checked from data; `bags/index.csv`
    names each bag's case and overrides. `discard`: each bag is deleted once read; `bags` None: a
    temporary directory."""

    base: tuple[str, ...]
    ticks_per_run: int
    runs: int
    quiet: bool
    desc: str
    bags: Path | None = None
    discard: bool = False
    bar: Any = field(default=None, init=False)
    recorded: BagRuns = field(init=False)

    def __post_init__(self) -> None:
        self.recorded = BagRuns(self.bags, self.discard)

    def __enter__(self) -> Runner:
        if not self.quiet:
            from tqdm import tqdm

            self.bar = tqdm(
                total=self.runs * self.ticks_per_run,
                unit="tick",
                unit_scale=True,
                desc=self.desc,
                leave=False,
                file=sys.stderr,
                mininterval=0.2,
            )
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.close()

    def scene(self, overrides: Sequence[str]) -> Any:
        from haptic_teleop.scene.load import find_scene, load_scene

        return load_scene(find_scene(BASE_SCENE), overrides=[*self.base, *overrides])

    def run(self, case: Case) -> Trace:
        from haptic_teleop.engine.nve_loop import record_nve_run
        from haptic_teleop.record.reader import BagReader

        last = [0]

        def progress(n: int) -> None:
            if self.bar is not None:
                self.bar.update(n - last[0])
            last[0] = n

        with self.recorded.bag(case.key, case.label, case.settings, case.overrides) as bag:
            engine, _ = record_nve_run(
                self.scene(case.overrides), bag, progress=progress, parallel=False, handle_sigint=False
            )
            if self.bar is not None:
                self.bar.update(engine.ticks - last[0])
            with BagReader(bag) as reader:
                rows = reader.read_nve()
        name = engine.schema.clients[CLIENT]
        return Trace(
            np.arange(len(rows.values)) * engine.period_s,
            rows.field(f"{name}.hip_v_m_per_s"),
            rows.field(f"{name}.force_n"),
            rows.field(f"{name}.spring_n_per_m"),
            rows.field(f"{name}.rtt_s"),
        )


def _client(key: str) -> str:
    return f"nve.clients.{CLIENT}.{key}"


def delay_overrides(rtt_s: float) -> tuple[str, ...]:
    """Round trip `rtt_s`, half each way (0: no delay effect at all)."""
    effects = "{}" if rtt_s == 0.0 else f"{{delay: {{delay_s: {rtt_s / 2.0!r}}}}}"
    return (_client(f"up.effects={effects}"), _client(f"down.effects={effects}"))


NO_COMPENSATION = (_client("compensation={scheme: none}"),)


def fujimoto_overrides(alpha: float, initial: float | None, threshold_s: float) -> tuple[str, ...]:
    k0 = "" if initial is None else f", initial_spring_n_per_m: {initial!r}"
    return (
        _client(
            "compensation={scheme: fujimoto04, "
            f"reduction_n_per_m_per_s: {alpha!r}, threshold_rtt_s: {threshold_s!r}{k0}}}"
        ),
    )


def push_overrides(args: argparse.Namespace, out: Path, start_s: float, distance_m: float) -> tuple[str, ...]:
    """The HIP's push: the scene's constant-velocity push at --speed-m-per-s from rest (a velocity
    step), or with --ramp-s > 0 the same push (from `start_s`, over `distance_m`) whose velocity
    rises from 0 and falls back to 0 along raised cosines over the ramp (a trace written to
    OUT/hip_trace.csv)."""
    base = (f"scene.duration_s={args.duration_s!r}", _client(f"operator.speed_m_per_s={args.speed_m_per_s!r}"))
    if args.ramp_s == 0.0:
        return base
    path = out / "hip_trace.csv"
    write_ramp_trace(path, args.duration_s, start_s, args.speed_m_per_s, distance_m, args.ramp_s)
    return (base[0], _client(f"operator={{profile: trace, trace_file: {str(path.resolve())!r}}}"))


def ramp_displacement_m(t_s: np.ndarray, start_s: float, speed: float, distance_m: float, ramp_s: float) -> np.ndarray:
    """The push with raised-cosine velocity ramps, like a hand's: from `start_s` the velocity rises as
    speed (1 - cos(pi u / ramp)) / 2 over the ramp, stays `speed`, and falls as
    speed (1 + cos(pi u / ramp)) / 2 over the last ramp, so that `distance_m` is covered (needs
    speed * ramp < distance_m); then held."""
    tau = np.clip(t_s - start_s, 0.0, None)
    ramp_m = 0.5 * speed * ramp_s  # covered by each ramp
    steady_s = (distance_m - 2.0 * ramp_m) / speed
    w = math.pi / ramp_s
    up = 0.5 * speed * (tau - np.sin(w * np.minimum(tau, ramp_s)) / w)
    steady = ramp_m + speed * (tau - ramp_s)
    u = np.clip(tau - ramp_s - steady_s, 0.0, ramp_s)
    down = ramp_m + speed * steady_s + 0.5 * speed * (u + np.sin(w * u) / w)
    x = np.where(tau < ramp_s, up, np.where(tau < ramp_s + steady_s, steady, down))
    out: np.ndarray = np.minimum(x, distance_m)
    return out


def write_ramp_trace(
    path: Path, duration_s: float, start_s: float, speed: float, distance_m: float, ramp_s: float
) -> None:
    t = np.arange(0.0, duration_s + 0.0005, 0.001)
    x = ramp_displacement_m(t, start_s, speed, distance_m, ramp_s)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "position_m"])
        w.writerows((f"{a:.6f}", f"{b:.9g}") for a, b in zip(t, x, strict=True))


def push_window(ref: Trace) -> np.ndarray:
    """The ticks of the push: where the HIP moves."""
    out: np.ndarray = ref.hip_v_m_per_s > 0.0
    return out


def errors(force: np.ndarray, ref: np.ndarray, window: np.ndarray) -> dict[str, float]:
    """RMS, peak (largest absolute) and mean (signed) error of `force` against `ref` over `window`,
    and the RMS relative to `ref`'s RMS there."""
    e = (force - ref)[window]
    ref_rms = rms(ref[window])
    r = rms(e)
    return {
        "rms_error_n": r,
        "peak_error_n": float(np.max(np.abs(e))) if len(e) else math.nan,
        "mean_error_n": float(np.mean(e)) if len(e) else math.nan,
        "relative_rms_error": r / ref_rms if ref_rms > 0.0 else math.nan,
    }


def command_line(args: argparse.Namespace, name: str, flags: Sequence[str]) -> str:
    parts = [f"haptic-teleop experiment {name}"]
    for f in flags:
        v = getattr(args, f.lstrip("-").replace("-", "_"))
        if isinstance(v, bool):
            if v:
                parts.append(f)
        elif v is not None:
            parts.append(f"{f} {v:g}" if isinstance(v, float) else f"{f} {v}")
    parts += [f"--set {s}" for s in args.set or ()]
    return " ".join(parts)


_COLOURS = ("0.55", "black", "tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange")


# Legends beside the axes, never over a curve.
LEGEND: dict[str, Any] = {"fontsize": 9, "loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0}


def nve_figure(rows: int, height: float) -> Any:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13.5, height), layout="constrained")
    return fig, fig.subplots(rows, 1, squeeze=False)[:, 0]


def force_axes(ax: Any, t: np.ndarray, series: Sequence[tuple[str, np.ndarray, str, str]], title: str) -> None:
    for label, y, colour, style in series:
        ax.plot(t, y, style, color=colour, lw=1.4 if style == "-" else 1.8, label=label)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("force fed back F [N]")
    ax.set_title(title, fontsize=11)
    ax.grid(True, alpha=0.3)
    ax.legend(**LEGEND)


def shade_push(ax: Any, t: np.ndarray, window: np.ndarray) -> None:
    if window.any():
        ax.axvspan(t[window][0], t[window][-1], color="0.93", zorder=0, label="push (error window)")


def analysis_cases(scene: Any, rtt_s: float, interaction_rad_per_s: float | None) -> tuple[list[Case], dict[str, Any]]:
    """The runs of the analysis experiment and the distorted coefficients they use."""
    from haptic_teleop.core.nve_transparency import (
        DISTORTIONS,
        NveModel,
        distorted_damping_n_s_per_m,
        distorted_mass_kg,
        dominant_distortion,
        spring_distortion_n_per_m,
    )

    nve = scene.config.nve
    c = nve.clients[CLIENT]
    k = c.coupling
    model = NveModel(
        nve.object.mass_kg,
        nve.object.damping_n_s_per_m,
        k.client_stiffness_n_per_m,
        k.server_stiffness_n_per_m,
        k.client_damping_n_s_per_m,
        k.server_damping_n_s_per_m,
    )
    w = interaction_rad_per_s if interaction_rad_per_s is not None else c.compensation.interaction_rad_per_s
    mh = distorted_mass_kg(model, rtt_s)
    bh = distorted_damping_n_s_per_m(model, rtt_s)
    picked = dominant_distortion(model, w)
    other = next(d for d in DISTORTIONS if d != picked)
    springs = {}
    for d in DISTORTIONS:
        try:
            springs[d] = spring_distortion_n_per_m(model, rtt_s, d)
        except ValueError:  # damping-based with b = 0
            springs[d] = math.nan
    short = {"mass": "k_hm", "damping": "k_hb"}
    none0 = (*NO_COMPENSATION, *delay_overrides(0.0))
    cases = [
        Case(
            "no_delay", "(0) no delay, original m, b, k_h", none0, f"m={model.mass_kg:g}, b={model.damping_n_s_per_m:g}"
        ),
        Case(
            "delay",
            f"(1) round trip {rtt_s * 1e3:g} ms, original m, b, k_h",
            (*NO_COMPENSATION, *delay_overrides(rtt_s)),
            f"k_h={model.client_stiffness_n_per_m:g}",
        ),
        Case(
            "distorted_mass_damping",
            f"(2) no delay, m_h = {mh:.4g} kg, b_h = {bh:.4g} N s/m",
            (*none0, f"nve.object.mass_kg={mh!r}", f"nve.object.damping_n_s_per_m={bh!r}"),
            f"m_h={mh:.6g}, b_h={bh:.6g}",
        ),
        Case(
            "distorted_spring",
            f"(3) no delay, {short[picked]} = {springs[picked]:.4g} N/m ({picked}-based, the rule's)",
            (*none0, _client(f"coupling.client_stiffness_n_per_m={springs[picked]!r}")),
            f"{short[picked]}={springs[picked]:.6g}",
        ),
    ]
    if math.isfinite(springs[other]):
        cases.append(
            Case(
                "other_spring",
                f"(3') no delay, {short[other]} = {springs[other]:.4g} N/m ({other}-based, not the rule's)",
                (*none0, _client(f"coupling.client_stiffness_n_per_m={springs[other]!r}")),
                f"{short[other]}={springs[other]:.6g}",
            )
        )
    facts = {
        "mass_kg": model.mass_kg,
        "damping_n_s_per_m": model.damping_n_s_per_m,
        "client_stiffness_n_per_m": model.client_stiffness_n_per_m,
        "server_stiffness_n_per_m": model.server_stiffness_n_per_m,
        "distorted_mass_kg": mh,
        "distorted_damping_n_s_per_m": bh,
        "interaction_rad_per_s": w,
        "rule_picks": picked,
        "mass_based_spring_n_per_m": springs["mass"],
        "damping_based_spring_n_per_m": springs["damping"],
    }
    return cases, facts


ANALYSIS_FLAGS = ("--rtt-s", "--speed-m-per-s", "--duration-s", "--ramp-s", "--interaction-rad-per-s")


def add_common_arguments(p: argparse.ArgumentParser, name: str) -> None:
    p.add_argument("--out", help=f"output directory, new or empty (default runs/{name}-NNN)")
    p.add_argument(
        "--rtt-s",
        type=number(0.0, 10.0, low_open=True),
        default=0.3,
        help="round trip R [s], half each way (default 0.3)",
    )
    p.add_argument(
        "--speed-m-per-s",
        type=number(0.0, 5.0, low_open=True),
        default=0.1,
        help="the HIP's push speed [m/s] (default 0.1, nve_push's)",
    )
    p.add_argument(
        "--duration-s",
        type=number(1.0, 600.0),
        default=10.0,
        help="simulated time of each run [s] (default 10; the push starts at 0.5 s and covers 0.9 m)",
    )
    p.add_argument(
        "--ramp-s",
        type=number(0.0, 60.0),
        default=0.0,
        help="0 (default): the push starts and ends as a velocity step (nve_push's profile); > 0: its velocity "
        "rises from 0 and falls back to 0 over this many seconds (raised cosines), like a hand's",
    )
    p.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override a key of the base scene nve_push")
    p.add_argument("--discard-bags", action="store_true", help="read each run's bag for the tables, then delete it")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bar, no table)")


def add_analysis_arguments(p: argparse.ArgumentParser) -> None:
    add_common_arguments(p, "nve-analysis")
    p.add_argument(
        "--interaction-rad-per-s",
        type=number(0.0, 1e3, low_open=True),
        help="w of the rule that picks the spring distortion (mass-based iff m w >= b; default: the scene's, 1)",
    )


def prepare_runs(
    args: argparse.Namespace, name: str, validate: Callable[[Any], object] | None = None
) -> tuple[Path, Runner]:
    """Validate the base scene with the arguments (exit 2 before anything is written), make the
    output directory; return it and a runner of the runs on the base scene with the push."""
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.errors import InputError

    # the runs' bags zstd-compressed when kept (recorded.compression); a --set may say otherwise
    probe = Runner((compression(args.discard_bags), *(args.set or ())), 0, 0, True, name)
    scene = probe.scene(
        (f"scene.duration_s={args.duration_s!r}", _client(f"operator.speed_m_per_s={args.speed_m_per_s!r}"))
    )
    if scene.config.nve.axes != 1:
        raise InputError("--set: nve.axes: the NVE experiments push along one axis; allowed: 1")
    op = scene.config.nve.clients[CLIENT].operator
    if op.profile != "push":
        raise InputError(
            f"--set: nve.clients.{CLIENT}.operator.profile = {op.profile!r}: the experiments push; allowed: push"
        )
    if args.ramp_s > 0.0 and args.speed_m_per_s * args.ramp_s >= op.distance_m:
        raise InputError(
            f"--ramp-s {args.ramp_s:g}: the two ramps cover the whole {op.distance_m:g} m push at --speed-m-per-s "
            f"{args.speed_m_per_s:g}; allowed: ramp_s * speed < the push's distance"
        )
    if validate is not None:
        validate(scene)
    out = Path(args.out) if args.out else default_out(name)
    check_out_dir(out)
    base = (*probe.base, *push_overrides(args, out, op.start_s, op.distance_m))
    ticks = int(round(args.duration_s / scene.config.scene.period_s))
    return out, Runner(base, ticks, 0, args.quiet, name, out / "bags", args.discard_bags)


def main_analysis(args: argparse.Namespace) -> int:
    out, runner = prepare_runs(args, "nve-analysis")
    cases, facts = analysis_cases(runner.scene(()), args.rtt_s, args.interaction_rad_per_s)
    runner.runs = len(cases)
    with runner:
        traces = {c.key: runner.run(c) for c in cases}
    ref = traces["delay"]
    window = push_window(ref)
    header = [
        "run",
        "settings",
        "rms_error_n",
        "peak_error_n",
        "mean_error_n",
        "relative_rms_error",
        "rms_force_n",
    ]
    rows = []
    for c in cases:
        if c.key == "delay":
            continue
        e = errors(traces[c.key].force_n, ref.force_n, window)
        rows.append(
            [
                c.label,
                c.settings,
                e["rms_error_n"],
                e["peak_error_n"],
                e["mean_error_n"],
                e["relative_rms_error"],
                rms(traces[c.key].force_n[window]),
            ]
        )
    ref_rms = rms(ref.force_n[window])
    write_csv(out / "nve_analysis.csv", header, rows)
    cmd = command_line(args, "nve-analysis", ("--out", *ANALYSIS_FLAGS))
    text = (
        f"`{cmd}`\n\nErrors against (1) over the push ({window.sum() * (ref.t_s[1] - ref.t_s[0]):.4g} s; "
        f"(1)'s RMS force {ref_rms:.4g} N). m = {facts['mass_kg']:g} kg, b = {facts['damping_n_s_per_m']:g} N s/m, "
        f"k_h = {facts['client_stiffness_n_per_m']:g} N/m, k_e = {facts['server_stiffness_n_per_m']:g} N/m, "
        f"R = {args.rtt_s:g} s; the rule (w = {facts['interaction_rad_per_s']:g} rad/s) picks the "
        f"{facts['rule_picks']}-based spring distortion.\n\n" + markdown(header, rows)
    )
    (out / "nve_analysis.md").write_text(text)
    plot_analysis(out / "nve_analysis.png", cases, traces, window, args)
    if not args.quiet:
        print(text)
        print(f"csv:   {out / 'nve_analysis.csv'}\ntable: {out / 'nve_analysis.md'}\nplot:  {out / 'nve_analysis.png'}")
        print(bags_line(out, args.discard_bags))
    return 0


_ERROR_LABELS = {
    "no_delay": "(0) no delay, original − (1)",
    "distorted_mass_damping": "(2) no delay, distorted m_h, b_h − (1)",
    "distorted_spring": "(3) no delay, distorted spring − (1)",
}


def plot_analysis(
    path: Path, cases: Sequence[Case], traces: dict[str, Trace], window: np.ndarray, args: argparse.Namespace
) -> None:
    fig, (top, bottom) = nve_figure(2, 8.0)
    ref = traces["delay"]
    t = ref.t_s
    styles = {
        "no_delay": ("0.6", "-"),
        "delay": ("black", "-"),
        "distorted_mass_damping": ("tab:blue", "--"),
        "distorted_spring": ("tab:red", ":"),
    }
    shade_push(top, t, window)
    force_axes(
        top,
        t,
        [(c.label, traces[c.key].force_n, *styles[c.key]) for c in cases if c.key in styles],
        f"Verification of the transparency analysis: push at {args.speed_m_per_s:g} m/s"
        + (f" (raised-cosine velocity ramps of {args.ramp_s:g} s)" if args.ramp_s else " (velocity step)"),
    )
    shade_push(bottom, t, window)
    for c in cases:
        if c.key in ("distorted_mass_damping", "distorted_spring", "no_delay"):
            colour, style = styles[c.key]
            bottom.plot(t, traces[c.key].force_n - ref.force_n, style, color=colour, lw=1.6, label=_ERROR_LABELS[c.key])
    bottom.axhline(0.0, color="black", lw=0.8)
    bottom.set_xlabel("time t [s]")
    bottom.set_ylabel("force error against (1) [N]")
    bottom.set_title("Error against (1): the delayed run with the original coefficients", fontsize=11)
    bottom.grid(True, alpha=0.3)
    bottom.legend(**LEGEND)
    fig.savefig(path, dpi=100)
