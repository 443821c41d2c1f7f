"""Human-readable summary table of a run or a bag."""

from __future__ import annotations

import math
from typing import Any

ROWS = (
    ("realtime_factor", "real-time factor (sim s / wall s)", "{:.1f}"),
    ("engine_loop", "tick loop", "{}"),
    ("force_rms_error_n", "force RMS error, felt vs wall, aligned (N)", "{:.4f}"),
    ("force_peak_error_n", "force peak error, aligned (N)", "{:.4f}"),
    ("force_rms_error_unaligned_n", "force RMS error, not aligned (N)", "{:.4f}"),
    ("force_alignment_lag_s", "alignment lag (s)", "{:.3f}"),
    ("position_rms_error_m", "position RMS error, slave vs master (m)", "{:.5f}"),
    ("contact_force_max_n", "peak wall force (N)", "{:.3f}"),
    ("packets_sent_forward", "packets sent forward", "{}"),
    ("packets_lost_forward", "packets lost forward", "{}"),
    ("packets_late_forward", "packets late forward", "{}"),
    ("packets_late_by_scheduling_forward", "  of the forward packets, taken late by this machine", "{}"),
    ("packets_sent_backward", "packets sent backward", "{}"),
    ("packets_lost_backward", "packets lost backward", "{}"),
    ("packets_late_backward", "packets late backward", "{}"),
    ("packets_late_by_scheduling_backward", "  of the backward packets, taken late by this machine", "{}"),
    ("loss_rate_forward", "loss rate forward", "{:.4f}"),
    ("loss_rate_backward", "loss rate backward", "{:.4f}"),
    ("delay_forward_p50_s", "network delay forward p50 (s)", "{:.4f}"),
    ("delay_backward_p50_s", "network delay backward p50 (s)", "{:.4f}"),
    ("buffering_delay_forward_mean_s", "buffering delay forward mean (s)", "{:.4f}"),
    ("buffering_delay_backward_mean_s", "buffering delay backward mean (s)", "{:.4f}"),
    ("wire_bits_per_s_forward", "bits/s on the wire forward", "{:.0f}"),
    # seed 000's transparency analysis of a contact run (docs/transparency.md): predicted, measured
    ("transparency_regime", "transparency regime", "{}"),
    ("force_slope_predicted_n_per_s", "force slope in contact, predicted (N/s)", "{:.4f}"),
    ("force_slope_measured_n_per_s", "force slope in contact, measured (N/s)", "{:.4f}"),
    ("force_drop_predicted_n", "force drop for the delay, predicted (N)", "{:.4f}"),
    ("force_drop_measured_n", "force drop for the delay, measured (N)", "{:.4f}"),
    ("transparent_loss_time_predicted_s", "transparent loss time, predicted (s)", "{:.3f}"),
    ("transparent_loss_time_measured_s", "transparent loss time, measured (s)", "{:.3f}"),
    ("allowed_force_error_n", "required force error E (N)", "{:.4g}"),
    ("allowable_delay_s", "allowable delay each way, for E (s)", "{:.4g}"),
    ("allowable_loss_time_s", "allowable loss time, for E (s)", "{:.4g}"),
    ("force_rms_error_vs_reference_n", "force RMS error vs undisturbed run (N)", "{:.4f}"),
    ("force_peak_error_vs_reference_n", "force peak error vs undisturbed run (N)", "{:.4f}"),
    ("master_energy_margin_min_j", "master energy margin min (J)", "{:.4g}"),
    ("slave_energy_margin_min_j", "slave energy margin min (J)", "{:.4g}"),
    ("two_port_energy_margin_min_j", "two-port energy margin min (J)", "{:.4g}"),
)
# Lines printed only when the count is not 0 (a live run's packets taken late by the machine).
SHOWN_IF_ANY = ("packets_late_by_scheduling_forward", "packets_late_by_scheduling_backward")


# A margin below 0 by no more than this is rounding in its sums (a port that gave nothing: -8e-35 J), not a warning.
ROUNDING_J = 1e-9


def format_summary(summary: dict[str, Any]) -> str:
    if summary.get("kind") == "nve":
        from haptic_teleop.analysis.nve_summary import format_nve_summary

        return format_nve_summary(summary)
    lines = [
        f"scene {summary.get('scene')}  seed {summary.get('seed')}  {summary.get('duration_s', 0):.3f} s"
        + ("  (interrupted)" if summary.get("interrupted") else "")
    ]
    width = max(len(label) for _, label, _ in ROWS)
    for key, label, fmt in ROWS:
        if key not in summary or (key in SHOWN_IF_ANY and not summary[key]):
            continue
        v = summary[key]
        text = "n/a" if isinstance(v, float) and math.isnan(v) else fmt.format(v)
        lines.append(f"  {label:<{width}}  {text}")
    unmodelled = summary.get("transparency_unmodelled_effects")
    if unmodelled:  # the predictions are for a constant delay; the measured values include these
        lines.append(f"  {'predictions do not model':<{width}}  {', '.join(unmodelled)}")
    for side in ("master", "slave"):  # a hardware side's ledger: the torque its device reported
        topic = summary.get(f"{side}_energy_torque_topic")
        if isinstance(topic, str) and topic.endswith("/measured_effort"):
            what = "the torque the device reported"
            unmeasured = summary.get(f"{side}_unmeasured_torque_reads")
            if unmeasured:  # reads without a report: the command stood in (docs/hardware_plant.md)
                what += f"; {unmeasured} reads without a report hold the command"
            lines.append(f"  {f'{side} energy booked on':<{width}}  {topic} ({what})")
    for side in ("master", "slave"):
        v = summary.get(f"{side}_energy_margin_min_j")
        if isinstance(v, float) and v < -ROUNDING_J:
            lines.append(f"  WARNING: the {side} port was not passive (margin {v:.4g} J < 0)")
    return "\n".join(lines)
