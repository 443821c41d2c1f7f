"""`composed PLAN`: a scene's whole node plan in this one process (`launcher.run_single_process`:
one executor, one shared loop thread), as `haptic-teleop launch SCENE --single-process` runs it.

The ROS 2 launch files start it for `single_process:=true` (`ros2_launch.launch_processes`):
`ros2 launch` can only start one process per executable, and the composed set is the configuration
recommended on small machines (docs/live.md). PLAN is a JSON file of the plan's NodeSpecs written
next to their parameter files (`write_plan`); each node reads its own parameter file
(`--params-file`, use_global_arguments=False), so nothing on this process's command line after
`--ros-args` (what launch_ros's Node appends) reaches the nodes: it is ignored.

Exit codes: 0 when the scene finished, 130 / 143 when SIGINT / SIGTERM stopped it (-2 / -15 if it
came before the nodes were built), 2 for a bad plan or parameter, 1 for any other failure.
"""

from __future__ import annotations

import argparse
import faulthandler
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from haptic_teleop.live.launcher import NodeSpec, run_single_process

PLAN_FILE = "composed_plan.json"
PLAN_FORMAT = 1  # `format` of the plan file
EXIT_BAD_PLAN = 2


def write_plan(plan: Sequence[NodeSpec], folder: str | Path) -> Path:
    """The plan as JSON in `folder` (where `write_params_files` puts the nodes' parameter files)."""
    nodes = [
        {"name": s.name, "executable": s.executable, "params": s.params, "remaps": [list(r) for r in s.remaps]}
        for s in plan
    ]
    path = Path(folder) / PLAN_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"format": PLAN_FORMAT, "nodes": nodes}, indent=1) + "\n")
    return path


def read_plan(path: str | Path) -> list[NodeSpec]:
    """The NodeSpecs of a plan file (`write_plan`); ValueError saying what is wrong with it."""
    try:
        data: Any = json.loads(Path(path).read_text())
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != PLAN_FORMAT or not isinstance(data.get("nodes"), list):
        raise ValueError(f"{path}: not a plan file of format {PLAN_FORMAT} (write_plan)")
    plan = []
    for i, node in enumerate(data["nodes"]):
        try:
            remaps = tuple((str(a), str(b)) for a, b in node.get("remaps", ()))
            plan.append(NodeSpec(str(node["name"]), str(node["executable"]), dict(node["params"]), remaps))
        except (KeyError, TypeError, ValueError, AttributeError):
            raise ValueError(f"{path}: node {i} needs name, executable, params (and remaps as pairs)") from None
    if not plan:
        raise ValueError(f"{path}: the plan has no node")
    return plan


def main(argv: Sequence[str] | None = None) -> int:
    """Console script `composed` (lib/haptic_teleop): run the plan file's nodes in this process."""
    args = list(sys.argv[1:] if argv is None else argv)
    if "--ros-args" in args:  # launch_ros's Node always appends it; the nodes take their own files
        args = args[: args.index("--ros-args")]
    parser = argparse.ArgumentParser(
        prog="composed", description="Every node of a haptic_teleop plan in one process (one shared loop thread)."
    )
    parser.add_argument("plan", help=f"the plan file ({PLAN_FILE}) next to the nodes' parameter files")
    ns = parser.parse_args(args)
    try:
        plan = read_plan(ns.plan)
    except ValueError as exc:
        print(f"composed: {exc}", file=sys.stderr, flush=True)
        return EXIT_BAD_PLAN
    remapped = [s.name for s in plan if s.remaps]
    if remapped:
        # run_single_process gives each node its parameter file only: a remapping would be lost.
        print(
            f"composed: {', '.join(remapped)} remap topics, which a composed run does not apply; "
            "run one process per node",
            file=sys.stderr,
            flush=True,
        )
        return EXIT_BAD_PLAN
    faulthandler.enable(all_threads=True)  # a native crash prints every thread's stack, as node_main
    # The parameter files are rewritten where they are, from the same specs: the same bytes.
    return run_single_process(plan, Path(ns.plan).resolve().parent)


if __name__ == "__main__":
    sys.exit(main())
