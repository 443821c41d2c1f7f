"""`haptic-teleop experiment playout`: seed 000's haptic-synchronization claim, tested fairly
(docs/playout_claim.md, "The haptic-synchronization claim, tested fairly").

Seed 000 says its network-adaptive buffering (the buffering time from the transparency analysis:
allowable delay and loss time, with the minimum network delay) gives less force feedback error than
the existing haptic synchronization schemes over a time-varying delay. This runs, on the bundled
scene seed_contact_playout (the seed's premise with force reflection and the master's bound binding;
a sinusoidal delay with jitter and netem reordering, both ways) in four configurations (`CONFIGS`:
as bundled, without netem reorder, with the published two-condition EBA, without the bound
binding), every policy in both directions:

- `network_adaptive`: the seed's rule (core/playout.py `NetworkAdaptiveBuffer`; D_a, L_a and d0 are
  passed by the engine from the scene's transparency analysis and the link, assembly.build_network);
- `adaptive` (Ramjee et al. 1994, algorithm 1), `percentile` (NetEq-like, q = 0.95);
- `fixed_above`: `fixed` with its buffering time set so that its constant latency is above every
  network delay of the run (`fixed_above_delay_s`: max - min of the link's one-way delays, which the
  common random numbers make the same for every policy of a seed);
- `transparency` (the previous reading, default horizon 1 s) and `none` (play on arrival).

Seeds are paired: seed k gives every policy the same network draws (docs/network.md, "Random
streams"), so differences against `network_adaptive` are taken seed by seed. The errors are the
master's felt force against the undisturbed reference run (the same scene with no network effects,
run once: it is deterministic) and against the wall force at the same instant, over the whole run.
Writes playout.csv (per policy: mean and sample std over seeds), playout_paired.csv (paired
differences), playout_runs.csv (every run), playout.md and playout.png.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.replications.args import number, subset
from haptic_teleop.studies.replications.recorded import BagRuns, bags_line, compression, record_ticks
from haptic_teleop.studies.replications.tables import markdown, rms, write_csv

HELP = (
    "seed 000's haptic-synchronization claim: its network-adaptive buffering against adaptive, percentile, a "
    "constant latency above the network delay and play-on-arrival, paired seeds; force error against the "
    "undisturbed run; CSV, tables, plot"
)
BASE_SCENE = "seed_contact_playout"
SEED_POLICY = "network_adaptive"
# name -> (label, buffer keys set in both directions); `fixed_above` gets its buffering per seed.
POLICIES: dict[str, tuple[str, dict[str, Any]]] = {
    "network_adaptive": ("network-adaptive (seed 000)", {"policy": "network_adaptive"}),
    "adaptive": ("adaptive (Ramjee)", {"policy": "adaptive"}),
    "percentile": ("percentile (NetEq-like, 0.95)", {"policy": "percentile"}),
    "fixed_above": ("constant latency above the delay", {"policy": "fixed"}),
    "transparency": ("transparency (previous reading, H 1 s)", {"policy": "transparency"}),
    "none": ("play on arrival", {"policy": "none"}),
}
DIRS = ("forward", "backward")
# name -> (label, scene overrides): the scene as bundled, the same without netem's reordering
# (reordering by jitter remains), the same with the published two-condition EBA at the master (a
# per-step cap: a hold past the transparent loss time stops the ramp for good; Python loop), and
# force reflection without the bound binding.
CONFIGS: dict[str, tuple[str, tuple[str, ...]]] = {
    "binding": ("bound binding, reordering", ()),
    "binding_no_reorder": (
        "bound binding, no netem reorder",
        ("network.forward.effects.reorder=null", "network.backward.effects.reorder=null"),
    ),
    "two_condition": (
        "bound binding, published two-condition EBA, reordering",
        ("controllers.master.eba.law=two_condition",),
    ),
    "not_binding": (
        "bound not binding (b_m 1, g 1), reordering",
        ("master.damping_n_s_per_m=1.0", "controllers.master.force_gain=1.0"),
    ),
}


def fixed_above_delay_s(delays_s: np.ndarray, period_s: float) -> float:
    """The `fixed` buffering time whose constant latency is above every delay in `delays_s`:
    `fixed` plays at (the least relative delay before playout starts) + buffering, that least
    delay is at least min(delays), and the engine pushes a packet at the first tick at or after
    its arrival (up to one period later), so max - min + one period puts the playout point after
    every packet's push."""
    d = delays_s[np.isfinite(delays_s)]
    return float(d.max() - d.min()) + period_s if d.size else 0.0


def _scene(overrides: Sequence[str]) -> Any:
    from haptic_teleop.scene.load import find_scene, load_scene

    return load_scene(find_scene(BASE_SCENE), overrides=list(overrides))


def _buffer_overrides(keys: dict[str, Any]) -> list[str]:
    return [f"network.{d}.buffer.{k}={v}" for d in DIRS for k, v in keys.items()]


@dataclass
class Measured:
    felt_n: np.ndarray
    wall_n: np.ndarray  # the wall force times the force-reflection gain (1 for the position law)
    rx_seq: np.ndarray  # backward releases per tick (-1: none)
    fwd_log: np.ndarray
    bwd_log: np.ndarray


def _run(overrides: Sequence[str], runs: BagRuns, key: str) -> tuple[Measured, Any]:
    """One run recorded to its bag; what the tables use read back from the bag."""
    scene = _scene(overrides)
    with runs.bag(key, overrides=overrides) as bag:
        t = record_ticks(scene, bag)
    m = scene.config.controllers.master
    gain = m.force_gain if m.law == "force" else 1.0  # what the law renders of the wall force
    return (
        Measured(
            felt_n=np.abs(t.column("m_force_n")),
            wall_n=gain * np.abs(t.column("s_contact_n")),
            rx_seq=t.column("bwd_rx_seq").astype(np.int64),
            fwd_log=t.forward_log,
            bwd_log=t.backward_log,
        ),
        scene,
    )


def _delays(log: np.ndarray) -> np.ndarray:
    """One-way delays of the packets that arrived (originals; late ones too)."""
    orig = log[log[:, 4] == 0]
    return np.asarray(orig[:, 2] - orig[:, 1], dtype=float)


def _stats(m: Measured, ref: Measured, period_s: float) -> dict[str, float]:
    """The run's metrics at the master (the backward direction's buffer)."""
    e_ref = m.felt_n - ref.felt_n
    e_wall = m.felt_n - m.wall_n
    log = m.bwd_log
    orig = log[log[:, 4] == 0]
    n = len(orig)
    arrival = np.full(int(orig[:, 0].max()) + 1 if n else 1, np.nan)
    arrival[orig[:, 0].astype(np.int64)] = orig[:, 2]
    ticks = np.flatnonzero(m.rx_seq >= 0)
    seqs = m.rx_seq[ticks]
    arr = arrival[seqs]
    push_tick = np.ceil(arr / period_s - 1e-9)
    buffering = (ticks - push_tick) * period_s
    # the age of the sample in use at every tick (after the first release): network delay + buffering
    in_use = np.maximum.accumulate(np.where(m.rx_seq >= 0, m.rx_seq, -1))
    ok = in_use >= 0
    age = (np.flatnonzero(ok) - in_use[ok]) * period_s
    fwd = m.fwd_log[m.fwd_log[:, 4] == 0]
    return {
        "force_rms_error_vs_reference_n": rms(e_ref),
        "force_peak_error_vs_reference_n": float(np.max(np.abs(e_ref))),
        "force_rms_error_vs_wall_n": rms(e_wall),
        "force_peak_error_vs_wall_n": float(np.max(np.abs(e_wall))),
        "felt_force_end_n": float(m.felt_n[-1]),
        "buffering_backward_mean_ms": float(np.mean(buffering)) * 1e3 if buffering.size else math.nan,
        "sample_age_backward_mean_ms": float(np.mean(age)) * 1e3 if age.size else math.nan,
        "late_loss_rate_backward": float(np.mean(orig[:, 3] == 4)) if n else math.nan,
        "late_loss_rate_forward": float(np.mean(fwd[:, 3] == 4)) if len(fwd) else math.nan,
    }


METRICS = (
    "force_rms_error_vs_reference_n",
    "force_peak_error_vs_reference_n",
    "force_rms_error_vs_wall_n",
    "force_peak_error_vs_wall_n",
    "felt_force_end_n",
    "buffering_backward_mean_ms",
    "sample_age_backward_mean_ms",
    "late_loss_rate_backward",
    "late_loss_rate_forward",
)
PAIRED = METRICS[:4]


def run_experiment(
    policies: Sequence[str],
    seeds: Sequence[int],
    extra: Sequence[str],
    runs: BagRuns | None = None,
    config: str = "",
) -> tuple[list[list[Any]], dict[str, float]]:
    """Every policy on every seed of one configuration (`extra`: scene overrides): rows
    [policy, seed, fixed buffering (s), *METRICS]; and the facts the seed policy runs on (D_a, L_a, d0).
    Each run is recorded to a bag of `runs` (`<config>_<run>`) and measured from it."""
    runs = runs if runs is not None else BagRuns()
    pre = f"{config}_" if config else ""
    no_net = [f"network.{d}.effects={{}}" for d in DIRS] + _buffer_overrides({"policy": "none"})
    ref, scene = _run((*extra, *no_net), runs, f"{pre}undisturbed")
    period = scene.config.scene.period_s
    rows: list[list[Any]] = []
    facts: dict[str, float] = {}
    for seed in seeds:
        seed_ov = (*extra, f"scene.seed={seed}")
        arrival_run, _ = _run((*seed_ov, *_buffer_overrides({"policy": "none"})), runs, f"{pre}none_seed{seed}")
        fixed_s = max(
            fixed_above_delay_s(_delays(arrival_run.fwd_log), period),
            fixed_above_delay_s(_delays(arrival_run.bwd_log), period),
        )
        for name in policies:
            keys = dict(POLICIES[name][1])
            if name == "fixed_above":
                keys["buffering_time_s"] = repr(fixed_s)
            m = (
                arrival_run
                if name == "none"
                else _run((*seed_ov, *_buffer_overrides(keys)), runs, f"{pre}{name}_seed{seed}")[0]
            )
            st = _stats(m, ref, period)
            rows.append([name, seed, fixed_s if name == "fixed_above" else math.nan, *(st[k] for k in METRICS)])
    from haptic_teleop.core.netconfig import min_one_way_delay_s
    from haptic_teleop.scene.contact import transparency_budget_of

    budget = transparency_budget_of(scene.config)
    if budget is not None:
        facts["allowable_delay_s"], facts["allowable_loss_time_s"] = budget
    facts["min_one_way_delay_s"] = min_one_way_delay_s(_scene(extra).config.network.backward.effects)
    return rows, facts


def summary(rows: list[list[Any]], policies: Sequence[str]) -> tuple[list[list[Any]], list[list[Any]]]:
    """Per policy: mean and sample std over seeds of each metric; paired differences (policy minus
    the seed policy, seed by seed) of the force errors: mean, std, and how many seeds it is below."""
    table, paired = [], []
    base = {r[1]: r for r in rows if r[0] == SEED_POLICY}
    for name in policies:
        rs = [r for r in rows if r[0] == name]
        row: list[Any] = [name, POLICIES[name][0], len(rs)]
        for i, _ in enumerate(METRICS):
            v = np.array([r[3 + i] for r in rs], dtype=float)
            row += [float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else math.nan]
        table.append(row)
        if name == SEED_POLICY or not base:
            continue
        prow: list[Any] = [name]
        for k in PAIRED:
            i = METRICS.index(k)
            diff = np.array([r[3 + i] - base[r[1]][3 + i] for r in rs if r[1] in base], dtype=float)
            prow += [float(np.mean(diff)), float(np.std(diff, ddof=1)) if len(diff) > 1 else math.nan]
            prow.append(int(np.sum(diff > 0.0)))
        paired.append(prow)
    return table, paired


TABLE_HEADER = ["policy", "label", "seeds"] + [f"{k}_{s}" for k in METRICS for s in ("mean", "std")]
PAIRED_HEADER = ["policy"] + [f"{k}_minus_seed_policy_{s}" for k in PAIRED for s in ("mean", "std", "seeds_worse")]
RUNS_HEADER = ["policy", "seed", "fixed_buffering_time_s", *METRICS]


def _pm(mean: float, std: float, scale: float = 1.0, digits: int = 4) -> str:
    if not math.isfinite(std):
        return f"{mean * scale:.{digits}g}"
    return f"{mean * scale:.{digits}g} ± {std * scale:.2g}"


def markdown_tables(table: list[list[Any]], paired: list[list[Any]], n_seeds: int) -> str:
    """The docs' tables: per policy mean ± std, and paired differences against the seed policy."""
    col = {k: 3 + 2 * i for i, k in enumerate(METRICS)}
    head = [
        "policy",
        "RMS vs reference (N)",
        "peak vs reference (N)",
        "RMS vs wall (N)",
        "peak vs wall (N)",
        "buffering, backward (ms)",
        "sample age, backward (ms)",
        "late loss, backward",
        "late loss, forward",
    ]
    body = []
    for r in table:
        body.append(
            [
                r[1],
                *(_pm(r[col[k]], r[col[k] + 1]) for k in PAIRED),
                _pm(r[col["buffering_backward_mean_ms"]], r[col["buffering_backward_mean_ms"] + 1], digits=3),
                _pm(r[col["sample_age_backward_mean_ms"]], r[col["sample_age_backward_mean_ms"] + 1], digits=3),
                _pm(r[col["late_loss_rate_backward"]], r[col["late_loss_rate_backward"] + 1], digits=3),
                _pm(r[col["late_loss_rate_forward"]], r[col["late_loss_rate_forward"] + 1], digits=3),
            ]
        )
    out = markdown(head, body)
    phead = [
        "policy minus network-adaptive",
        "RMS vs reference (N)",
        "peak vs reference (N)",
        "RMS vs wall (N)",
        "peak vs wall (N)",
    ]
    pbody = []
    for p in paired:
        cells = [POLICIES[p[0]][0]]
        for j in range(len(PAIRED)):
            mean, std, worse = p[1 + 3 * j], p[2 + 3 * j], p[3 + 3 * j]
            cells.append(f"{_pm(mean, std)} (worse on {worse}/{n_seeds})")
        pbody.append(cells)
    return out + "\n" + markdown(phead, pbody)


def _plot(rows: list[list[Any]], configs: Sequence[str], policies: Sequence[str], path: Path) -> None:
    """Per configuration: RMS and peak error against the undisturbed run per policy (a box over the
    seeds, one dot per seed), and RMS error against the mean buffering."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(configs), 3, figsize=(15, 4.2 * len(configs)), squeeze=False)
    ib = 4 + METRICS.index("buffering_backward_mean_ms")
    ie = 4 + METRICS.index("force_rms_error_vs_reference_n")
    for ci, c in enumerate(configs):
        crows = [r for r in rows if r[0] == c]
        for ax, key, title in (
            (axes[ci][0], "force_rms_error_vs_reference_n", "RMS force error vs undisturbed run [N]"),
            (axes[ci][1], "force_peak_error_vs_reference_n", "peak force error vs undisturbed run [N]"),
        ):
            i = 4 + METRICS.index(key)
            data = [[r[i] for r in crows if r[1] == p] for p in policies]
            ax.boxplot(data, showmeans=True)
            for j, d in enumerate(data):
                ax.plot(np.full(len(d), j + 1.0) + np.linspace(-0.15, 0.15, len(d)), d, ".", color="C0", alpha=0.5)
            ax.set_xticks(range(1, len(policies) + 1), list(policies), rotation=25, ha="right", fontsize=8)
            ax.set_title(f"{CONFIGS[c][0]}:\n{title}", fontsize=9)
            ax.grid(alpha=0.3)
        ax = axes[ci][2]
        for j, p in enumerate(policies):
            rs = [r for r in crows if r[1] == p]
            ax.plot([r[ib] for r in rs], [r[ie] for r in rs], "o", color=f"C{j}", label=p, alpha=0.6)
        ax.set_xlabel("mean buffering, backward [ms]")
        ax.set_ylabel("RMS error vs undisturbed run [N]")
        ax.set_title(f"{CONFIGS[c][0]}:\nerror against buffering (one dot per seed)", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="output directory, new or empty (default runs/playout-NNN)")
    p.add_argument("--seeds", type=number(1, 1000, kind=int), default=20, help="seeds 1..N (paired across policies)")
    p.add_argument("--policies", default=",".join(POLICIES), help=f"which policies ({', '.join(POLICIES)})")
    p.add_argument("--configs", default=",".join(CONFIGS), help=f"which configurations ({', '.join(CONFIGS)})")
    p.add_argument("--quick", action="store_true", help="3 seeds, 1.5 s runs, the first configuration (for tests)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key of the base scene")
    p.add_argument("--discard-bags", action="store_true", help="measure each run's bag, then delete it")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")


def main(args: argparse.Namespace) -> int:
    from haptic_teleop.analysis.outputs import check_out_dir, default_out

    policies = subset(args.policies, list(POLICIES), "--policies")
    configs = subset(args.configs, list(CONFIGS), "--configs")
    if SEED_POLICY not in policies:
        policies.insert(0, SEED_POLICY)
    extra: tuple[str, ...] = (compression(args.discard_bags), *(args.set or ()))
    seeds = int(args.seeds)
    if args.quick:
        extra = ("scene.duration_s=1.5", "operator.duration_s=0.9", *extra)
        seeds = min(seeds, 3)
        configs = configs[:1]
    for c in configs:  # a bad --set fails here, before anything is written
        _scene((*CONFIGS[c][1], *extra))
    out = Path(args.out) if args.out else default_out("playout")
    check_out_dir(out)
    runs = BagRuns(out / "bags", args.discard_bags)
    all_rows: list[list[Any]] = []
    all_table: list[list[Any]] = []
    all_paired: list[list[Any]] = []
    text = ""
    for c in configs:
        label, ov = CONFIGS[c]
        rows, facts = run_experiment(policies, range(1, seeds + 1), (*ov, *extra), runs, c)
        table, paired = summary(rows, policies)
        all_rows += [[c, *r] for r in rows]
        all_table += [[c, *r] for r in table]
        all_paired += [[c, *r] for r in paired]
        text += f"### {label}\n\n" + markdown_tables(table, paired, seeds)
        text += "\n" + ", ".join(f"{k} = {v:.4g}" for k, v in facts.items()) + "\n\n"
    write_csv(out / "playout_runs.csv", ["configuration", *RUNS_HEADER], all_rows)
    write_csv(out / "playout.csv", ["configuration", *TABLE_HEADER], all_table)
    write_csv(out / "playout_paired.csv", ["configuration", *PAIRED_HEADER], all_paired)
    (out / "playout.md").write_text(text)
    _plot(all_rows, configs, policies, out / "playout.png")
    if not args.quiet:
        sys.stdout.write(text)
        sys.stdout.write(f"{out / 'playout.png'}\n{bags_line(out, args.discard_bags)}\n")
    return 0
