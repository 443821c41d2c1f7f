"""`haptic-teleop identify SCENE --side master|slave`: excite an arm's joints, estimate their
viscous and Coulomb friction, print the largest damping EBA may assume for each, write it into
the scene (docs/identify.md).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from haptic_teleop import interrupt
from haptic_teleop.core.friction import Z_DEFAULT, Excitation
from haptic_teleop.errors import HapticTeleopError, InputError
from haptic_teleop.plants.base import BACKENDS, backend

if TYPE_CHECKING:
    import numpy as np

    from haptic_teleop.engine.excitation import IdentifyResult
    from haptic_teleop.plants.hardware import JointDriver
    from haptic_teleop.scene.schema import LoadedScene, Scene

SIDES = ("master", "slave")
POINT_SITES = {"master": "handle", "slave": "tool"}
# A simulated plant reports its velocity with this much white noise (rad/s) unless told otherwise:
# a sensor's, so the estimate's interval has something to be honest about (docs/identify.md).
SIM_VELOCITY_NOISE_RAD_PER_S = 0.01

EXIT_OK = 0
EXIT_FAILURE = 1


@dataclass
class Truth:
    """A simulated plant's true friction per joint (driver order), to compare the estimate with."""

    damping_nm_s_per_rad: np.ndarray
    coulomb_nm: np.ndarray


def joint_driver_for(
    config: Scene, side: str, seed: int, velocity_noise_rad_per_s: float = SIM_VELOCITY_NOISE_RAD_PER_S
) -> tuple[JointDriver, Truth | None]:
    """The joint driver of a scene's side, and the true friction when the plant is simulated.

    `backend: mujoco`: the simulated arm (plants/sim_driver.py) on the side's model, joints, start
    pose, torque limits and damping, with the model's dry friction, its velocity reported with
    white noise (seeded). A real backend that `identify` can excite (plants/base.py): the side's
    device through its backend's driver (the run's), returned with None (the truth is unknown).
    """
    cfg = getattr(config, side)
    b = backend(cfg.backend)
    if not b.identify:
        allowed = ", ".join(name for name, x in BACKENDS.items() if x.identify)
        raise InputError(
            f"identify on {side}.backend {cfg.backend!r} is not available; allowed: {allowed} (the excitation adds "
            "gravity compensation, which this backend's controller does itself)"
        )
    if b.real:
        # The side's device as the run would drive it (its backend's driver: for servos their ids,
        # models, signs, offsets, Current Limit at the joint's torque limit); its friction is unknown.
        from haptic_teleop.plants.hardware import ArmDriver
        from haptic_teleop.plants.kinematics import ArmKinematics
        from haptic_teleop.scene.sides import side_period_s

        kin = ArmKinematics(cfg.model, cfg.joints, POINT_SITES[side])
        arm = b.make_arm_driver(cfg.hardware, kin, cfg.torque_limit_nm, side_period_s(config, side))
        assert isinstance(arm, ArmDriver)
        return arm.driver, None
    import numpy as np

    from haptic_teleop.plants.sim_driver import MujocoJointDriver
    from haptic_teleop.scene.sides import sim_settings

    driver = MujocoJointDriver(
        cfg.model,
        POINT_SITES[side],
        joints=cfg.joints,
        start_q_rad=cfg.start_q_rad,
        damping_nm_s_per_rad=cfg.damping_nm_s_per_rad,
        torque_limit_nm=cfg.torque_limit_nm,
        sim=sim_settings(config),
        velocity_noise_rad_per_s=velocity_noise_rad_per_s,
        rng=np.random.default_rng([seed, SIDES.index(side), 0x1D]),
    )
    return driver, Truth(driver.true_damping_nm_s_per_rad, driver.true_coulomb_nm)


# ------------------------------------------------------------------------------------ output


def format_table(result: IdentifyResult, truth: Truth | None, joints: tuple[str, ...]) -> str:
    """One row per identified joint: b with its standard error, c with its standard error, the
    safe EBA damping, the samples used; for a simulated plant the true values and the errors in %."""
    head = ["joint", "b [N m s/rad]", "c [N m]", "safe b for EBA", "samples"]
    if truth is not None:
        head += ["true b", "b err %", "true c", "c err %"]
    rows = [head]
    notes = []
    for ji in result.joints:
        f = ji.fit
        if f is None:
            rows.append([ji.joint, "-", "-", "-", str(len(ji.velocity_rad_per_s))] + (["-"] * 4 if truth else []))
            notes.append(f"{ji.joint}: no fit: {ji.error}")
            continue
        row = [
            ji.joint,
            f"{f.viscous_nm_s_per_rad:.5g} ± {f.se_viscous:.2g}",
            f"{f.coulomb_nm:.5g} ± {f.se_coulomb:.2g}",
            f"{f.safe_damping_nm_s_per_rad:.5g}",
            f"{f.n}" + (f" ({ji.rejected_windows} rejected)" if ji.rejected_windows else ""),
        ]
        if truth is not None:
            k = joints.index(ji.joint)
            b, c = float(truth.damping_nm_s_per_rad[k]), float(truth.coulomb_nm[k])
            row += [f"{b:.5g}", _err(f.viscous_nm_s_per_rad, b), f"{c:.5g}", _err(f.coulomb_nm, c)]
        rows.append(row)
        if ji.dropped_speeds_rad_per_s:
            speeds = ", ".join(f"{s:g}" for s in ji.dropped_speeds_rad_per_s)
            notes.append(f"{ji.joint}: speeds left out (no room in the joint's range): {speeds} rad/s")
        if ji.rejected_by:
            notes.append(f"{ji.joint}: windows rejected: " + "; ".join(f"{n} {_REASON[r]}" for r, n in ji.rejected_by))
        if ji.narrowed and ji.range_rad is not None:
            lo, hi = ji.range_rad
            notes.append(
                f"{ji.joint}: an obstacle stopped the joint; its passes were planned in [{lo:.3f}, {hi:.3f}] rad "
                "(clear it or move the other joints' start positions to use the whole range)"
            )
    widths = [max(len(r[i]) for r in rows) for i in range(len(head))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    z = next((ji.fit.z for ji in result.joints if ji.fit is not None), Z_DEFAULT)
    lines.append(f"safe b = max(0, b - {z:g} se): the largest damping EBA may assume (c is not used by EBA)")
    return "\n".join(lines + notes)


_REASON = {
    "blocked": "blocked (the joint stalled against an obstacle; the passes were re-planned short of it)",
    "guard": "guard (braked at the range's end: widen the range or lower the speeds)",
    "clamp": "clamp (torque at its clamp: raise torque_fraction, lower the speeds, check the gravity model)",
    "stale": "stale (repeated reads: check the bus, baud rate and the USB latency timer)",
    "speed": "speed (speed not held within 20 %: raise the velocity bandwidth or torque_fraction)",
    "unsteady": "unsteady (speed drifted > 20 % across the window: the loop still settling or the joint meeting "
    "resistance)",
    "no room": "no room (no pass fitted where the joint stood)",
}


def _err(estimate: float, true: float) -> str:
    if true == 0.0:
        return f"{estimate:+.2g} N m"
    return f"{100.0 * (estimate / true - 1.0):+.2f}"


def write_plot(path: Path, result: IdentifyResult, truth: Truth | None, joints: tuple[str, ...], title: str) -> None:
    """Friction torque against velocity, one panel per joint: the samples, the fit, the damping
    EBA may assume (a line through 0), and for a simulated plant the true friction."""
    import numpy as np
    from matplotlib.figure import Figure

    done = [ji for ji in result.joints if ji.velocity_rad_per_s]
    n = max(1, len(done))
    fig = Figure(figsize=(4.2 * n, 3.8), layout="constrained")
    axes = fig.subplots(1, n, squeeze=False)[0]
    for ax, ji in zip(axes, done, strict=False):
        v = np.asarray(ji.velocity_rad_per_s)
        tau = np.asarray(ji.friction_nm)
        ax.axhline(0.0, color="0.8", lw=0.8)
        ax.axvline(0.0, color="0.8", lw=0.8)
        vmax = float(np.max(np.abs(v))) * 1.1
        grid = np.linspace(-vmax, vmax, 401)
        grid = grid[grid != 0.0]
        neg, pos = grid[grid < 0.0], grid[grid > 0.0]
        f = ji.fit
        if truth is not None:
            k = joints.index(ji.joint)
            b, c = float(truth.damping_nm_s_per_rad[k]), float(truth.coulomb_nm[k])
            for part in (neg, pos):
                ax.plot(part, b * part + c * np.sign(part), color="0.5", lw=3, alpha=0.5, label=None)
            ax.plot([], [], color="0.5", lw=3, alpha=0.5, label=f"true: b {b:.3g}, c {c:.3g}")
        ax.plot(v, tau, "o", ms=4, color="C0", label="samples (one per window)")
        if f is not None:
            for i, part in enumerate((neg, pos)):
                ax.plot(
                    part,
                    f.predict(part),
                    color="C1",
                    lw=1.5,
                    label=None if i else f"fit: b {f.viscous_nm_s_per_rad:.3g}, c {f.coulomb_nm:.3g}",
                )
            sb = f.safe_damping_nm_s_per_rad
            ax.plot(grid, sb * grid, "--", color="C2", lw=1.2, label=f"EBA may assume b = {sb:.3g}")
        ax.set_title(ji.joint)
        ax.set_xlabel("joint velocity [rad/s]")
        ax.set_ylabel("friction torque [N m]")
        ax.legend(fontsize=7, loc="upper left")
        ax.grid(True, alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=110)


def scene_with_damping(
    loaded: LoadedScene,
    path: str,
    overrides: list[str],
    seed: int | None,
    side: str,
    damping: list[float],
    emulate: bool = False,
) -> str:
    """The resolved scene text with `<side>.damping_nm_s_per_rad` set (loaded again: validated;
    `emulate`: a device's address may be missing, as the emulator's is not written)."""
    from haptic_teleop.scene.load import load_scene

    values = ", ".join(repr(float(b)) for b in damping)
    scene = load_scene(
        path, overrides=[*overrides, f"{side}.damping_nm_s_per_rad=[{values}]"], seed=seed, emulate=emulate
    )
    return scene.to_yaml()


# ------------------------------------------------------------------------------------ command


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="arm scene YAML path, or a bundled scene's name (e.g. touch_dynamixel_wall)")
    p.add_argument("--side", required=True, choices=SIDES, help="which arm to identify")
    p.add_argument(
        "--joint", action="append", metavar="NAME", help="identify this joint only (repeatable; default all)"
    )
    p.add_argument("--set", action="append", metavar="KEY.PATH=VALUE", help="override any scene key (repeatable)")
    p.add_argument(
        "--write", metavar="OUT.yaml", help="write the scene with <side>.damping_nm_s_per_rad = the safe values"
    )
    p.add_argument("--plot", metavar="FILE.png", help="friction torque against velocity per joint, with the fit")
    p.add_argument("--seed", type=int, help="override scene.seed (a simulated plant's sensor noise)")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors (no progress bar, no table)")
    p.add_argument(
        "--emulate",
        action="store_true",
        help="identify an emulated arm: an emulator for each side on hardware, from the scene, driven through the "
        "unmodified SDK (as run --emulate; docs/identify.md)",
    )
    p.add_argument(
        "--z", type=float, default=Z_DEFAULT, help=f"confidence bound width in standard errors (default {Z_DEFAULT:g})"
    )
    p.add_argument(
        "--torque-fraction",
        type=float,
        default=Excitation().torque_fraction,
        help="the excitation's torque beyond gravity compensation, as a fraction of each motor's limit (default 0.3)",
    )
    p.add_argument("--speeds", metavar="V1,V2,...", help="pass speeds in rad/s (default 0.2,0.4,0.7,1,1.5)")
    p.add_argument("--repeats", type=int, help="times the speed list is run (default 2)")
    p.add_argument("--offset", action="store_true", help="also fit a constant torque bias (unmodelled gravity error)")


def _excitation(args: argparse.Namespace) -> Excitation:
    kw: dict[str, Any] = {"torque_fraction": args.torque_fraction}
    if args.speeds is not None:
        try:
            kw["speeds_rad_per_s"] = tuple(float(s) for s in args.speeds.split(","))
        except ValueError:
            raise InputError(
                f"--speeds {args.speeds}: allowed: speeds in rad/s separated by commas, e.g. 0.2,0.5,1"
            ) from None
    if args.repeats is not None:
        kw["repeats"] = args.repeats
    try:
        return Excitation(**kw)
    except ValueError as exc:
        raise InputError(f"excitation settings: {exc}") from None


def main(args: argparse.Namespace) -> int:
    from haptic_teleop.scene.load import find_scene, load_scene

    if not (args.z >= 0.0 and math.isfinite(args.z)):
        raise InputError(f"--z {args.z}: allowed: a finite number >= 0 (standard errors)")
    exc = _excitation(args)
    overrides = list(args.set or ())
    path = str(find_scene(args.scene))
    if not args.emulate:
        return _identify(
            args, exc, path, overrides, load_scene(path, overrides=overrides, seed=args.seed, identify=True)
        )
    # --emulate: an emulator per side on hardware, from the scene (assembly/emulation.py), stopped
    # on every way out; the scene --write writes names the user's overrides, not the emulator's port.
    from haptic_teleop.assembly.emulation import emulated

    first = load_scene(path, overrides=overrides, seed=args.seed, identify=True, emulate=True)
    with emulated(first.config) as ports:
        loaded = load_scene(path, overrides=overrides + ports, seed=args.seed, identify=True)
        return _identify(args, exc, path, overrides, loaded)


def _identify(args: argparse.Namespace, exc: Excitation, path: str, overrides: list[str], loaded: LoadedScene) -> int:
    config = loaded.config
    if not config.is_arm:
        raise InputError(
            f"{path}: a one-axis scene; identify needs an arm scene (a model with joints, e.g. touch_dynamixel_wall)"
        )
    if args.write is not None:
        out = Path(args.write)
        if out.is_dir() or not out.parent.is_dir():
            raise InputError(f"--write {args.write}: allowed: a file path in an existing directory")
    if args.plot is not None and not Path(args.plot).parent.is_dir():
        raise InputError(f"--plot {args.plot}: allowed: a file path in an existing directory")
    side = args.side
    from haptic_teleop.engine.excitation import Identifier
    from haptic_teleop.plants.kinematics import ArmKinematics

    driver, truth = joint_driver_for(config, side, config.scene.seed)
    joints = tuple(driver.joints)
    for name in args.joint or ():
        if name not in joints:
            raise InputError(f"--joint {name}: no such joint of the {side}; allowed: {', '.join(joints)}")
    selected = tuple(args.joint) if args.joint else joints
    kin = ArmKinematics(getattr(config, side).model, joints, POINT_SITES[side])

    bar: Any = None
    last = [0, 0]  # ticks shown; whether the second joint was reached

    def progress(p: Any) -> None:
        if p.joint_index == 1 and last[1] == 0:
            last[1] = 1
            interrupt.pause_for_test("second_joint")  # tests: a signal once the first joint is done
        if bar is not None:
            bar.total = max(bar.total, p.ticks)  # repositioning moves the plan did not count
            bar.set_postfix_str(f"{p.joint} pass {p.pass_index + 1}/{p.passes}", refresh=False)
            bar.update(p.ticks - last[0])
            last[0] = p.ticks

    ident = Identifier(
        driver,
        kin,
        config.scene.period_s,
        excitation=exc,
        joints=selected,
        z=args.z,
        offset=args.offset,
        progress=progress,
    )
    if not args.quiet:
        from tqdm import tqdm

        bar = tqdm(
            total=ident.total_ticks,
            unit="tick",
            unit_scale=True,
            desc=f"identify {side}",
            leave=False,
            file=sys.stderr,
            mininterval=0.2,
        )
    with interrupt.finishing(), contextlib.ExitStack() as stack:
        stack.enter_context(interrupt.on_stop(ident.request_stop))
        try:
            result = ident.run()
        finally:
            if bar is not None:
                bar.close()
    if not args.quiet:
        print(format_table(result, truth, joints))
    if result.interrupted:
        print(
            "haptic-teleop: identify stopped by a signal, torque off; joints not finished are left out"
            + (f", {args.write} not written" if args.write is not None else ""),
            file=sys.stderr,
        )
        return EXIT_OK  # the command exits with the signal's code (cli._main)
    if args.plot is not None:
        write_plot(Path(args.plot), result, truth, joints, f"{config.scene.name}: {side} joint friction")
        if not args.quiet:
            print(f"plot:  {args.plot}")
    failed = [ji.joint for ji in result.joints if ji.fit is None]
    if args.write is not None:
        fits = {ji.joint: ji.fit for ji in result.joints if ji.fit is not None}
        damping = list(kin.damping_nm_s_per_rad())  # the scene's (or the model's) for joints not identified
        given = getattr(config, side).damping_nm_s_per_rad
        if given is not None:
            damping = list(given)
        for name in selected:
            f = fits.get(name)
            if f is None:
                raise HapticTeleopError(f"{args.write} not written: joint {name!r} has no estimate")
            if not f.safe_damping_nm_s_per_rad > 0.0:
                raise HapticTeleopError(
                    f"{args.write} not written: the data do not bound joint {name!r}'s damping above 0 "
                    f"(b = {f.viscous_nm_s_per_rad:.3g} ± {f.se_viscous:.2g}); identify with more --repeats or "
                    "faster --speeds, or set a value by hand"
                )
            damping[joints.index(name)] = f.safe_damping_nm_s_per_rad
        text = scene_with_damping(loaded, path, overrides, args.seed, side, damping, emulate=bool(args.emulate))
        from haptic_teleop.analysis.outputs import write_atomic

        write_atomic(Path(args.write), text)
        if not args.quiet:
            print(f"scene: {args.write} ({side}.damping_nm_s_per_rad = the safe values)")
    if failed:
        return EXIT_FAILURE
    return EXIT_OK
