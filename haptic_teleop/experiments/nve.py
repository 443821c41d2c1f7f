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

Every run is the NVE engine in memory (engine/nve_loop.py), deterministic: the same arguments
give the same numbers.
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

from haptic_teleop.experiments.args import number
from haptic_teleop.experiments.tables import markdown, rms, write_csv

BASE_SCENE = "nve_push"
CLIENT = 0  # the experiments push with the scene's first client

ANALYSIS_HELP = (
    "seed 000's verification of the NVE transparency analysis: the force with round trip R against no delay "
    "with the distorted mass and damping, and with the distorted spring; plot, CSV and table"
)
COMPENSATION_HELP = (
    "seed 000's delay compensation experiment: push at constant velocity over round trip R with no "
    "compensation, Fujimoto04 (two settings) and the proposed scheme, each against no delay; plot, CSV, table"
)

# --- runs ------------------------------------------------------------------------------------------


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
    """Runs the cases of one command against its base scene, with one progress bar over all ticks."""

    base: tuple[str, ...]
    ticks_per_run: int
    runs: int
    quiet: bool
    desc: str
    bar: Any = field(default=None, init=False)

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
        from haptic_teleop.engine.nve_loop import NveEngine

        engine = NveEngine(self.scene(case.overrides))
        last = [0]

        def progress(n: int) -> None:
            if self.bar is not None:
                self.bar.update(n - last[0])
            last[0] = n

        engine.run(progress=progress, handle_sigint=False)
        if self.bar is not None:
            self.bar.update(engine.ticks - last[0])
        data = engine.data
        assert data is not None
        name = engine.schema.clients[CLIENT]

        def col(group: str) -> np.ndarray:
            out: np.ndarray = data[:, engine.schema.index(f"{name}.{group}")].copy()
            return out

        return Trace(
            np.arange(len(data)) * engine.period_s,
            col("hip_v_m_per_s"),
            col("force_n"),
            col("spring_n_per_m"),
            col("rtt_s"),
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


# --- errors and tables -----------------------------------------------------------------------------


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


# --- plots -----------------------------------------------------------------------------------------

_COLOURS = ("0.55", "black", "tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange")


# Legends beside the axes, never over a curve.
_LEGEND: dict[str, Any] = {"fontsize": 9, "loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0}


def _figure(rows: int, height: float) -> Any:
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
    ax.legend(**_LEGEND)


def shade_push(ax: Any, t: np.ndarray, window: np.ndarray) -> None:
    if window.any():
        ax.axvspan(t[window][0], t[window][-1], color="0.93", zorder=0, label="push (error window)")


# --- nve-analysis ----------------------------------------------------------------------------------


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
    p.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bar, no table)")


def add_analysis_arguments(p: argparse.ArgumentParser) -> None:
    add_common_arguments(p, "nve-analysis")
    p.add_argument(
        "--interaction-rad-per-s",
        type=number(0.0, 1e3, low_open=True),
        help="w of the rule that picks the spring distortion (mass-based iff m w >= b; default: the scene's, 1)",
    )


def _prepare(
    args: argparse.Namespace, name: str, validate: Callable[[Any], object] | None = None
) -> tuple[Path, Runner]:
    """Validate the base scene with the arguments (exit 2 before anything is written), make the
    output directory; return it and a runner of the runs on the base scene with the push."""
    from haptic_teleop.analysis.outputs import check_out_dir, default_out
    from haptic_teleop.errors import InputError

    probe = Runner(tuple(args.set or ()), 0, 0, True, name)
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
    return out, Runner(base, ticks, 0, args.quiet, name)


def main_analysis(args: argparse.Namespace) -> int:
    out, runner = _prepare(args, "nve-analysis")
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
    return 0


_ERROR_LABELS = {
    "no_delay": "(0) no delay, original − (1)",
    "distorted_mass_damping": "(2) no delay, distorted m_h, b_h − (1)",
    "distorted_spring": "(3) no delay, distorted spring − (1)",
}


def plot_analysis(
    path: Path, cases: Sequence[Case], traces: dict[str, Trace], window: np.ndarray, args: argparse.Namespace
) -> None:
    fig, (top, bottom) = _figure(2, 8.0)
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
    bottom.legend(**_LEGEND)
    fig.savefig(path, dpi=100)


# --- nve-compensation ------------------------------------------------------------------------------

COMPENSATION_FLAGS = (
    "--rtt-s",
    "--speed-m-per-s",
    "--duration-s",
    "--ramp-s",
    "--alpha-low",
    "--alpha-high",
    "--initial-spring-n-per-m",
    "--threshold-rtt-s",
    "--alpha-sweep-points",
    "--rtt-sweep",
)
RTT_SWEEP_S = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5)


def add_compensation_arguments(p: argparse.ArgumentParser) -> None:
    add_common_arguments(p, "nve-compensation")
    p.add_argument(
        "--alpha-low",
        type=number(0.0, 1e6),
        default=0.25,
        help="(3) Fujimoto04's alpha [N/m per s of round trip] (default 0.25: takes 0.075 N/m off k_h = 0.5 "
        "at 300 ms, under-corrects)",
    )
    p.add_argument(
        "--alpha-high",
        type=number(0.0, 1e6),
        default=1.5,
        help="(4) Fujimoto04's alpha (default 1.5: takes 0.45 N/m off k_h = 0.5 at 300 ms, over-corrects)",
    )
    p.add_argument(
        "--initial-spring-n-per-m",
        type=number(0.0, 1e6),
        help="Fujimoto04's K0 [N/m] (default: the scene's k_h, 0.5)",
    )
    p.add_argument(
        "--threshold-rtt-s",
        type=number(0.0, 100.0),
        default=0.0,
        help="Fujimoto04's R0 [s]: the round trip below which K stays K0 (default 0)",
    )
    p.add_argument(
        "--alpha-sweep-points",
        type=number(0, 200, kind=int),
        default=12,
        help="Fujimoto04 runs at alphas from 0 to where K reaches 0, for the plot's second panel (0: none; default 12)",
    )
    p.add_argument(
        "--rtt-sweep",
        action="store_true",
        help=f"also run every scheme at R = {', '.join(f'{r:g}' for r in RTT_SWEEP_S)} s: "
        "nve_compensation_rtt.png and .csv",
    )


def compensation_cases(args: argparse.Namespace, rtt_s: float, k0: float) -> list[Case]:
    k0_text = f"K0={k0:g}, R0={args.threshold_rtt_s:g} s"
    return [
        Case("no_compensation", "(2) no compensation", (*NO_COMPENSATION, *delay_overrides(rtt_s)), "k_h fixed"),
        Case(
            "fujimoto_low",
            f"(3) Fujimoto04, alpha = {args.alpha_low:g} N/m/s",
            (
                *fujimoto_overrides(args.alpha_low, args.initial_spring_n_per_m, args.threshold_rtt_s),
                *delay_overrides(rtt_s),
            ),
            f"alpha={args.alpha_low:g}, {k0_text}",
        ),
        Case(
            "fujimoto_high",
            f"(4) Fujimoto04, alpha = {args.alpha_high:g} N/m/s",
            (
                *fujimoto_overrides(args.alpha_high, args.initial_spring_n_per_m, args.threshold_rtt_s),
                *delay_overrides(rtt_s),
            ),
            f"alpha={args.alpha_high:g}, {k0_text}",
        ),
        Case("proposed", "(5) proposed (transparency)", delay_overrides(rtt_s), "nve_push's compensation"),
    ]


def _transparency_settings(scene: Any) -> str:
    comp = scene.config.nve.clients[CLIENT].compensation
    if comp.scheme != "transparency":
        from haptic_teleop.errors import InputError

        raise InputError(
            f"--set: nve.clients.{CLIENT}.compensation.scheme = {comp.scheme!r}: the proposed scheme (5) is the "
            "base scene's compensation; allowed: transparency"
        )
    keys = ("rule", "interaction_rad_per_s", "allowable_mass_kg", "allowable_damping_n_s_per_m", "min_spring_n_per_m")
    return ", ".join(f"{k}={getattr(comp, k)}" for k in keys if getattr(comp, k) is not None)


def main_compensation(args: argparse.Namespace) -> int:
    out, runner = _prepare(args, "nve-compensation", _transparency_settings)
    scene = runner.scene(())
    settings = _transparency_settings(scene)
    k0 = (
        args.initial_spring_n_per_m
        if args.initial_spring_n_per_m is not None
        else scene.config.nve.clients[CLIENT].coupling.client_stiffness_n_per_m
    )
    cases = compensation_cases(args, args.rtt_s, k0)
    cases[-1] = Case(cases[-1].key, cases[-1].label, cases[-1].overrides, settings)
    # Fujimoto04's alpha from 0 to where K reaches its floor (0) at the round trip the client measures
    # (R + one period: the loop's own tick).
    period_s = scene.config.scene.period_s
    excess = args.rtt_s + period_s - args.threshold_rtt_s
    alpha_top = k0 / excess if excess > 0.0 else 0.0
    alphas = (
        list(np.linspace(0.0, alpha_top * 1.1, args.alpha_sweep_points))
        if args.alpha_sweep_points and alpha_top > 0
        else []
    )
    sweep_rtts = RTT_SWEEP_S if args.rtt_sweep else ()
    runner.runs = 1 + len(cases) + len(alphas) + len(sweep_rtts) * len(cases)
    ref_case = Case("no_delay", "(1) no delay", (*NO_COMPENSATION, *delay_overrides(0.0)), "no delay")
    with runner:
        ref = runner.run(ref_case)
        traces = {c.key: runner.run(c) for c in cases}
        window = push_window(ref)
        alpha_err = []
        for a in alphas:
            tr = runner.run(
                Case(
                    "sweep",
                    "",
                    (
                        *fujimoto_overrides(float(a), args.initial_spring_n_per_m, args.threshold_rtt_s),
                        *delay_overrides(args.rtt_s),
                    ),
                )
            )
            alpha_err.append(errors(tr.force_n, ref.force_n, window)["rms_error_n"])
        rtt_err: dict[str, list[float]] = {c.key: [] for c in cases}
        for r in sweep_rtts:
            for c in compensation_cases(args, r, k0):
                rtt_err[c.key].append(errors(runner.run(c).force_n, ref.force_n, window)["rms_error_n"])
    header = [
        "run",
        "settings",
        "spring_at_end_n_per_m",
        "rms_error_n",
        "peak_error_n",
        "mean_error_n",
        "relative_rms_error",
        "closest",
    ]
    errs = {c.key: errors(traces[c.key].force_n, ref.force_n, window) for c in cases}
    best = min(errs, key=lambda k: errs[k]["rms_error_n"])
    rows = [
        [
            c.label,
            c.settings,
            float(traces[c.key].spring_n_per_m[-1]),
            errs[c.key]["rms_error_n"],
            errs[c.key]["peak_error_n"],
            errs[c.key]["mean_error_n"],
            errs[c.key]["relative_rms_error"],
            "yes" if c.key == best else "",
        ]
        for c in cases
    ]
    write_csv(out / "nve_compensation.csv", header, rows)
    if alphas:
        write_csv(
            out / "nve_compensation_alpha.csv",
            ["alpha_n_per_m_per_s", "spring_n_per_m", "rms_error_n"],
            [[float(a), max(0.0, k0 - float(a) * max(0.0, excess)), e] for a, e in zip(alphas, alpha_err, strict=True)],
        )
    ref_rms = rms(ref.force_n[window])
    measured = float(traces["no_compensation"].rtt_s[-1])
    cmd = command_line(args, "nve-compensation", ("--out", *COMPENSATION_FLAGS))
    text = (
        f"`{cmd}`\n\nErrors against (1) no delay over the push ((1)'s RMS force {ref_rms:.4g} N); round trip "
        f"R = {args.rtt_s:g} s (measured by the client: {measured:.4g} s). Closest to (1): "
        f"{next(c.label for c in cases if c.key == best)}.\n\n" + markdown(header, rows)
    )
    if alphas:
        i = int(np.argmin(alpha_err))
        text += (
            f"\nFujimoto04 swept over alpha (0 to {alphas[-1]:.3g} N/m/s, {len(alphas)} runs): smallest RMS error "
            f"{alpha_err[i]:.4g} N at alpha = {alphas[i]:.3g} N/m/s (K = {max(0.0, k0 - alphas[i] * excess):.3g} N/m); "
            f"the proposed scheme's {errs['proposed']['rms_error_n']:.4g} N.\n"
        )
    (out / "nve_compensation.md").write_text(text)
    plot_compensation(
        out / "nve_compensation.png", ref, cases, traces, window, alphas, alpha_err, errs, args, k0, excess
    )
    files = [
        f"csv:   {out / 'nve_compensation.csv'}",
        f"table: {out / 'nve_compensation.md'}",
        f"plot:  {out / 'nve_compensation.png'}",
    ]
    if alphas:
        files.insert(1, f"csv:   {out / 'nve_compensation_alpha.csv'}")
    if sweep_rtts:
        rtt_rows = [[r, *(rtt_err[c.key][i] for c in cases)] for i, r in enumerate(sweep_rtts)]
        rtt_header = ["rtt_s", *(f"{c.key}_rms_error_n" for c in cases)]
        write_csv(out / "nve_compensation_rtt.csv", rtt_header, rtt_rows)
        plot_rtt(out / "nve_compensation_rtt.png", sweep_rtts, cases, rtt_err, args)
        rtt_text = "\nRMS error against (1) over round trip R:\n\n" + markdown(rtt_header, rtt_rows)
        text += rtt_text
        (out / "nve_compensation.md").write_text(text)
        files += [f"csv:   {out / 'nve_compensation_rtt.csv'}", f"plot:  {out / 'nve_compensation_rtt.png'}"]
    if not args.quiet:
        print(text)
        print("\n".join(files))
    return 0


_SCHEME_STYLE = {
    "no_compensation": ("black", "-"),
    "fujimoto_low": ("tab:orange", "--"),
    "fujimoto_high": ("tab:purple", "-."),
    "proposed": ("tab:red", "-"),
}


def plot_compensation(
    path: Path,
    ref: Trace,
    cases: Sequence[Case],
    traces: dict[str, Trace],
    window: np.ndarray,
    alphas: Sequence[float],
    alpha_err: Sequence[float],
    errs: dict[str, dict[str, float]],
    args: argparse.Namespace,
    k0: float,
    excess: float,
) -> None:
    fig, axes = _figure(2 if alphas else 1, 9.0 if alphas else 5.0)
    top = axes[0]
    t = ref.t_s
    shade_push(top, t, window)
    series = [("(1) no delay", ref.force_n, "tab:green", "-")]
    series += [(c.label, traces[c.key].force_n, *_SCHEME_STYLE[c.key]) for c in cases]
    force_axes(top, t, series, f"Pushing at {args.speed_m_per_s:g} m/s with a {args.rtt_s * 1e3:g} ms round trip")
    if alphas:
        ax = axes[1]
        ax.plot(alphas, alpha_err, "o-", color="tab:blue", label="Fujimoto04 at alpha (sweep)")
        for c in cases:
            colour, style = _SCHEME_STYLE[c.key]
            if c.key in ("fujimoto_low", "fujimoto_high"):
                a = args.alpha_low if c.key == "fujimoto_low" else args.alpha_high
                ax.plot([a], [errs[c.key]["rms_error_n"]], "s", ms=9, color=colour, label=c.label)
            else:
                ax.axhline(errs[c.key]["rms_error_n"], color=colour, ls=style, lw=1.6, label=c.label)
        # At one round trip every schedule is one spring: (5)'s, written as the alpha that gives it.
        k5 = float(traces["proposed"].spring_n_per_m[-1])
        if excess > 0.0 and math.isfinite(k5):
            ax.axvline(
                (k0 - k5) / excess,
                color="tab:red",
                ls=":",
                lw=1.6,
                label=f"(5)'s spring K = {k5:.3g} N/m, as Fujimoto04's alpha",
            )
        ax.set_xlabel("Fujimoto04's alpha [N/m per s of round trip]  (K = K0 − alpha (R − R0), floored at 0)")
        ax.set_ylabel("RMS force error against (1) [N]")
        ax.set_title(
            "Fujimoto04's error against its setting alpha (the one its user finds by trial and error)", fontsize=11
        )
        sec = ax.secondary_xaxis(
            "top",
            functions=(
                lambda a: k0 - np.asarray(a) * excess,
                lambda k: (k0 - np.asarray(k)) / excess if excess > 0 else k,
            ),
        )
        sec.set_xlabel("Fujimoto04's spring K at the measured round trip [N/m]")
        ax.grid(True, alpha=0.3)
        ax.legend(**_LEGEND)
    fig.savefig(path, dpi=100)


def plot_rtt(
    path: Path, rtts: Sequence[float], cases: Sequence[Case], rtt_err: dict[str, list[float]], args: argparse.Namespace
) -> None:
    fig, (ax,) = _figure(1, 5.0)
    for c in cases:
        colour, style = _SCHEME_STYLE[c.key]
        ax.plot([r * 1e3 for r in rtts], rtt_err[c.key], style, marker="o", color=colour, lw=1.6, label=c.label)
    ax.set_xlabel("round trip R [ms]")
    ax.set_ylabel("RMS force error against no delay [N]")
    ax.set_title(f"Each scheme's error against the round trip (push at {args.speed_m_per_s:g} m/s)", fontsize=11)
    ax.grid(True, alpha=0.3)
    ax.legend(**_LEGEND)
    fig.savefig(path, dpi=100)
