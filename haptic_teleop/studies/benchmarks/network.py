"""`haptic-teleop bench network`: what the network relay and the playout buffer cost per packet.

Each case drives one direction as the engine does at 1 kHz: build the `Packet`, `link.send`,
`link.deliver(now)`, `buffer.push` for every arrival and one `buffer.release(now)` per tick. The
figure is this process's CPU time per packet sent (least and median of `--repeat` runs). The last part runs the default
scene with every effect on in both directions against no effects at all (real-time factor of the
loop alone and of loop + bag recording).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from haptic_teleop.studies.benchmarks import add_scene_argument, positive

PERIOD_NS = 1_000_000
DELAY = {"delay_s": 0.05}
JITTER = {"delay_s": 0.05, "jitter_s": 0.005, "distribution": "normal"}
# One effect at a time (reorder needs a delay, so it runs on the constant delay), then all together.
EFFECT_CASES: tuple[tuple[str, dict[str, Any]], ...] = (
    ("no effects", {}),
    ("blackout (1 s window in 10 s)", {"blackout": {"starts_s": [3.0], "ends_s": [4.0]}}),
    ("rate limit 2 Mbit/s (no drops)", {"rate_limit": {"rate_bps": 2e6}}),
    ("rate limit 400 kbit/s, queue 50 (drops)", {"rate_limit": {"rate_bps": 4e5, "queue_limit_packets": 50}}),
    ("loss bernoulli 5 %", {"loss": {"probability": 0.05}}),
    (
        "loss gilbert-elliott",
        {"loss": {"model": "gilbert_elliott", "p": 0.01, "r": 0.25, "one_minus_h": 0.7, "one_minus_k": 0.001}},
    ),
    ("loss 4-state", {"loss": {"model": "four_state", "p13": 0.01, "p31": 0.3, "p32": 0.2, "p23": 0.4, "p14": 0.02}}),
    ("duplicate 1 %", {"duplicate": {"probability": 0.01}}),
    ("corrupt 1 %", {"corrupt": {"probability": 0.01}}),
    ("delay 50 ms constant", {"delay": DELAY}),
    ("delay 50 ms + 5 ms normal jitter", {"delay": JITTER}),
    ("delay jitter, correlation 0.25 (netem)", {"delay": {**JITTER, "correlation": 0.25}}),
    (
        "delay jitter, correlation 0.25 (copula)",
        {"delay": {**JITTER, "correlation": 0.25}, "correlation_model": "gaussian_copula"},
    ),
    (
        "delay sinusoid 30..120 ms + jitter",
        {
            "delay": {
                "jitter_s": 0.005,
                "distribution": "normal",
                "sinusoid": {"min_delay_s": 0.03, "max_delay_s": 0.12, "period_s": 4.0},
            }
        },
    ),
    ("reorder 5 % (on 50 ms delay)", {"delay": DELAY, "reorder": {"probability": 0.05}}),
)
ALL_EFFECTS: dict[str, Any] = {
    "blackout": {"starts_s": [3.0], "ends_s": [3.5]},
    "rate_limit": {"rate_bps": 2e6},
    "loss": {"model": "gilbert_elliott", "p": 0.01, "r": 0.25, "one_minus_h": 0.7, "one_minus_k": 0.001},
    "duplicate": {"probability": 0.01},
    "corrupt": {"probability": 0.01},
    "delay": {
        "jitter_s": 0.005,
        "distribution": "normal",
        "sinusoid": {"min_delay_s": 0.03, "max_delay_s": 0.12, "period_s": 4.0},
    },
    "reorder": {"probability": 0.05},
}
POLICY_PARAMS: dict[str, dict[str, Any]] = {
    "none": {},
    "fixed": {"buffering_time_s": 0.01},
    "adaptive": {},
    "percentile": {},
    "transparency": {"force_slope_n_per_s": 10.0},
    "network_adaptive": {"allowable_delay_s": 0.1, "allowable_loss_time_s": 0.02, "min_one_way_delay_s": 0.03},
}


def per_packet_us(
    effects: dict[str, Any], buffer: dict[str, Any], packets: int, repeat: int, seed: int = 1
) -> tuple[float, float]:
    """Least and median CPU time (us) per packet of Packet + send + deliver + push + release at 1 kHz.

    CPU time of this process (`time.process_time`), not wall time: on a shared machine it does not
    count the time other processes hold the core, but sharing the core's caches still slows it,
    so the least of the runs is the figure least disturbed by the neighbours.
    """
    from haptic_teleop.core.link import Packet
    from haptic_teleop.core.netconfig import NetworkEffectsConfig, build_link
    from haptic_teleop.core.playout_config import BufferConfig, build_buffer
    from haptic_teleop.typedconfig import build

    cfg = build(NetworkEffectsConfig, effects, "effects", "bench")
    bcfg = build(BufferConfig, buffer, "buffer", "bench")
    times = []
    payload = (0.01, 0.02, 0.0)
    for _ in range(repeat):
        link = build_link(cfg, seed, "forward")
        buf = build_buffer(bcfg, PERIOD_NS)
        send, deliver, push, release = link.send, link.deliver, buf.push, buf.release
        t0 = time.process_time()
        for n in range(packets):
            now = n * PERIOD_NS
            send(Packet(n, now, payload, 84))
            for p in deliver(now):
                push(p, now)
            release(now)
        times.append((time.process_time() - t0) / packets * 1e6)
    return min(times), statistics.median(times)


def scene_overrides(effects: dict[str, Any] | None, policy: str | None = None) -> list[str]:
    """--set lines that give both directions `effects` (None: no effects) and optionally a policy."""
    import json

    out = []
    for d in ("forward", "backward"):
        out.append(f"network.{d}.effects={json.dumps(effects or {})}")
        if policy is not None:
            out.append(f"network.{d}.buffer.policy={policy}")
    return out


def scene_rtf(cases: list[list[str]], scene_name: str, repeat: int) -> list[tuple[float, float]]:
    """Per case, median real-time factors: loop alone, and loop + bag recording (as `run` measures it).

    The cases take turns within each repeat, so a change in the machine's load hits them alike.
    """
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.engine.run import record_run
    from haptic_teleop.scene.load import find_scene, load_scene

    scenes = [load_scene(find_scene(scene_name), overrides=ov) for ov in cases]
    loop: list[list[float]] = [[] for _ in cases]
    rec: list[list[float]] = [[] for _ in cases]
    for _ in range(repeat):
        for i, scene in enumerate(scenes):
            r = Engine(scene).run(handle_sigint=False)
            loop[i].append(r.ticks * scene.config.scene.period_s / r.loop_wall_s)
            with tempfile.TemporaryDirectory() as tmp:
                _, timing = record_run(scene, Path(tmp) / "bag", handle_sigint=False)
            rec[i].append(timing.realtime_factor)
    return [(statistics.median(a), statistics.median(b)) for a, b in zip(loop, rec, strict=True)]


def bench(
    packets: int, repeat: int, scene_name: str, scene_repeat: int, extra: list[str], only: str | None, scene: bool
) -> int:
    def wanted(label: str) -> bool:
        return only is None or only in label

    print(f"relay + buffer CPU time per packet, 1 kHz, {packets} packets; least / median of {repeat} runs")
    print("\neach effect alone (buffer: none)")
    for label, effects in (*EFFECT_CASES, ("all effects together", {**ALL_EFFECTS})):
        if wanted(label):
            lo, med = per_packet_us(effects, {"policy": "none"}, packets, repeat)
            print(f"  {label:<42} {lo:6.2f} / {med:6.2f} us")
    print("\neach buffer policy (link: 50 ms + 5 ms normal jitter)")
    for policy, params in POLICY_PARAMS.items():
        if wanted(f"policy {policy}"):
            lo, med = per_packet_us({"delay": JITTER}, {"policy": policy, **params}, packets, repeat)
            print(f"  {policy:<42} {lo:6.2f} / {med:6.2f} us")
    if not scene:
        return 0
    print(f"\nscene {scene_name}, median of {scene_repeat}: real-time factor (loop alone / loop + recording)")
    cases = {
        "no effects": scene_overrides(None),
        "every effect, buffer none": scene_overrides(ALL_EFFECTS),
        "every effect, buffer transparency": scene_overrides(ALL_EFFECTS, "transparency"),
    }
    results = scene_rtf([[*extra, *ov] for ov in cases.values()], scene_name, scene_repeat)
    for label, (loop, rec) in zip(cases, results, strict=True):
        print(f"  {label:<42} {loop:6.1f} / {rec:6.1f}")
    return 0


HELP = "network relay and playout buffer cost per packet, and a scene's real-time factor with every effect on"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--packets", type=positive(int), default=100_000, help="packets per case")
    p.add_argument("--repeat", type=positive(int), default=3, help="runs per case; the median is printed")
    add_scene_argument(p, help="scene for the real-time factor")
    p.add_argument("--scene-repeat", type=positive(int), default=3, help="runs of the scene per case")
    p.add_argument("--duration-s", type=positive(float), help="override the scene's duration (default: the scene's)")
    p.add_argument(
        "--only",
        metavar="TEXT",
        help="per-packet cases whose label contains TEXT ('policy NAME' for a buffer), e.g. to run one under perf stat",
    )
    p.add_argument("--no-scene", action="store_true", help="skip the scene's real-time factor")


def main(args: argparse.Namespace) -> int:
    extra = [] if args.duration_s is None else [f"scene.duration_s={args.duration_s}"]
    return bench(args.packets, args.repeat, args.scene, args.scene_repeat, extra, args.only, not args.no_scene)
