"""`haptic-teleop bench codec`: what each codec of the codec stage costs per sample (docs/codec_cost.md).

Each case drives one stream the way a channel does at 1 kHz, with nothing lost in between: per
tick the encoder's `send`, every packet straight into the decoder's `receive` (an ARQ
acknowledgement straight back into the encoder's `feedback`), and one decoder `sample`. The signal
is a smooth hand-like motion (sum of sinusoids, fixed seed) in 1 or 3 axes. The figure is this
process's CPU time per sample (least and median of `--repeat` runs), and the same against a bare
reference measured in the same run: one tick of the Python loop and of the compiled loop on the
bench scene (no recording). A channel codes two streams per tick (forward and backward), so the
codec's share of a tick is twice its cost per sample over the tick's.

First, the codec stage in the loop itself: the real-time factor of the compiled and the Python
loop on the scene with each compiled codec (deadband, prediction, FEC, ARQ, HLI; `LOOP_CASES`) named on both
directions, against the same loop without a codec, measured in the same run (best of at least 5,
interleaved). Issue 13's budget: within 10 % of the codec-less run. The same for an arm scene
(`--arm-scene`, default touch_ur5e_wall) in the compiled arm loop (`ARM_LOOP_CASES`).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from haptic_teleop.studies.benchmarks import add_scene_argument, positive

HELP = "what each codec costs per sample against a bare tick, and in the loop (real-time factor with and without)"
PERIOD_NS = 1_000_000


def _signal(samples: int, dim: int, seed: int = 1) -> list[tuple[float, ...]]:
    """A smooth hand-like motion: three sinusoids per axis, amplitudes of centimetres."""
    rng = np.random.default_rng(seed)
    t = np.arange(samples) * PERIOD_NS * 1e-9
    out = np.zeros((samples, dim))
    for a in range(dim):
        for _ in range(3):
            f = rng.uniform(0.2, 3.0)
            out[:, a] += rng.uniform(0.002, 0.02) * np.sin(2 * math.pi * f * t + rng.uniform(0, 2 * math.pi))
    return [tuple(row) for row in out.tolist()]


def _codecs(dim: int) -> list[tuple[str, Callable[[], tuple[Any, Any]]]]:
    from haptic_teleop.core.arq import ArqConfig, build_arq
    from haptic_teleop.core.deadband import DeadbandConfig, build_deadband
    from haptic_teleop.core.fec import FecConfig, build_fec
    from haptic_teleop.core.hli_codec import HliConfig, build_hli_codec
    from haptic_teleop.core.prediction import PredictionConfig, build_prediction

    size = 100 + 16 * dim  # about a JointState's; the cost does not depend on it

    def deadband(**kw: Any) -> Callable[[], tuple[Any, Any]]:
        return lambda: tuple(build_deadband(DeadbandConfig(**kw), dim, PERIOD_NS, size))

    return [
        ("deadband 10 %, hold", deadband(deadband=0.1)),
        ("deadband 10 %, extrapolate", deadband(deadband=0.1, reconstruction="extrapolate")),
        ("hli, 20 % Gilbert (bursts of 2)", lambda: build_hli_codec(HliConfig(p=0.125, r=0.5), PERIOD_NS, dim)),
        ("prediction", lambda: build_prediction(PredictionConfig(), PERIOD_NS)),
        ("fec repetition k = 2", lambda: build_fec(FecConfig(scheme="repetition", k=2), PERIOD_NS)),
        ("fec parity k = 4", lambda: build_fec(FecConfig(scheme="parity", k=4), PERIOD_NS)),
        ("arq 25 ms, 4 retries", lambda: build_arq(ArqConfig(timeout_s=0.025, max_retransmissions=4), PERIOD_NS)),
    ]


def per_sample_us(make: Callable[[], tuple[Any, Any]], signal: list[tuple[float, ...]], repeat: int) -> list[float]:
    """CPU time per sample (us) of encoder -> decoder -> sample, lossless and immediate."""
    out = []
    for _ in range(repeat):
        enc, dec = make()
        send, receive, sample, feedback = enc.send, dec.receive, dec.sample, enc.feedback
        t0 = time.process_time()
        for n, x in enumerate(signal):
            now = n * PERIOD_NS
            for p in send(n, now, x):
                for ack in receive(p, now):
                    feedback(ack, now)
            sample(n, now)
        out.append((time.process_time() - t0) / len(signal) * 1e6)
    return out


def tick_us(scene_name: str, loop: str, seconds: float, repeat: int) -> list[float]:
    """CPU time per tick (us) of the engine's `loop` on the scene, nothing recorded."""
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.scene.load import find_scene, load_scene

    out = []
    scene = load_scene(find_scene(scene_name), overrides=[f"scene.duration_s={seconds}"])
    for _ in range(repeat + (1 if loop == "compiled" else 0)):  # the first compiled run may compile
        engine = Engine(scene, loop=loop)
        t0 = time.process_time()
        engine.run(handle_sigint=False)
        out.append((time.process_time() - t0) / engine.ticks * 1e6)
    return out[-repeat:]


# The codec stage in the loop: each case names the same codec on both directions of the scene
# (a name ending in a key of LOSSES: with that loss on both links, its reference the same lossy
# run without a codec; HLI needs a Gilbert model, its N_HLI1 comes from it).
LOSSY = ", 10 % loss"
GILBERT = ", Gilbert 20 % loss"
LOSSES = {
    LOSSY: "{probability: 0.1}",
    GILBERT: "{model: gilbert_elliott, p: 0.125, r: 0.5, one_minus_h: 1.0, one_minus_k: 0.0}",
}


# Seed 000's error-control experiment's network (docs/codec_error_control.md): 5 ms each way, a
# round trip of 10 ms, under its ARQ's timeout of 25 ms, so ARQ retransmits only what was lost (on
# the scene's own 50 ms each way, mu = 25 ms sends every sample 4 times). A name with this before
# its loss suffix runs with this delay on both links, its reference the codec-less run with it.
SEED_NET = ", 5 ms each way"
SEED_DELAY = "{delay_s: 0.005}"
# The scene's 50 ms each way with 4 ms of normal jitter (packets overtake each other): a deadband's
# link runs it in the kernel; the codec-less reference ticks its schedule in Python
# (axis_host.TickedSchedule), so these rows are also set against the plain codec-less run.
JITTER = ", 4 ms jitter"
JITTER_DELAY = "{delay_s: 0.05, jitter_s: 0.004}"


def _loss_of(name: str) -> str | None:
    return next((s for s in LOSSES if name.endswith(s)), None)


def _network_overrides(name: str, directions: tuple[str, ...] = ("forward", "backward")) -> list[str]:
    """The case's network on `directions`: the seed's delay and the loss its name ends with."""
    over = []
    loss = _loss_of(name)
    for d in directions:
        if SEED_NET in name:
            over.append(f"network.{d}.effects.delay={SEED_DELAY}")
        if JITTER in name:
            over.append(f"network.{d}.effects.delay={JITTER_DELAY}")
        if loss is not None:
            over.append(f"network.{d}.effects.loss={LOSSES[loss]}")
    return over


def _reference(name: str) -> str:
    """The codec-less case a case is set against: the same network."""
    net = "".join(n for n in (SEED_NET, JITTER) if n in name)
    return "no codec" + net + (_loss_of(name) or "")


LOOP_CASES: tuple[tuple[str, str | None], ...] = (
    ("no codec", None),
    ("deadband 10 %, hold", "{kind: deadband, deadband: 0.1}"),
    ("deadband 10 %, extrapolate (sent rate)", "{kind: deadband, deadband: 0.1, reconstruction: extrapolate}"),
    (
        "deadband 10 %, extrapolate (last two)",
        "{kind: deadband, deadband: 0.1, reconstruction: extrapolate, extrapolate_from: last_two}",
    ),
    ("deadband 5 %, adaptive, floor", "{kind: deadband, deadband: 0.05, adaptive_gain: 10, min_threshold: 0.001}"),
    ("prediction", "{kind: prediction}"),
    ("fec repetition k = 2", "{kind: fec, scheme: repetition, k: 2}"),
    ("fec parity k = 4", "{kind: fec, scheme: parity, k: 4}"),
    ("arq 25 ms, 4 retries", "{kind: arq, timeout_s: 0.025, max_retransmissions: 4}"),
    ("arq 4 ms, 1 retry", "{kind: arq, timeout_s: 0.004, max_retransmissions: 1}"),
    # mu above the scene's 100 ms round trip: each sample sent once; an ACK per packet, or a
    # cumulative one at most every 4 ticks (ack_every_ticks)
    ("arq mu = 150 ms, nu = 4", "{kind: arq, timeout_s: 0.15, max_retransmissions: 4}"),
    (
        "arq mu = 150 ms, nu = 4, ACK every 4 ticks",
        "{kind: arq, timeout_s: 0.15, max_retransmissions: 4, ack_every_ticks: 4}",
    ),
    # over 10 % loss each way (the FEC decoder recovers): against the same lossy run without a codec
    ("no codec" + LOSSY, None),
    ("fec repetition k = 2" + LOSSY, "{kind: fec, scheme: repetition, k: 2}"),
    ("fec parity k = 3, wait 3" + LOSSY, "{kind: fec, scheme: parity, k: 3, wait_ticks: 3}"),
    ("arq 25 ms, 4 retries" + LOSSY, "{kind: arq, timeout_s: 0.025, max_retransmissions: 4}"),
    ("arq mu = 150 ms, nu = 4" + LOSSY, "{kind: arq, timeout_s: 0.15, max_retransmissions: 4}"),
    (
        "arq mu = 150 ms, nu = 4, ACK every 4 ticks" + LOSSY,
        "{kind: arq, timeout_s: 0.15, max_retransmissions: 4, ack_every_ticks: 4}",
    ),
    # ARQ as seed 000's experiment sets it (mu = 25 ms, nu = 4) on that experiment's network
    ("no codec" + SEED_NET, None),
    ("arq 25 ms, 4 retries" + SEED_NET, "{kind: arq, timeout_s: 0.025, max_retransmissions: 4}"),
    ("arq 4 ms, 1 retry" + SEED_NET, "{kind: arq, timeout_s: 0.004, max_retransmissions: 1}"),
    ("no codec" + SEED_NET + LOSSY, None),
    ("arq 25 ms, 4 retries" + SEED_NET + LOSSY, "{kind: arq, timeout_s: 0.025, max_retransmissions: 4}"),
    ("no codec" + JITTER, None),
    ("deadband 10 %, hold" + JITTER, "{kind: deadband, deadband: 0.1}"),
    ("deadband 10 %, extrapolate (sent rate)" + JITTER, "{kind: deadband, deadband: 0.1, reconstruction: extrapolate}"),
    ("no codec" + GILBERT, None),
    ("hli (defaults)" + GILBERT, "{kind: hli}"),
    ("hli, hold, 1 Mbit/s" + GILBERT, "{kind: hli, predictor: hold, allowed_bandwidth_bps: 1000000}"),
)


def loop_rtf(
    scene_name: str, seconds: float, repeat: int
) -> tuple[dict[str, dict[str, float]], dict[str, dict[str, list[float]]]]:
    """Real-time factor (scene time over this process's CPU time of the run, nothing recorded) of
    each `LOOP_CASES` case in each loop: the largest of `repeat` runs, and every run's by round
    (a round runs each case once: the cases' runs are interleaved so that a slow minute of the
    machine hits them alike, and a ratio taken within a round compares runs a second apart)."""
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.scene.load import find_scene, load_scene

    out: dict[str, dict[str, float]] = {"compiled": {}, "python": {}}
    rounds: dict[str, dict[str, list[float]]] = {"compiled": {}, "python": {}}
    scenes = {}
    for name, codec in LOOP_CASES:
        over = [f"scene.duration_s={seconds}"]
        if codec is not None:
            over += [f"network.forward.codec={codec}", f"network.backward.codec={codec}"]
        over += _network_overrides(name)
        scenes[name] = load_scene(find_scene(scene_name), overrides=over)
    for loop in ("compiled", "python"):
        for scene in scenes.values():  # compile (or load numba's cache) before the timed runs
            Engine(scene, loop=loop)
        for _ in range(repeat):
            for name, scene in scenes.items():
                engine = Engine(scene, loop=loop)
                assert engine.loop_kind == loop  # `Engine(loop="compiled")` refuses with one line otherwise
                t0 = time.process_time()
                engine.run(handle_sigint=False)
                rtf = engine.ticks * engine.period_s / (time.process_time() - t0)
                out[loop][name] = max(out[loop].get(name, 0.0), rtf)
                rounds[loop].setdefault(name, []).append(rtf)
    return out, rounds


def paired_ratios(rounds: dict[str, list[float]], name: str) -> list[float]:
    """Each round's RTF of case `name` over its reference's in the same round (`_reference`)."""
    return [a / b for a, b in zip(rounds[name], rounds[_reference(name)], strict=True)]


# The codec stage in the compiled arm loop (engine/compiled/arm_codec_kernel.py): the same cases on both
# directions of an arm scene, against the compiled arm loop without one (engine/compiled/arm_kernel.py),
# each case's reference as in LOOP_CASES (`_reference`).
ARM_LOOP_CASES = LOOP_CASES


def arm_loop_rtf(scene_name: str, seconds: float, repeat: int) -> dict[str, float]:
    """Real-time factor (scene time over this process's CPU time, nothing recorded) of the arm
    scene in the compiled arm loop for each `ARM_LOOP_CASES` case, the largest of `repeat` runs
    (the least CPU time), the cases interleaved."""
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.scene.load import find_scene, load_scene

    scenes = {}
    for name, codec in ARM_LOOP_CASES:
        over = [f"scene.duration_s={seconds}"]
        if codec is not None:
            over += [f"network.forward.codec={codec}", f"network.backward.codec={codec}"]
        over += _network_overrides(name)
        scenes[name] = load_scene(find_scene(scene_name), overrides=over)
    for scene in scenes.values():  # compile (or load numba's cache) before the timed runs
        Engine(scene, loop="compiled").close_plants()
    out: dict[str, float] = {}
    for _ in range(repeat):
        for name, scene in scenes.items():
            engine = Engine(scene, loop="compiled")  # refuses with one line if it cannot
            t0 = time.process_time()
            engine.run(handle_sigint=False)
            rtf = engine.ticks * engine.period_s / (time.process_time() - t0)
            out[name] = max(out.get(name, 0.0), rtf)
    return out


def compiled_codec_ns(scene_name: str, samples: int, repeat: int) -> dict[str, float]:
    """ns per tick of one direction's compiled codec stage alone (engine/codec_kernel.codec_ticks:
    encoder, link, decoder; the backward direction, 3 values a sample, the scene's link), least
    of `repeat` runs over the bench's smooth signal."""
    from haptic_teleop.engine.compiled import codec_kernel
    from haptic_teleop.engine.compiled.codec_host import CodecNet
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.scene.load import find_scene, load_scene

    signal = np.array(_signal(samples, 3))
    out: dict[str, float] = {}
    for name, codec in LOOP_CASES:
        loss = _loss_of(name)
        if codec is None or (loss is not None and "hli" not in codec):
            continue
        over = [f"network.backward.codec={codec}", *_network_overrides(name, ("backward",))]
        if SEED_NET in name:  # and on the link of its ACKs
            over.append(f"network.forward.effects.delay={SEED_DELAY}")
        scene = load_scene(find_scene(scene_name), overrides=over)
        engine = Engine(scene, loop="python")  # only for its codec channel
        ch = engine.codecs[1]
        assert ch is not None
        best = math.inf
        for _ in range(repeat + 1):  # the first may compile
            net = CodecNet(ch, engine.period_ns)  # reads the channel's settings; a fresh state
            net.ready(samples)
            t0 = time.process_time()
            codec_kernel.codec_ticks(*net.args(), signal, engine.period_ns, np.zeros((3, 3)), *net.history())
            best = min(best, time.process_time() - t0)
        out[name] = best / samples * 1e9
        engine.master.close()
        engine.slave.close()
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scene_argument(p, help="the scene whose tick is the reference (default wall_contact)")
    p.add_argument("--samples", type=positive(int), default=20_000, help="samples per case (default 20000)")
    p.add_argument("--repeat", type=positive(int), default=3, help="runs per case (default 3)")
    p.add_argument("--seconds", type=positive(float), default=5.0, help="simulated seconds of the reference ticks")
    p.add_argument("--arm-scene", default="touch_ur5e_wall", help="the arm scene of the arm loop's figure")
    p.add_argument("--arm-seconds", type=positive(float), default=10.0, help="simulated seconds of each arm run")


def main(args: argparse.Namespace) -> int:
    rtf, rounds = loop_rtf(args.scene, args.seconds, max(args.repeat, 5))
    print(
        f"the codec stage in the loop ({args.scene}, the codec on both directions, {args.seconds:g} s, "
        f"no recording; real-time factor, best of {max(args.repeat, 5)}; 'paired': the median and range "
        "of each round's ratio to the reference run a second apart):"
    )
    w = max(len(name) for name, _ in LOOP_CASES)
    # ('/ plain': against the codec-less run without network effects besides the delay, for the
    # rows whose own reference ticks its schedule in Python: Gilbert loss, jitter)
    head = (
        f"{'case':{w}s} {'compiled RTF':>12s} {'/ no codec':>10s} {'paired':>19s} {'/ plain':>8s} "
        f"{'Python RTF':>10s} {'/ no codec':>10s}"
    )
    print(head)
    print("-" * len(head))
    for name, _ in LOOP_CASES:
        c, p = rtf["compiled"][name], rtf["python"][name]
        ref = _reference(name)
        c0, p0 = rtf["compiled"][ref], rtf["python"][ref]
        pr = paired_ratios(rounds["compiled"], name)
        paired = f"{statistics.median(pr):.3f} ({min(pr):.2f}-{max(pr):.2f})"
        plain = c / rtf["compiled"]["no codec"]
        print(f"{name:{w}s} {c:12.0f} {c / c0:10.3f} {paired:>19s} {plain:8.3f} {p:10.1f} {p / p0:10.3f}")
    print()
    reps = max(args.repeat, 5)
    arm = arm_loop_rtf(args.arm_scene, args.arm_seconds, reps)
    print(
        f"the codec stage in the compiled arm loop ({args.arm_scene}, the codec on both directions, "
        f"{args.arm_seconds:g} s, no recording; real-time factor, best of {reps}):"
    )
    wa = max(len(name) for name, _ in ARM_LOOP_CASES)
    # (and against the lossless codec-less run: a codec-less run with Gilbert loss ticks its
    # schedule in Python, axis_host.TickedSchedule, a codec direction runs its link in the kernel)
    head = f"{'case':{wa}s} {'compiled RTF':>12s} {'/ no codec':>10s} {'/ lossless no codec':>19s}"
    print(head)
    print("-" * len(head))
    for name, _ in ARM_LOOP_CASES:
        ref = arm[_reference(name)]
        print(f"{name:{wa}s} {arm[name]:12.1f} {arm[name] / ref:10.3f} {arm[name] / arm['no codec']:19.3f}")
    print()
    ns = compiled_codec_ns(args.scene, args.samples, reps)
    print(f"one direction's compiled codec stage alone (3 values a sample, the scene's link; least of {reps}):")
    for name, value in ns.items():
        print(f"  {name:{w}s} {value:6.1f} ns per tick")
    print()
    ref = {loop: tick_us(args.scene, loop, args.seconds, args.repeat) for loop in ("python", "compiled")}
    py, comp = min(ref["python"]), min(ref["compiled"])
    print(
        f"reference tick ({args.scene}, no recording): Python loop {py:.2f} us, "
        f"compiled loop {comp:.2f} us (least of {args.repeat})"
    )
    print()
    head = (
        f"{'codec':34s} {'dim':>3s} {'us/sample':>17s} {'2 streams / Python tick':>24s} "
        f"{'2 streams / compiled tick':>26s}"
    )
    print(head)
    print("-" * len(head))
    for dim in (1, 3):
        signal = _signal(args.samples, dim)
        for name, make in _codecs(dim):
            times = per_sample_us(make, signal, args.repeat)
            least, med = min(times), statistics.median(times)
            print(f"{name:34s} {dim:3d} {least:7.2f} ({med:6.2f} med) {2 * least / py:23.0%} {2 * least / comp:25.0%}")
    return 0
