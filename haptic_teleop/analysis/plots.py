"""PNG plots of one run: forces, positions, energy at each port."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from haptic_teleop.analysis.metrics import Signals, port_energy


def write_plots(sig: Signals, out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    t = sig.t_s
    lag = sig.backward_lag_ticks
    paths = []
    title = f"{sig.scene['scene']['name']} (seed {sig.scene['scene']['seed']})"

    fig, ax = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, height_ratios=(3, 1))
    ax[0].plot(t, sig.contact_n, label="wall force on robot", color="tab:red", lw=1.2)
    ax[0].plot(t, sig.master_force_n, label="force rendered to operator", color="tab:blue", lw=1.2)
    if 0 < lag < t.size:
        ax[0].plot(
            t[lag:],
            sig.contact_n[:-lag],
            label=f"wall force delayed {lag * sig.period_s * 1e3:.0f} ms",
            color="tab:red",
            ls="--",
            lw=0.8,
            alpha=0.7,
        )
    ax[0].set_ylabel("force along x (N)")
    ax[0].legend(loc="best")
    ax[0].set_title(f"Forces: {title}")
    ax[0].grid(alpha=0.3)
    err = (
        sig.master_force_n[lag:] - sig.contact_n[: t.size - lag]
        if 0 < lag < t.size
        else sig.master_force_n - sig.contact_n
    )
    ax[1].plot(t[t.size - err.size :], err, color="k", lw=0.8)
    ax[1].set_ylabel("felt - wall (N)")
    ax[1].set_xlabel("time (s)")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    p = out_dir / "forces.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    fig, ax = plt.subplots(figsize=(10, 4.5))
    ax.plot(t, sig.operator_x_m * 1e3, label="operator intended", color="tab:gray", ls=":")
    ax.plot(t, sig.master_x_m * 1e3, label="master", color="tab:blue")
    ax.plot(t, sig.slave_x_m * 1e3, label="slave", color="tab:green")
    ax.axhline(float(sig.scene["slave"]["wall"]["position_m"]) * 1e3, color="tab:red", lw=0.8, label="wall")
    ax.set_ylabel("position (mm)")
    ax.set_xlabel("time (s)")
    ax.set_title(f"Positions: {title}")
    ax.legend(loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    p = out_dir / "positions.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)

    sc = sig.scene
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for k, (side, x, f, res) in enumerate(
        (("master", sig.master_x_m, sig.master_force_n, sig.master_reservoir_j),
         ("slave", sig.slave_x_m, sig.slave_force_n, sig.slave_reservoir_j))
    ):  # fmt: skip
        b = float(sc[side]["damping_n_s_per_m"])
        e0 = float(sc["controllers"][side]["eba"]["initial_energy_j"])
        margin = e0 + port_energy(x, f, b, sig.period_s)
        ax[k].plot(t, margin, label="energy margin from plant signals", color="tab:purple")
        if res is not None:
            ax[k].plot(t, res, label="controller reservoir", color="tab:orange", ls="--", lw=0.9)
        ax[k].axhline(0.0, color="k", lw=0.6)
        ax[k].set_ylabel(f"{side} (J)")
        ax[k].grid(alpha=0.3)
        ax[k].legend(loc="best")
        lo = float(np.min(margin))
        ax[k].set_title(f"{side} port: min margin {lo:.3g} J" + (" (stayed passive)" if lo >= 0 else " (NOT passive)"))
    ax[1].set_xlabel("time (s)")
    fig.tight_layout()
    p = out_dir / "energy.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths
