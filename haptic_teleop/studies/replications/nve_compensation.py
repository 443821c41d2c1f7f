"""`haptic-teleop experiment nve-compensation`: seed 000's second NVE experiment, its delay
compensation against the uncompensated client and Fujimoto's scheme over round-trip times
(docs/nve_experiments.md); the shared runner and cases are studies/replications/nve.py's.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.args import number
from haptic_teleop.studies.replications.nve import (
    CLIENT,
    LEGEND,
    NO_COMPENSATION,
    Case,
    Trace,
    add_common_arguments,
    command_line,
    delay_overrides,
    errors,
    force_axes,
    fujimoto_overrides,
    nve_figure,
    prepare_runs,
    push_window,
    shade_push,
)
from haptic_teleop.studies.replications.recorded import bags_line
from haptic_teleop.studies.replications.tables import markdown, rms, write_csv

COMPENSATION_HELP = (
    "seed 000's delay compensation experiment: push at constant velocity over round trip R with no "
    "compensation, Fujimoto04 (two settings) and the proposed scheme, each against no delay; plot, CSV, table"
)


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
    out, runner = prepare_runs(args, "nve-compensation", _transparency_settings)
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
        print(bags_line(out, args.discard_bags))
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
    fig, axes = nve_figure(2 if alphas else 1, 9.0 if alphas else 5.0)
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
        ax.legend(**LEGEND)
    fig.savefig(path, dpi=100)


def plot_rtt(
    path: Path, rtts: Sequence[float], cases: Sequence[Case], rtt_err: dict[str, list[float]], args: argparse.Namespace
) -> None:
    fig, (ax,) = nve_figure(1, 5.0)
    for c in cases:
        colour, style = _SCHEME_STYLE[c.key]
        ax.plot([r * 1e3 for r in rtts], rtt_err[c.key], style, marker="o", color=colour, lw=1.6, label=c.label)
    ax.set_xlabel("round trip R [ms]")
    ax.set_ylabel("RMS force error against no delay [N]")
    ax.set_title(f"Each scheme's error against the round trip (push at {args.speed_m_per_s:g} m/s)", fontsize=11)
    ax.grid(True, alpha=0.3)
    ax.legend(**LEGEND)
    fig.savefig(path, dpi=100)
