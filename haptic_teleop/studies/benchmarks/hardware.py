"""`haptic-teleop bench hardware`: the Dynamixel driver's loop rate against the bus emulator.

One tick is what an arm plant on the driver does: `read()` (one group sync read, or fast sync
read, of Present Current/Velocity/Position of every servo) and `write(tau)` (one group sync write
of Goal Current). The host loop runs free (no sleep) for `--ticks` ticks after a warm-up, against
the emulator in its own process on a pseudo-terminal with wire timing (bytes x 10 / baud), Return
Delay Time 0 and no USB latency, in real time. Cases: 3 servos (the dxl_arm.xml arm in MuJoCo) and
6 servos (the emulator's "inertia" physics), at 1 and 4 Mbps, sync read and fast sync read.

The limit is what the bus can carry (`driver.wire_limit_hz`): 1 / (bytes per tick x 10 / baud),
with bytes per tick = sync write (14 + 3 n) + sync read instruction (14 + n) + replies (21 n for
sync read, 8 + 14 n for fast sync read). Target: the rate within 80 % of the limit. Where the
time goes is printed next to it: the host's CPU time per tick (this process: the SDK building and
parsing packets, the driver's conversions) and the emulator process's CPU time per tick.
Figures only: no test asserts them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.studies.benchmarks import positive

ARM3 = (("base_yaw", "XM540-W270"), ("shoulder", "XM540-W270"), ("elbow", "XM430-W350"))


def _proc_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a process (Linux /proc), None when unreadable."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def bus_dict(n_servos: int, baud_bps: int) -> dict[str, Any]:
    """The emulator's configuration of a case (JSON-ready)."""
    registers = {"return_delay_time": 0}
    if n_servos == 3:
        servos = [
            {"id": k + 1, "model": model, "joint": name, "registers": registers} for k, (name, model) in enumerate(ARM3)
        ]
        physics: dict[str, Any] = {"kind": "mujoco", "model": "dxl_arm.xml"}
    else:
        servos = [
            {"id": k + 1, "model": ARM3[k % 3][1], "joint": f"j{k + 1}", "registers": registers}
            for k in range(n_servos)
        ]
        physics = {
            "kind": "inertia",
            "joints": [
                {"name": f"j{k + 1}", "inertia_kg_m2": 0.02, "viscous_nm_s_per_rad": 0.1, "coulomb_nm": 0.05}
                for k in range(n_servos)
            ],
        }
    return {"servos": servos, "baud_bps": baud_bps, "usb_latency_s": 0.0, "physics": physics}


def run_case(n_servos: int, baud_bps: int, fast: bool, ticks: int, warmup: int, pin: bool = False) -> dict[str, Any]:
    from haptic_teleop.emulators.dynamixel.config import BusConfig
    from haptic_teleop.emulators.dynamixel.process import start_bus
    from haptic_teleop.plants.dynamixel.chain import (
        DynamixelChainConfig,
        DynamixelJoint,
        wire_bytes_per_tick,
        wire_limit_hz,
    )
    from haptic_teleop.plants.dynamixel.driver import DynamixelDriver

    bus_cfg = BusConfig.from_dict(bus_dict(n_servos, baud_bps))
    bus = start_bus(bus_cfg)
    cpus = sorted(os.sched_getaffinity(0))
    if pin and len(cpus) >= 2:  # host and emulator on CPUs of their own: neither preempts the other
        os.sched_setaffinity(0, {cpus[0]})
        os.sched_setaffinity(bus.pid, {cpus[1]})
    try:
        joints = tuple(
            DynamixelJoint(s.joint, s.id, s.model, zero_offset_rad=math.pi, current_limit=200) for s in bus_cfg.servos
        )
        cfg = DynamixelChainConfig(
            bus.port, joints, baud_bps=baud_bps, fast_sync_read=fast, bus_watchdog_s=1.0, read_timeout_s=0.5
        )
        tau = np.zeros(n_servos)
        with DynamixelDriver(cfg) as drv:
            drv.start()
            for _ in range(warmup):
                drv.read()
                drv.write(tau)
            emu_pid = getattr(bus, "pid", None)
            emu0 = _proc_cpu_s(emu_pid) if emu_pid else None
            stale0 = drv.stale_reads
            cpu_read = cpu_write = wall_read = 0.0
            clock, cpu_clock = time.perf_counter, time.process_time
            t0 = clock()
            for _ in range(ticks):
                a, ca = clock(), cpu_clock()
                drv.read()
                b, cb = clock(), cpu_clock()
                drv.write(tau)
                cpu_write += cpu_clock() - cb
                cpu_read += cb - ca
                wall_read += b - a
            wall = clock() - t0
            emu1 = _proc_cpu_s(emu_pid) if emu_pid else None
            stale = drv.stale_reads - stale0
    finally:
        bus.stop()
        if pin:
            os.sched_setaffinity(0, set(cpus))
    limit = wire_limit_hz(n_servos, baud_bps, fast)
    rate = ticks / wall
    return {
        "servos": n_servos,
        "baud_bps": baud_bps,
        "read": "fast sync read" if fast else "sync read",
        "bytes_per_tick": wire_bytes_per_tick(n_servos, fast),
        "rate_hz": rate,
        "limit_hz": limit,
        "ratio": rate / limit,
        "wire_us_per_tick": 1e6 / limit,
        "tick_us": 1e6 * wall / ticks,
        "host_bound_hz": 1.0 / (1.0 / limit + (cpu_read + cpu_write) / ticks),
        "read_wall_us_per_tick": 1e6 * wall_read / ticks,
        "host_cpu_us_per_tick": 1e6 * (cpu_read + cpu_write) / ticks,
        "read_cpu_us_per_tick": 1e6 * cpu_read / ticks,
        "write_cpu_us_per_tick": 1e6 * cpu_write / ticks,
        "emulator_cpu_us_per_tick": None if emu0 is None or emu1 is None else 1e6 * (emu1 - emu0) / ticks,
        "stale_reads": stale,
    }


HELP = "Dynamixel driver loop rate (read + write per tick) against the bus emulator, next to the wire-time limit"


def _list_of(kind: str) -> Any:
    """An argparse type: a comma-separated list of servo counts, baud rates or read kinds; a bad
    item is refused by argparse (one line, exit 2) naming what is allowed."""
    from haptic_teleop.plants.dynamixel.chain import SDK_BAUD_RATES_BPS

    allowed = {
        "servos": "whole numbers 1..20",
        "bauds": f"baud rates from {', '.join(map(str, SDK_BAUD_RATES_BPS))}",
        "reads": "sync, fast",
    }[kind]

    def parse(text: str) -> list[Any]:
        items = [x.strip() for x in text.split(",") if x.strip()]
        try:
            if not items:
                raise ValueError
            if kind == "reads":
                if any(x not in ("sync", "fast") for x in items):
                    raise ValueError
                return items
            values = [int(x) for x in items]
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: allowed: {allowed}, separated by commas") from None
        if (kind == "servos" and not all(1 <= v <= 20 for v in values)) or (
            kind == "bauds" and not all(v in SDK_BAUD_RATES_BPS for v in values)
        ):
            raise argparse.ArgumentTypeError(f"{text!r}: allowed: {allowed}, separated by commas")
        return values

    parse.__name__ = kind
    return parse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--servos", type=_list_of("servos"), default=[3, 6], help="servo counts (3: dxl_arm in MuJoCo; others: inertia)"
    )
    p.add_argument(
        "--bauds", type=_list_of("bauds"), default=[1_000_000, 4_000_000], help="baud rates (bps), comma separated"
    )
    p.add_argument(
        "--reads", type=_list_of("reads"), default=["sync", "fast"], help="sync, fast or both, comma separated"
    )
    p.add_argument("--ticks", type=positive(int), default=3000, help="timed ticks per case (default 3000)")
    p.add_argument("--warmup", type=positive(int), default=200, help="untimed ticks first (default 200)")
    p.add_argument("--repeat", type=positive(int), default=1, help="runs per case; the table shows the median")
    p.add_argument("--pin", action="store_true", help="pin this process and the emulator to one CPU each")
    p.add_argument("--json", metavar="PATH", help="also write every run's figures to this JSON file")


def main(args: argparse.Namespace) -> int:
    servos, bauds, reads = args.servos, args.bauds, args.reads
    print(
        f"Dynamixel driver against the bus emulator (wire timing, Return Delay 0, USB latency 0), "
        f"{args.ticks} ticks free-running, median of {args.repeat}"
        + (", host and emulator pinned to one CPU each" if args.pin else "")
    )
    print("limit = 1 / (bytes per tick x 10 / baud); target: rate >= 80 % of the limit")
    head = (
        f"{'servos':>6} {'baud':>9} {'read':<15} {'bytes':>5} {'rate Hz':>8} {'limit Hz':>9} {'ratio':>6}  "
        f"{'tick us':>7} {'wire us':>7} {'read us':>7} {'host cpu us':>11} {'(read':>6} {'write)':>6} "
        f"{'emu cpu us':>10} {'stale':>5} {'wire+host Hz':>12}"
    )
    print(head)
    runs: list[dict[str, Any]] = []
    for n in servos:
        for baud in bauds:
            for read in reads:
                got = [run_case(n, baud, read == "fast", args.ticks, args.warmup, args.pin) for _ in range(args.repeat)]
                runs.extend(got)
                med = sorted(got, key=lambda r: r["rate_hz"])[len(got) // 2]
                emu = med["emulator_cpu_us_per_tick"]
                rates = ", ".join(f"{r['rate_hz']:.0f}" for r in got)
                print(
                    f"{n:>6} {baud:>9} {med['read']:<15} {med['bytes_per_tick']:>5} {med['rate_hz']:>8.0f} "
                    f"{med['limit_hz']:>9.0f} {med['ratio']:>6.2f}  {med['tick_us']:>7.0f} "
                    f"{med['wire_us_per_tick']:>7.0f} {med['read_wall_us_per_tick']:>7.0f} "
                    f"{med['host_cpu_us_per_tick']:>11.0f} {med['read_cpu_us_per_tick']:>6.0f} "
                    f"{med['write_cpu_us_per_tick']:>6.0f} {'-' if emu is None else f'{emu:.0f}':>10} "
                    f"{med['stale_reads']:>5} {med['host_bound_hz']:>12.0f}"
                    + (f"   (runs: {rates})" if len(got) > 1 else ""),
                    flush=True,
                )
    ratios = [r["ratio"] for r in runs]
    print(f"ratio: rate / limit; median over all cases {statistics.median(ratios):.2f}; target >= 0.80")
    print(
        "tick us: wall time per tick; wire us: the bytes' time on the bus; read us: wall time in read() "
        "(sync read out, replies back); host cpu us: this process's CPU time per tick (the SDK building "
        "and parsing packets, the driver), split into read and write; emu cpu us: the emulator process's; "
        "wire+host Hz: 1 / (wire time + host CPU time), what this host would reach on a bus whose servos "
        "answer in no time"
    )
    if args.json:
        Path(args.json).write_text(json.dumps({"benchmark": "hardware", "runs": runs}, indent=1) + "\n")
    return 0
