"""`record_run`: a scene run in lockstep and recorded as it goes (the bag written by a second
process while the loop runs), with its wall-clock facts (`RunTiming`, kept beside the bag)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from haptic_teleop.engine.lockstep import Engine, RunResult
from haptic_teleop.engine.output import Collector, RunSink, Tee
from haptic_teleop.scene.schema import LoadedScene


@dataclass(frozen=True)
class RunTiming:
    """Wall-clock facts of one recorded run (kept beside the bag, never in it)."""

    simulated_s: float
    loop_wall_s: float
    record_wall_s: float  # loop start to bag closed
    interrupted: bool
    loop: str = "python"  # which loop ran: "compiled" or "python" (Engine.loop_kind)
    pacing: dict[str, float | int] | None = None  # a real device's run: pacer.Pacer.facts()

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall second of the loop with recording included."""
        return self.simulated_s / self.record_wall_s if self.record_wall_s > 0 else float("inf")

    def as_dict(self) -> dict[str, float | bool | str]:
        return {
            "simulated_s": self.simulated_s,
            "loop_wall_s": self.loop_wall_s,
            "record_wall_s": self.record_wall_s,
            "realtime_factor": self.realtime_factor,
            "loop_realtime_factor": self.simulated_s / self.loop_wall_s if self.loop_wall_s > 0 else float("inf"),
            "interrupted": self.interrupted,
            "loop": self.loop,
            **({"realtime": True, **self.pacing} if self.pacing is not None else {}),
        }


def record_run(
    scene: LoadedScene,
    bag_dir: Path,
    progress: Callable[[int], None] | None = None,
    parallel: bool = True,
    handle_sigint: bool = True,
    loop: str = "auto",
    on_engine: Callable[[Engine], None] | None = None,
    keep: bool = False,
    make_view: Callable[[Sequence[str], int], Any] | None = None,
) -> tuple[Engine, RunTiming]:
    """Run a scene and record it: the bag is written by a second process while the loop runs.

    The loop streams to the recorder (`Engine.run` with it as the sink): memory does not grow
    with the run's length. `keep=True` also keeps the whole run in `engine.data` (tests). Whatever
    ends the run (last tick, Ctrl-C, an exception in a tick) the bag is closed with every tick
    that finished, and is readable. `on_engine(engine)` is called once the engine is built, before
    the bag is opened (the command line registers its stop request there). `make_view(columns,
    period_ns)`: a live view the recording feeds as it goes (`run --foxglove`:
    record/foxglove_view.py), closed with the bag.
    """
    from haptic_teleop.engine.reference import reference_facts
    from haptic_teleop.record.recorder import RunRecorder

    engine = Engine(scene, loop=loop)
    c = scene.config
    view = None
    try:
        if on_engine is not None:
            on_engine(engine)
        # The undisturbed reference run the analysis compares with, if the scene asks for one: it
        # goes into this run's bag (engine/reference.py), so the analysis never simulates.
        reference = reference_facts(scene)
        view = make_view(engine.schema.columns, engine.period_ns) if make_view is not None else None
        rec = RunRecorder(
            bag_dir,
            scene.to_yaml(),
            engine.period_ns,
            c.recording.eba_internals,
            c.recording.packets,
            engine.schema.width,
            parallel=parallel,
            compression=c.recording.compression,
            schema=engine.schema,
            view=view,
        )
    except BaseException:
        engine.close_plants()  # a real device's torque off: no tick will run
        if view is not None:
            view.close()
        raise
    collector = Collector(engine.schema.width) if keep else None
    sink: RunSink = rec if collector is None else Tee(rec, collector)
    t0 = time.perf_counter()
    result: RunResult | None = None
    try:
        result = engine.run(progress=progress, handle_sigint=handle_sigint, sink=sink)
    finally:
        done = getattr(engine, "ticks_done", 0)
        info = {
            "ticks": done,
            "interrupted": done < engine.ticks,
            "failed": result is None,
            # Remote samples each side's guard rejected (the slave checks the forward direction).
            "rejected_samples_forward": engine.slave_ctrl.rejected_samples,
            "rejected_samples_backward": engine.master_ctrl.rejected_samples,
            # The damping each port's joint really has in the simulator (MjModel dof_damping, SI
            # per joint): the analysis' true energy margin uses it (docs/eba.md).
            "master_joint_damping": engine.master.joint_damping(),
            "slave_joint_damping": engine.slave.joint_damping(),
        }
        info.update(engine.codec_facts())
        # An in-contact start: each reservoir's start value (holding energy + eba.initial_energy_j).
        info.update(getattr(engine, "initial_energy", {}))
        info.update(reference)
        if c.is_arm:  # the wall plane in the task frame (the analysis' penetration)
            info["wall_point_m"] = list(c.slave.wall.point_m or ())
            info["wall_normal"] = list(c.slave.wall.normal or ())
            # A real device's side: its damping above is the scene's assumption (docs/hardware.md).
            info["master_backend"] = c.master.backend
            info["slave_backend"] = c.slave.backend
            for side, plant in (("master", engine.master), ("slave", engine.slave)):
                if hasattr(plant, "unmeasured_reads"):  # a real device: its measured effort's reads that
                    # carried no report, the command standing in (docs/hardware_plant.md, "Applied, not commanded")
                    info[f"{side}_unmeasured_torque_reads"] = plant.unmeasured_reads
                    info[f"{side}_unmeasured_torque_reads_after_first_report"] = plant.unmeasured_after_report
        if collector is not None:
            engine.data = collector.data()
        rec.close(info)  # and the view
    wall = time.perf_counter() - t0
    pacing = engine.pacer.facts() if engine.pacer is not None else None
    if pacing is not None:  # a real device's reads that failed (the driver repeated its last sample)
        for side, plant in (("master", engine.master), ("slave", engine.slave)):
            if hasattr(plant, "stale_ticks"):
                pacing[f"{side}_stale_reads"] = plant.stale_ticks
            if hasattr(plant, "hold_budget_s"):  # its holds between reads (docs/eba_many_joints.md, "Late ticks ...")
                pacing[f"{side}_long_holds"] = plant.long_holds
                pacing[f"{side}_over_budget_holds"] = plant.over_budget_holds
                pacing[f"{side}_longest_hold_s"] = plant.longest_hold_s
                pacing[f"{side}_max_hold_s"] = plant.hold_budget_s
    return engine, RunTiming(
        done * engine.period_s, result.loop_wall_s, wall, result.interrupted, engine.loop_kind, pacing
    )
