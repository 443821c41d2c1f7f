"""`haptic-teleop bench accuracy`: what simulation accuracy costs in CPU time (docs/accuracy.md).

Sweeps MuJoCo's timestep, integrator, solver iterations and tolerance, contact softness and the
control rate on a short window of a scene, one family of settings at a time around the scene's
own settings. Every setting is compared with a reference run (RK4 at the smallest timestep, at the
scene's control rate): force and position errors on a common time grid, the slave plant's energy
drift, and CPU time per simulated second (median of repeats). Writes accuracy.csv, accuracy.md
(table) and pareto.png (error against CPU time, non-dominated settings marked).
"""

from __future__ import annotations

import argparse
import csv
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.errors import HapticTeleopError, InputError
from haptic_teleop.studies.benchmarks import add_scene_argument, positive

INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")
REFERENCE_INTEGRATOR = "RK4"
MIN_TIMESTEP_S = 0.000125
TIMESTEPS_S = (0.000125, 0.00025, 0.0005, 0.001, 0.002)
CONTROL_RATE_FACTORS = (0.5, 2.0)  # control periods swept, as multiples of the scene's period
SOLVER_ITERATIONS = (1, 2, 3, 5, 10)
SOLVER_TOLERANCES = (1e-2, 1e-4, 1e-6, 1e-10)
CONTACT_IMPEDANCES = (0.01, 0.05, 0.2, 0.5)
SOLREF_TIMECONSTS_S = (0.002, 0.005, 0.01, 0.02)  # MuJoCo's (timeconst, dampratio) form, dampratio 1
SOLREF_DAMPRATIO = 1.0
DEFAULT_DURATION_S = 3.0

# Error columns: recorded engine column, what kind of signal it is (docs/accuracy.md, "Errors").
#   state: value at the tick's start instant, compared at the grid instants
#   past:  average over the period before the tick (the plant's contact force)
#   held:  held over the period after the tick (the applied actuator force)
ERROR_SIGNALS = (
    ("contact_force_rms_error_n", "s_contact_n", "past"),
    ("master_force_rms_error_n", "m_force_n", "held"),
    ("slave_position_rms_error_m", "s_x_m", "state"),
    ("master_position_rms_error_m", "m_x_m", "state"),
)
PARETO_ERRORS = (
    ("contact_force_rms_error_n", "wall contact force RMS error (N)"),
    ("slave_position_rms_error_m", "slave position RMS error (m)"),
)
CSV_COLUMNS = (
    "label",
    "family",
    "reference",
    "scene_default",
    "period_s",
    "control_rate_hz",
    "substeps",
    "timestep_s",
    "integrator",
    "solver_iterations",
    "solver_tolerance",
    "contact_impedance",
    "solref",
    "grid_period_s",
    "contact_force_rms_error_n",
    "contact_force_peak_error_n",
    "wall_law_force_rms_error_n",
    "master_force_rms_error_n",
    "slave_position_rms_error_m",
    "master_position_rms_error_m",
    "energy_drift_j",
    "energy_drift_end_j",
    "cpu_s_per_sim_s",
    "cpu_s_per_sim_s_min",
    "cpu_s_per_sim_s_max",
    "cpu_repeats",
    "pareto_force",
    "pareto_position",
)


@dataclass(frozen=True)
class Setting:
    """One point of the sweep: MuJoCo and control-rate settings applied on top of a scene."""

    family: str
    period_s: float
    substeps: int
    integrator: str
    solver_iterations: int
    solver_tolerance: float
    contact_impedance: float
    solref_timeconst_s: float | None = None  # None: the scene's exact K, B mapping (docs/plants.md)
    solref_dampratio: float = SOLREF_DAMPRATIO

    @property
    def timestep_s(self) -> float:
        return self.period_s / self.substeps

    def key(self) -> tuple[Any, ...]:
        """Identity of the numerical setting (the family is only how it was reached)."""
        return (
            round(self.period_s * 1e9),
            self.substeps,
            self.integrator,
            self.solver_iterations,
            self.solver_tolerance,
            self.contact_impedance,
            self.solref_timeconst_s,
            self.solref_dampratio if self.solref_timeconst_s is not None else None,
        )

    def overrides(self) -> list[str]:
        """Scene overrides for everything that has a scene key (solref time constant has none)."""
        return [
            f"scene.period_s={self.period_s!r}",
            f"simulation.substeps={self.substeps}",
            f"simulation.integrator={self.integrator}",
            f"simulation.solver_iterations={self.solver_iterations}",
            f"simulation.solver_tolerance={self.solver_tolerance!r}",
            f"slave.contact_impedance={self.contact_impedance!r}",
        ]

    def solref_text(self) -> str:
        if self.solref_timeconst_s is None:
            return "exact K,B"
        return f"({self.solref_timeconst_s:g}, {self.solref_dampratio:g})"

    def label(self) -> str:
        return (
            f"{self.integrator} h={self.timestep_s * 1e3:g}ms T={self.period_s * 1e3:g}ms"
            f" it={self.solver_iterations} tol={self.solver_tolerance:g} d={self.contact_impedance:g}"
            f" solref={self.solref_text().replace(' ', '')}"
        )


def substeps_for(period_s: float, timestep_s: float) -> int | None:
    """MuJoCo steps per control period for `timestep_s`, or None if it does not divide the period."""
    n = period_s / timestep_s
    k = round(n)
    if k < 1 or abs(n - k) > 1e-9 * n:
        return None
    return k


def base_setting(scene: Any) -> Setting:
    """The scene's own settings (the row marked `scene_default`)."""
    c = scene.config
    return Setting(
        family="timestep x integrator",
        period_s=c.scene.period_s,
        substeps=c.simulation.substeps,
        integrator=c.simulation.integrator,
        solver_iterations=c.simulation.solver_iterations,
        solver_tolerance=c.simulation.solver_tolerance,
        contact_impedance=c.slave.contact_impedance,
    )


def reference_setting(base: Setting, min_timestep_s: float = MIN_TIMESTEP_S) -> Setting:
    """RK4 at the smallest timestep, at the scene's control rate; other settings as the scene."""
    n = substeps_for(base.period_s, min_timestep_s)
    if n is None or n > 64:
        raise HapticTeleopError(
            f"bench accuracy: the reference timestep {min_timestep_s:g} s must divide the scene's "
            f"period_s {base.period_s:g} s into at most 64 substeps (simulation.substeps range); "
            "choose a scene period that is a multiple of it"
        )
    return replace(base, family="reference", substeps=n, integrator=REFERENCE_INTEGRATOR)


def build_plan(base: Setting, quick: bool = False) -> list[Setting]:
    """Settings to run, reference first, each numerical setting once (first family wins)."""
    ref = reference_setting(base)
    plan = [ref]
    if quick:
        fam = "timestep x integrator"
        for integ in ("implicitfast", REFERENCE_INTEGRATOR):
            for n in (1, 2):
                plan.append(replace(base, family=fam, integrator=integ, substeps=n))
        plan.append(replace(base, family="solver", solver_iterations=1))
        plan.append(replace(base, family="contact softness", solref_timeconst_s=SOLREF_TIMECONSTS_S[-1]))
        return _dedupe(plan)
    periods = [("timestep x integrator", base.period_s)] + [
        ("control rate", base.period_s * f) for f in CONTROL_RATE_FACTORS
    ]
    for family, period in periods:
        for integ in INTEGRATORS:
            for h in TIMESTEPS_S:
                n = substeps_for(period, h)
                if n is not None and n <= 64:
                    plan.append(replace(base, family=family, period_s=period, substeps=n, integrator=integ))
    plan += [replace(base, family="solver", solver_iterations=it) for it in SOLVER_ITERATIONS]
    plan += [replace(base, family="solver", solver_tolerance=tol) for tol in SOLVER_TOLERANCES]
    plan += [replace(base, family="contact softness", contact_impedance=d) for d in CONTACT_IMPEDANCES]
    plan += [replace(base, family="contact softness", solref_timeconst_s=tc) for tc in SOLREF_TIMECONSTS_S]
    return _dedupe(plan)


def _dedupe(plan: Sequence[Setting]) -> list[Setting]:
    seen: set[tuple[Any, ...]] = set()
    out = []
    for s in plan:
        if s.key() not in seen:
            seen.add(s.key())
            out.append(s)
    return out


# --- running ---------------------------------------------------------------------------------


@dataclass
class Signals:
    """The recorded columns a setting produced (one run; repeats are only timed)."""

    setting: Setting
    period_s: float
    columns: dict[str, np.ndarray]
    slave_mass_kg: float
    slave_damping_n_s_per_m: float
    energy_defined: bool  # False when plant effects (gravity, friction, sensor effects) change the balance
    cpu_s: list[float]
    wall: tuple[float, float, float] = (math.inf, 0.0, 0.0)  # position (m), stiffness (N/m), damping (N s/m)


def load_setting_scene(scene_path: Path, setting: Setting, duration_s: float, extra: Sequence[str] = ()) -> Any:
    from haptic_teleop.scene.load import load_scene

    return load_scene(scene_path, overrides=[*extra, f"scene.duration_s={duration_s!r}", *setting.overrides()])


def build_engine(scene: Any, setting: Setting) -> Any:
    """An Engine for `scene` with the settings that have no scene key written into MuJoCo."""
    from haptic_teleop.engine.lockstep import Engine

    engine = Engine(scene)
    if setting.solref_timeconst_s is not None:
        # MuJoCo's standard (timeconst, dampratio) solref replaces the plant's exact K, B mapping;
        # solimp (the impedance d) stays as the plant set it.
        model = engine.slave.model
        model.pair_solref[model.pair("tip_wall").id] = [setting.solref_timeconst_s, setting.solref_dampratio]
    return engine


def timed_run(scene: Any, setting: Setting) -> tuple[Any, float]:
    """One run of `scene` with `setting`: the RunResult and the CPU time of `Engine.run` (s)."""
    engine = build_engine(scene, setting)
    t0 = time.process_time()
    result = engine.run(handle_sigint=False)
    return result, time.process_time() - t0


def first_run(scene: Any, setting: Setting) -> Signals:
    """Run once and keep the columns the metrics need (later repeats are only timed)."""
    result, cpu = timed_run(scene, setting)
    names = {sig for _, sig, _ in ERROR_SIGNALS} | {"s_v_m_per_s", "s_force_n"}
    c = scene.config
    effects = getattr(c.slave, "effects", None)
    named = effects.named() if effects is not None else ()
    w = c.slave.wall
    return Signals(
        setting=setting,
        period_s=c.scene.period_s,
        columns={n: result.column(n).copy() for n in names},
        slave_mass_kg=c.slave.mass_kg,
        slave_damping_n_s_per_m=c.slave.damping_n_s_per_m,
        energy_defined=not named,
        cpu_s=[cpu],
        wall=(w.position_m, w.stiffness_n_per_m, w.damping_n_s_per_m),
    )


def run_setting(
    scene_path: Path, setting: Setting, duration_s: float, repeat: int, extra: Sequence[str] = ()
) -> Signals:
    """Run `setting` `repeat` times in a row; signals of the first run, CPU time of each."""
    scene = load_setting_scene(scene_path, setting, duration_s, extra)
    run = first_run(scene, setting)
    for _ in range(repeat - 1):
        run.cpu_s.append(timed_run(scene, setting)[1])
    return run


# --- metrics ---------------------------------------------------------------------------------


def _ratio(coarse_s: float, fine_s: float) -> int:
    k = coarse_s / fine_s
    r = round(k)
    if r < 1 or abs(k - r) > 1e-9 * k:
        raise HapticTeleopError(f"bench accuracy: control period {coarse_s:g} s is not a multiple of {fine_s:g} s")
    return r


def on_grid(x: np.ndarray, k: int, kind: str, blocks: int) -> np.ndarray:
    """`x` (one sample per control period) on a grid of `k` periods, `blocks` grid points.

    state: the value at each grid instant j*G; held (value held over the period after the sample):
    the mean over [j*G, (j+1)*G); past (value averaged over the period before the sample): the
    mean over (j*G, (j+1)*G], i.e. the samples that end inside that interval.
    """
    if kind == "state":
        return x[: blocks * k : k]
    start = 1 if kind == "past" else 0
    seg = x[start : start + blocks * k]
    return seg.reshape(blocks, k).mean(axis=1)


def grid_period_s(period_s: float, reference_period_s: float) -> float:
    """The coarser of the two control periods (which must be a multiple of the finer)."""
    coarse, fine = max(period_s, reference_period_s), min(period_s, reference_period_s)
    _ratio(coarse, fine)
    return coarse


def compare(run: Signals, ref: Signals) -> dict[str, float]:
    """Errors of `run` against `ref` on the coarser of the two control grids, same window."""
    g = grid_period_s(run.period_s, ref.period_s)
    k_run, k_ref = _ratio(g, run.period_s), _ratio(g, ref.period_s)
    n_run = len(run.columns["s_x_m"])
    n_ref = len(ref.columns["s_x_m"])
    # "past" signals need one sample beyond the last block; keep every kind on the same blocks.
    blocks = min((n_run - 1) // k_run, (n_ref - 1) // k_ref)
    if blocks < 1:
        raise HapticTeleopError("bench accuracy: the window is shorter than one grid period; raise --duration-s")
    out: dict[str, float] = {"grid_period_s": g}
    for name, col, kind in ERROR_SIGNALS:
        a = on_grid(run.columns[col], k_run, kind, blocks)
        b = on_grid(ref.columns[col], k_ref, kind, blocks)
        diff = a - b
        out[name] = float(np.sqrt(np.mean(diff * diff))) if np.all(np.isfinite(diff)) else math.inf
        if name == "contact_force_rms_error_n":
            out["contact_force_peak_error_n"] = float(np.max(np.abs(diff))) if np.isfinite(out[name]) else math.inf
    a = on_grid(wall_law_force_n(run), k_run, "state", blocks)
    b = on_grid(wall_law_force_n(ref), k_ref, "state", blocks)
    d = a - b
    out["wall_law_force_rms_error_n"] = float(np.sqrt(np.mean(d * d))) if np.all(np.isfinite(d)) else math.inf
    return out


def wall_law_force_n(run: Signals) -> np.ndarray:
    """The scene's wall law -(K p + B v) at each recorded state (p penetration), 0 out of contact.

    Not what the plant reports (MuJoCo's constraint force, sampled inside the period where the
    integrator evaluates it): a state-only force, so its error measures the dynamics alone.
    """
    pos, k, b = run.wall
    x, v = run.columns["s_x_m"], run.columns["s_v_m_per_s"]
    pen = x - pos
    return np.where(pen > 0.0, -(k * pen + b * v), 0.0)


def energy_residual_j(run: Signals) -> np.ndarray:
    """Slave energy balance residual at each tick (J): kinetic energy change minus net work.

    r(t_n) = m v_n^2/2 - m v_0^2/2 - sum_{i<n} [F_i dx_i + Fc_i dx_i - b (v_i + v_{i+1})/2 dx_i]
    with dx_i = x_{i+1} - x_i, F_i the actuator force held over period i (exact work under a
    zero-order hold), Fc_i MuJoCo's contact force averaged over period i (recorded at tick i+1)
    and b the joint damping. Zero in continuous time; derivation in docs/accuracy.md.
    """
    c = run.columns
    x, v, f, fc = c["s_x_m"], c["s_v_m_per_s"], c["s_force_n"], c["s_contact_n"]
    m, b = run.slave_mass_kg, run.slave_damping_n_s_per_m
    dx = np.diff(x)
    work = f[:-1] * dx + fc[1:] * dx - b * 0.5 * (v[:-1] + v[1:]) * dx
    ke = 0.5 * m * v * v
    return (ke - ke[0]) - np.concatenate(([0.0], np.cumsum(work)))


def pareto_front(cost: Sequence[float], error: Sequence[float]) -> list[bool]:
    """True for the points no other point dominates (both coordinates minimised).

    Point j dominates i when cost_j <= cost_i and error_j <= error_i with one of them strictly
    smaller; equal points do not dominate each other. Non-finite points are never on the front.
    """
    c = np.asarray(cost, dtype=float)
    e = np.asarray(error, dtype=float)
    if c.shape != e.shape or c.ndim != 1:
        raise ValueError(f"pareto_front: cost and error must be 1-D of equal length, got {c.shape} and {e.shape}")
    finite = np.isfinite(c) & np.isfinite(e)
    front = []
    for i in range(len(c)):
        if not finite[i]:
            front.append(False)
            continue
        le = (c <= c[i]) & (e <= e[i]) & finite
        lt = (c < c[i]) | (e < e[i])
        front.append(not bool(np.any(le & lt)))
    return front


def row_for(run: Signals, ref: Signals, base: Setting) -> dict[str, Any]:
    s = run.setting
    errors = compare(run, ref)
    if run.energy_defined:
        r = energy_residual_j(run)
        drift, drift_end = float(np.max(np.abs(r))), float(r[-1])
    else:
        drift = drift_end = math.nan
    duration_s = len(run.columns["s_x_m"]) * run.period_s
    return {
        "label": s.label(),
        "family": s.family,
        "reference": s.key() == ref.setting.key(),
        "scene_default": s.key() == base.key(),
        "period_s": s.period_s,
        "control_rate_hz": 1.0 / s.period_s,
        "substeps": s.substeps,
        "timestep_s": s.timestep_s,
        "integrator": s.integrator,
        "solver_iterations": s.solver_iterations,
        "solver_tolerance": s.solver_tolerance,
        "contact_impedance": s.contact_impedance,
        "solref": s.solref_text(),
        **errors,
        "energy_drift_j": drift,
        "energy_drift_end_j": drift_end,
        "cpu_s_per_sim_s": statistics.median(run.cpu_s) / duration_s,
        "cpu_s_per_sim_s_min": min(run.cpu_s) / duration_s,
        "cpu_s_per_sim_s_max": max(run.cpu_s) / duration_s,
        "cpu_repeats": len(run.cpu_s),
    }


def mark_fronts(rows: list[dict[str, Any]]) -> None:
    cost = [r["cpu_s_per_sim_s"] for r in rows]
    for key, (err, _) in zip(("pareto_force", "pareto_position"), PARETO_ERRORS, strict=True):
        for r, on in zip(rows, pareto_front(cost, [r[err] for r in rows]), strict=True):
            r[key] = on


# --- outputs ---------------------------------------------------------------------------------


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return "yes" if v else ""
    if isinstance(v, float):
        if math.isnan(v):
            return "n/a"
        if v == 0.0:
            return "0"
        return f"{v:.3g}"
    return str(v)


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items() if k in CSV_COLUMNS})


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    head = (
        "| family | T (ms) | h (ms) | integrator | iter | tol | d | solref | F err RMS (N) | F err peak (N) "
        "| F(state) err RMS (N) | x err RMS (m) | energy drift (J) | CPU s / sim s | front F | front x |"
    )
    lines = [head, "|" + " --- |" * 16]
    for r in rows:
        fam = r["family"] + (" (scene default)" if r["scene_default"] else "")
        lines.append(
            "| "
            + " | ".join(
                [
                    fam,
                    f"{r['period_s'] * 1e3:g}",
                    f"{r['timestep_s'] * 1e3:g}",
                    r["integrator"],
                    str(r["solver_iterations"]),
                    f"{r['solver_tolerance']:g}",
                    f"{r['contact_impedance']:g}",
                    r["solref"],
                    _fmt(r["contact_force_rms_error_n"]),
                    _fmt(r["contact_force_peak_error_n"]),
                    _fmt(r["wall_law_force_rms_error_n"]),
                    _fmt(r["slave_position_rms_error_m"]),
                    _fmt(r["energy_drift_j"]),
                    _fmt(r["cpu_s_per_sim_s"]),
                    "**yes**" if r["pareto_force"] else "",
                    "**yes**" if r["pareto_position"] else "",
                ]
            )
            + " |"
        )
    return "\n".join(lines) + "\n"


def write_markdown(path: Path, rows: Sequence[dict[str, Any]], command: str, facts: str) -> None:
    text = (
        "# Accuracy sweep\n\n"
        f"Command: `{command}`\n\n{facts}\n\n"
        "F err: wall contact force (as the plant reports it) against the reference; F(state) err: the scene's "
        "wall law -(K p + B v) at the recorded states; x err: slave position; energy drift: max |slave energy "
        "balance residual| over the window; front F / front x: on the Pareto front of that error against CPU time "
        "(docs/accuracy.md).\n\n" + markdown_table(rows)
    )
    path.write_text(text)


def _front_text(r: dict[str, Any]) -> str:
    text = f"{r['integrator']} h={r['timestep_s'] * 1e3:g} ms, T={r['period_s'] * 1e3:g} ms"
    if r["family"] in ("solver", "contact softness"):
        text += f", iter {r['solver_iterations']}, tol {r['solver_tolerance']:g}, d {r['contact_impedance']:g}"
        text += f", solref {r['solref']}"
    if r["reference"]:
        text += " (reference, error 0)"
    if r["scene_default"]:
        text += " (scene default)"
    return text


def write_plot(path: Path, rows: Sequence[dict[str, Any]], title: str) -> None:
    """Two panels (force error, position error) against CPU time, log axes, fronts numbered."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    colors = {"Euler": "tab:orange", "implicitfast": "tab:blue", "implicit": "tab:green", "RK4": "tab:red"}
    markers = {
        "reference": "*",
        "timestep x integrator": "o",
        "control rate": "s",
        "solver": "^",
        "contact softness": "D",
    }
    fig, axes = plt.subplots(1, 2, figsize=(16, 10))
    cost = np.array([r["cpu_s_per_sim_s"] for r in rows])
    for ax, (err_key, err_label), front_key in zip(
        axes, PARETO_ERRORS, ("pareto_force", "pareto_position"), strict=True
    ):
        err = np.array([r[err_key] for r in rows], dtype=float)
        positive = err[np.isfinite(err) & (err > 0)]
        floor = positive.min() / 5 if positive.size else 1e-12
        shown = np.where(err > 0, err, floor)
        for r, c, e in zip(rows, cost, shown, strict=True):
            ax.plot(
                c,
                e,
                markers.get(r["family"], "o"),
                color=colors.get(r["integrator"], "k"),
                ms=12 if r["reference"] else 6,
                alpha=0.85,
                mec="none",
            )
            if r["scene_default"]:
                ax.plot(c, e, "o", mfc="none", mec="magenta", ms=17, mew=2)
        idx = sorted((i for i, r in enumerate(rows) if r[front_key]), key=lambda i: cost[i])
        if idx:
            ax.step(cost[idx], shown[idx], where="post", color="0.3", lw=1, zorder=0)
            ax.plot(cost[idx], shown[idx], "o", mfc="none", mec="k", ms=12, mew=1.2)
            lines = []
            for n, i in enumerate(idx, start=1):
                ax.annotate(str(n), (cost[i], shown[i]), xytext=(6, 6), textcoords="offset points", fontsize=9)
                lines.append(f"{n}: {_front_text(rows[i])}")
            ax.text(
                0.0,
                -0.13,
                "Pareto front, cheapest first:\n" + "\n".join(lines),
                transform=ax.transAxes,
                va="top",
                ha="left",
                fontsize=8,
            )
        if np.any(err == 0):
            ax.axhline(floor, color="0.7", ls=":", lw=1)
        finite_shown = shown[np.isfinite(shown)]
        ax.set_ylim(floor / 2, max(float(finite_shown.max()) if finite_shown.size else floor, floor) * 3)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU time per simulated second (s/s, median of repeats)")
        ax.set_ylabel(err_label + " vs RK4 reference")
        ax.grid(True, which="both", alpha=0.3)
    handles = [Line2D([], [], ls="", marker="o", color=c, label=n) for n, c in colors.items()]
    handles += [Line2D([], [], ls="", marker=m, color="0.4", label=n) for n, m in markers.items()]
    handles += [
        Line2D([], [], ls="", marker="o", mfc="none", mec="k", ms=12, label="Pareto front (non-dominated)"),
        Line2D([], [], ls="", marker="o", mfc="none", mec="magenta", mew=2, ms=14, label="scene default"),
    ]
    fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.935), ncol=11, fontsize=9, frameon=False)
    fig.suptitle(title + "\n(the reference has error 0 and is drawn on the dotted line)", fontsize=11)
    fig.subplots_adjust(left=0.06, right=0.98, top=0.88, bottom=0.32, wspace=0.18)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --- command ---------------------------------------------------------------------------------


def default_out() -> Path:
    base = Path("runs")
    i = 1
    while (base / f"accuracy-{i:03d}").exists():
        i += 1
    return base / f"accuracy-{i:03d}"


def sweep(
    scene_name: str,
    duration_s: float,
    repeat: int,
    quick: bool,
    extra: Sequence[str] = (),
    progress: Callable[[str], None] | None = None,
) -> tuple[list[dict[str, Any]], str]:
    """Run the plan; rows in plan order (reference first) and a one-paragraph description."""
    from haptic_teleop.scene.load import find_scene, load_scene

    path = find_scene(scene_name)
    scene = load_scene(path, overrides=[*extra, f"scene.duration_s={duration_s!r}"])
    base = base_setting(scene)
    plan = build_plan(base, quick=quick)
    scenes = [load_setting_scene(path, s, duration_s, extra) for s in plan]  # all validated first
    runs = []
    for s, sc in zip(plan, scenes, strict=True):
        runs.append(first_run(sc, s))
        if progress is not None:
            progress(s.label())
    # Repeats go round the whole plan, so a change of the machine's load (shared here) spreads
    # over every setting instead of biasing the ones that happened to run during it.
    for _ in range(repeat - 1):
        for run, sc in zip(runs, scenes, strict=True):
            run.cpu_s.append(timed_run(sc, run.setting)[1])
            if progress is not None:
                progress(run.setting.label())
    ref = runs[0]
    rows = [row_for(r, ref, base) for r in runs]
    mark_fronts(rows)
    c = scene.config
    facts = (
        f"Scene `{c.scene.name}`{' with ' + ', '.join(extra) if extra else ''}, first {duration_s:g} s "
        f"(seed {c.scene.seed}); {len(rows)} settings; "
        f"reference: {ref.setting.label()}. CPU time: `time.process_time()` around `Engine.run`, median of "
        f"{max(1, repeat)} runs taken round the whole plan, on a shared 2-core machine (noisy)."
    )
    return rows, facts


def main(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else default_out()
    if out.exists() and any(out.iterdir()):
        raise InputError(
            f"--out {out}: exists and is not empty; allowed: a directory that does not exist yet or is empty"
        )
    from haptic_teleop.scene.load import find_scene, load_scene

    repeat = args.repeat if args.repeat is not None else (1 if args.quick else 5)
    if repeat < 1:
        raise HapticTeleopError(f"bench accuracy: --repeat {repeat}: allowed: an integer >= 1")
    scene = load_scene(find_scene(args.scene), overrides=[*(args.set or ()), f"scene.duration_s={args.duration_s!r}"])
    total = len(build_plan(base_setting(scene), quick=args.quick)) * repeat
    bar = None
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="run", desc="bench accuracy", file=sys.stderr, leave=False)

    def step(label: str) -> None:
        if bar is not None:
            bar.set_postfix_str(label[:40])
            bar.update(1)

    try:
        rows, facts = sweep(args.scene, args.duration_s, repeat, args.quick, args.set or (), step)
    finally:
        if bar is not None:
            bar.close()
    out.mkdir(parents=True, exist_ok=True)
    command = "haptic-teleop bench accuracy " + " ".join(
        [f"--scene {args.scene}", f"--duration-s {args.duration_s:g}", f"--repeat {repeat}"]
        + (["--quick"] if args.quick else [])
        + [f"--set {s}" for s in (args.set or ())]
    )
    write_csv(out / "accuracy.csv", rows)
    write_markdown(out / "accuracy.md", rows, command, facts)
    write_plot(out / "pareto.png", rows, f"{facts.split(';')[0]}: error against CPU time")
    print(facts)
    for r in rows:
        if r["pareto_force"] or r["pareto_position"] or r["scene_default"] or r["reference"]:
            tags = [t for t, k in (("front F", "pareto_force"), ("front x", "pareto_position")) if r[k]]
            tags += ["scene default"] * r["scene_default"] + ["reference"] * r["reference"]
            print(
                f"  {r['label']:<70} F {_fmt(r['contact_force_rms_error_n']):>8} N  "
                f"x {_fmt(r['slave_position_rms_error_m']):>8} m  "
                f"cpu {_fmt(r['cpu_s_per_sim_s']):>7} s/s  [{', '.join(tags)}]"
            )
    print(f"\ncsv:   {out / 'accuracy.csv'}\ntable: {out / 'accuracy.md'}\nplot:  {out / 'pareto.png'}")
    return 0


HELP = "sweep MuJoCo timestep, integrator, solver, contact softness, control rate: error against CPU time"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scene_argument(p)
    p.add_argument(
        "--duration-s",
        type=float,
        default=DEFAULT_DURATION_S,
        help=f"simulated window from t=0 (default {DEFAULT_DURATION_S:g} s: free motion, then contact)",
    )
    p.add_argument(
        "--repeat", type=positive(int), help="timed runs per setting; the median is used (default 5, --quick 1)"
    )
    p.add_argument("--quick", action="store_true", help="a tiny sweep (7 settings) to check the pipeline")
    p.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="scene override (repeatable)")
    p.add_argument("--out", help="output directory (default runs/accuracy-NNN)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
