"""Seed 000's transparency analysis of a contact run: predicted against measured (docs/transparency.md).

For a one-axis scene of the seed's premise (`operator.profile: imposed` or `slave.start:
in_contact`), or a push toward the wall with an `analysis:` section (`applies`), from the bag
alone (its scene and run facts, its signals), and the undisturbed reference run of the same scene
that the run recorded beside itself when the scene asks for one (`analysis.reference`, by default
for in-contact starts only: no network effects, i.e. no delay, no loss, buffer none, no codec;
engine/reference.py; a bag without it, a live run's, gets `transparency_reference` instead of the
reference keys):

- the felt force's slope in contact, `force_slope_predicted_n_per_s` (s = gamma v_m,
  core/transparency.py) and `_measured_` (a line through |F_m| over the second half of the ramp);
- the force drop for the run's delay against the reference at the ramp's end,
  `force_drop_predicted_n` / `_measured_` (in-contact starts only: the premise the formula is for),
  and the regime the prediction is for, `transparency_regime`;
- the transparent loss time of the longest hold of the master's remote sample during the ramp
  (a loss burst on the backward link), `transparent_loss_time_predicted_s` / `_measured_`;
- the allowable delay and loss time for `analysis.allowed_force_error_n`, `allowable_delay_s`,
  `allowable_loss_time_s`;
- the felt force's error against the reference, `force_rms_error_vs_reference_n`,
  `force_peak_error_vs_reference_n` (the error against the wall force is `force_rms_error_n`).

Predicted/measured pairs share their stem (`<stem>_predicted_<unit>`, `<stem>_measured_<unit>`).
The predictions take each direction's median delay as a constant one; a scene with other network
effects (loss, a blackout, jitter, a codec, ...) lists them in `transparency_unmodelled_effects`:
the measured values include them, the predicted ones do not.
A scene the analysis does not apply to gets no key at all.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from haptic_teleop.core.transparency import (
    ContactModel,
    allowable_delay,
    allowable_loss_time,
    force_drop,
    force_slope,
    force_slope_between,
    transparent_loss_time,
)
from haptic_teleop.scene.contact import contact_model_of, reference_wanted, transparency_applies
from haptic_teleop.scene.schema import Scene
from haptic_teleop.typedconfig import build

DEFAULT_ALLOWED_FORCE_ERROR_N = 0.1  # the stack's choice: seed 000 prints "error < 0.1N" for its HLI simulation only
MIN_WINDOW_TICKS = 20
MIN_HOLD_TICKS = 3  # a hold of the master's remote sample shorter than this is not a loss burst
# The run fact that holds the reference run's |F_m| per tick (engine/reference.py writes it).
REFERENCE_FACT = "reference_master_force_n"


def _ramp(sc: dict[str, Any], period_s: float, n: int) -> tuple[int, int]:
    """Ticks [first, last] of the operator's constant-velocity motion (clipped to the run)."""
    op = sc["operator"]
    start = float(op["start_s"])
    speed = float(op["speed_m_per_s"])
    length = float(op["duration_s"]) if op["profile"] == "imposed" else float(op["distance_m"]) / speed
    first = round(start / period_s)
    last = min(round((start + length) / period_s), n - 1)
    return first, last


def contact_model(config: Scene, run_info: dict[str, Any], speed_m_per_s: float) -> ContactModel:
    """The numbers the predictions use: the scene's contact model (`scene.contact.contact_model_of`,
    the scene as recorded) with the speed measured and the master's damping as the plant had it
    (the run facts), where the bag has them."""
    model = contact_model_of(config)
    if model is None:
        raise ValueError("the transparency analysis needs a one-axis scene whose operator pushes or is imposed")
    damping = run_info.get("master_joint_damping")
    b_m = float(damping[0]) if damping else model.master_physical_damping_n_s_per_m
    return dataclasses.replace(model, speed_m_per_s=speed_m_per_s, master_physical_damping_n_s_per_m=b_m)


def _released_ticks(release_s: np.ndarray, period_s: float) -> np.ndarray:
    return np.unique(np.round(release_s / period_s).astype(np.int64))


def longest_hold(release_s: np.ndarray, period_s: float, first: int, last: int) -> tuple[int, int] | None:
    """The longest hold of the master's remote sample that starts in ticks [first, last): (a, b),
    the ticks of the last release before it and the first after it (b = last + 1 if none came);
    None if no hold is MIN_HOLD_TICKS long."""
    ticks = _released_ticks(release_s, period_s)
    ticks = np.concatenate((ticks, [last + 1]))
    gaps = np.diff(ticks)
    ok = (ticks[:-1] >= first) & (ticks[:-1] < last) & (gaps > MIN_HOLD_TICKS)
    if not np.any(ok):
        return None
    i = int(np.flatnonzero(ok)[np.argmax(gaps[ok])])
    return int(ticks[i]), int(ticks[i + 1])


def rise_ticks(felt: np.ndarray, a: int, b: int) -> int:
    """How many of the held ticks a + 2 .. b (the master runs on the sample released at a from a + 1
    on) the felt force still rises: the ticks before the first that is not above the one before."""
    k = a + 2
    while k <= b and k < len(felt) and felt[k] > felt[k - 1]:
        k += 1
    return k - (a + 2)


def _line_slope(t: np.ndarray, f: np.ndarray) -> float:
    return float(np.polyfit(t, f, 1)[0])


def unmodelled_effects(sc: dict[str, Any]) -> list[str]:
    """The scene's network effects the predictions do not model (they take each direction's median
    delay as a constant one): every effect but a plain delay, a delay that varies, a codec."""
    out = []
    for d in ("forward", "backward"):
        ch = (sc.get("network") or {}).get(d) or {}
        for name, value in sorted((ch.get("effects") or {}).items()):
            if value is None or not isinstance(value, dict):  # absent, or a setting (correlation_model)
                continue
            if name == "delay":
                varying = [
                    k for k in ("jitter_s", "schedule", "sinusoid", "trace") if value.get(k) not in (None, 0, 0.0)
                ]
                if varying:
                    out.append(f"network.{d}.effects.delay ({', '.join(varying)})")
            else:
                out.append(f"network.{d}.effects.{name}")
        if ch.get("codec") is not None:
            out.append(f"network.{d}.codec")
    return out


def transparency_summary(bag: str | Path) -> dict[str, Any]:
    """The transparency keys of a bag's summary.json (module docstring); {} where they do not apply."""
    from haptic_teleop.analysis.metrics import load_signals
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as r:
        sc = yaml.safe_load(r.string("/haptic_teleop/scene"))
        if not r.schema.single_axis:
            return {}
        config = build(Scene, sc, "", "recorded scene")
        if not transparency_applies(config):
            return {}
        desired = np.abs(r.read("/master/eba").field("force_desired_n")) if r.has("/master/eba") else None
    sig = load_signals(bag)
    T = sig.period_s
    n = len(sig.t_s)
    felt = np.abs(sig.master_force_n)
    first, last = _ramp(sc, T, n)
    in_contact = (sc["slave"].get("start") or "free") == "in_contact"
    touching = np.flatnonzero(np.abs(sig.contact_n[first : last + 1]) > 0.0)
    if in_contact:
        onset = first
    elif touching.size:
        onset = first + int(touching[0])
    else:
        return {}
    w0 = onset + (last - onset) // 2
    if last - w0 < MIN_WINDOW_TICKS:
        return {}
    window = slice(w0, last + 1)
    # v_m: the master's mean velocity over the window, from its positions (a hand's push is slower
    # than its intended speed; an imposed one is exact)
    speed = float((sig.master_x_m[last] - sig.master_x_m[w0]) / ((last - w0) * T))
    if not speed > 0.0:
        return {}
    law = str(((sc["controllers"]["master"].get("eba") or {}).get("law")) or "reservoir")
    allowed = float((sc.get("analysis") or {}).get("allowed_force_error_n", DEFAULT_ALLOWED_FORCE_ERROR_N))
    model = contact_model(config, sig.run_info, speed)
    out: dict[str, Any] = {
        "transparency_law": law,
        "transparency_bound_binding": model.binding,
        "allowed_force_error_n": allowed,
        "force_slope_measured_n_per_s": _line_slope(sig.t_s[window], felt[window]),
    }
    out["force_slope_predicted_n_per_s"] = force_slope(model, law)
    # The predictions model a constant delay each way; what else the network did, the measured
    # values hold and the predicted ones do not (docs/transparency.md, "summary.json").
    unmodelled = unmodelled_effects(sc)
    if unmodelled:
        out["transparency_unmodelled_effects"] = unmodelled
    d_f = float(np.median(sig.forward_delays_s)) if sig.forward_delays_s.size else 0.0
    d_b = float(np.median(sig.backward_delays_s)) if sig.backward_delays_s.size else 0.0
    if in_contact:  # over the window, as measured (the delayed force reflection may not be steady yet)
        out["force_slope_predicted_n_per_s"] = force_slope_between(
            model, d_f, d_b, (w0 - first) * T, (last - first) * T, law
        )
        drop = force_drop(model, d_f, d_b, law, at_s=(last - first) * T)
        out["transparency_regime"] = drop.regime
        out["force_drop_predicted_n"] = drop.drop_n
        out["allowable_delay_s"] = allowable_delay(model, allowed, law)
    # The undisturbed reference run, recorded with the run when its scene asks for one
    # (scene.contact.reference_wanted: by default for the seed's in-contact premise only).
    recorded = sig.run_info.get(REFERENCE_FACT) if reference_wanted(config) else None
    if reference_wanted(config) and recorded is None:  # a live run's bag, or one from before
        out["transparency_reference"] = "not recorded in this bag"
    if recorded is not None:
        ref = np.asarray(recorded, dtype=float)
        m = min(len(ref), n)
        err = felt[:m] - ref[:m]
        out["force_rms_error_vs_reference_n"] = float(np.sqrt(np.mean(err * err)))
        out["force_peak_error_vs_reference_n"] = float(np.max(np.abs(err)))
        if in_contact and last < m:
            out["force_drop_measured_n"] = float(ref[last] - felt[last])
    if not in_contact:
        return out
    # The transparent loss time: the longest hold of the master's remote sample during the ramp.
    gap_end = float(desired[last] - felt[last]) if desired is not None else math.nan
    hold = longest_hold(sig.backward_release_s, T, first, last)
    if hold is not None and desired is not None:
        a, b = hold
        held = (b - a - 1) * T
        t_tr = transparent_loss_time(model, float(desired[a + 1] - felt[a + 1]), float(felt[a + 1]), law)
        out["loss_hold_s"] = held
        out["transparent_loss_time_predicted_s"] = min(held, t_tr)
        out["transparent_loss_time_measured_s"] = rise_ticks(felt, a, b) * T
        gap_end = float(desired[a + 1] - felt[a + 1])
    if math.isfinite(gap_end):
        t_tr_end = transparent_loss_time(model, gap_end, float(felt[last]), law)
        out["allowable_loss_time_s"] = allowable_loss_time(model, allowed, t_tr_end, law)
    return out
