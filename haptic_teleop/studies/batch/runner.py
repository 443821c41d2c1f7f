"""Where a sweep's points run: in this process, in local worker processes, or on a Dask cluster.

Every point runs through `run_point`, the same path as `haptic-teleop run` (the resolved scene
written to `runs/<run_hash>/scene.yaml` and loaded from there, `record_run`, `write_outputs`), so
a point gives the same summary wherever it runs: the scene and seed fix every random stream.

- `InProcess` (`--workers 1`): one point after the other in this process; Ctrl-C stops the running
  point's loop through the command line's own signal path (haptic_teleop/interrupt.py).
- `LocalPool` (`--workers N`, the default N = os.cpu_count()): a `concurrent.futures`
  ProcessPoolExecutor of N processes started with `spawn` (a clean interpreter, as a Dask worker
  has: nothing inherited from the parent's threads or its progress bar). Chosen over Dask's local
  scheduler because it is the standard library (the default needs no extra), starts in a fraction
  of a second, and its processes are this command's children, so a signal reaches their loops.
  A worker stops its running loop on SIGINT/SIGTERM (the terminal's Ctrl-C reaches the whole
  process group; a signal sent to the parent alone is passed on by `stop`).
- `DaskRunner` (`--scheduler ADDRESS`): `dask.distributed.Client(ADDRESS)`, one task per point; on
  a signal the points no worker has taken are cancelled and the ones being processed finish and
  are kept (a running Dask task cannot be stopped). A Dask worker process is daemonic, so there
  the bag is written in the worker's own process (`RunRecorder(parallel=False)`). The workers need
  this package and the scene's files (models, traces) at the same paths, and --out on a shared
  filesystem for runs/ (the results come back to this process either way).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import shutil
import signal
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from haptic_teleop.errors import InputError

RUNS = "runs"
POLL_S = 0.2


@dataclass(frozen=True)
class Task:
    """What a worker needs for one point: all plain data (pickled to a process or a Dask worker)."""

    run_hash: str
    scene_yaml: str
    run_dir: str
    keep_bag: bool = False
    run_plots: bool = False


# A worker process's stop flag and the engine it is running (set by _worker_init's handler).
_worker: dict[str, Any] = {"stop": False, "engine": None, "pid": None}


def run_point(task: Task, on_engine: Callable[[Any], None] | None = None) -> dict[str, Any]:
    """Run one point; its summary, or {"interrupted": True} (its directory removed) when a stop
    request ended its loop early (a part of a run is not a result)."""
    import json

    from haptic_teleop.analysis.outputs import SCENE_FILE, TIMING_FILE, write_atomic, write_outputs
    from haptic_teleop.scene.load import load_scene

    run_dir = Path(task.run_dir)
    if run_dir.exists():
        shutil.rmtree(run_dir)  # a point cut by a kill: run again from scratch
    run_dir.mkdir(parents=True)
    (run_dir / SCENE_FILE).write_text(task.scene_yaml)
    scene = load_scene(run_dir / SCENE_FILE)
    bag_dir = run_dir / "bag"
    parallel = not mp.current_process().daemon  # a Dask worker cannot start the writer process

    def engine_started(engine: Any) -> None:
        _worker["engine"] = engine
        if _worker["stop"]:
            engine.request_stop()
        if on_engine is not None:
            on_engine(engine)

    t0 = time.perf_counter()
    try:
        if scene.config.is_nve:
            from haptic_teleop.engine.nve_loop import record_nve_run

            _, timing = record_nve_run(scene, bag_dir, parallel=parallel, handle_sigint=False, on_engine=engine_started)
        else:
            from haptic_teleop.engine.run import record_run

            _, timing = record_run(scene, bag_dir, parallel=parallel, handle_sigint=False, on_engine=engine_started)
    finally:
        _worker["engine"] = None
    if timing.interrupted:
        shutil.rmtree(run_dir, ignore_errors=True)
        return {"run_hash": task.run_hash, "interrupted": True}
    write_atomic(run_dir / TIMING_FILE, json.dumps(timing.as_dict(), indent=2, sort_keys=True) + "\n")
    summary = write_outputs(bag_dir, run_dir, plots=task.run_plots)
    if not task.keep_bag:
        shutil.rmtree(bag_dir)
    return {
        "run_hash": task.run_hash,
        "interrupted": False,
        "summary": summary,
        "bag_path": str(bag_dir) if task.keep_bag else None,
        "wall_s": time.perf_counter() - t0,
        "pid": os.getpid(),
    }


def run_point_safe(task: Task) -> dict[str, Any]:
    """`run_point` in a worker process: an exception comes back as text (`error`), not as an
    object to unpickle in the sweep's process (the project's errors take several arguments and
    do not unpickle; a failed unpickling would break the whole pool)."""
    try:
        return run_point(task)
    except Exception as exc:  # noqa: BLE001 - reported with the point, the other points run on
        return {"run_hash": task.run_hash, "interrupted": False, "error": f"{type(exc).__name__}: {exc}"}


def _worker_init() -> None:
    """In each local worker: SIGINT and SIGTERM stop the running loop (and every later point at
    once); never an exception between points. The bag writer a worker forks ignores them."""
    _worker["pid"] = os.getpid()

    def handler(signum: int, frame: Any) -> None:
        if os.getpid() != _worker["pid"]:
            return  # the bag writer (forked): its parent closes the bag
        _worker["stop"] = True
        engine = _worker["engine"]
        if engine is not None:
            engine.request_stop()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)


Result = tuple[Task, "dict[str, Any] | None", "BaseException | None"]


class InProcess:
    """`--workers 1`: the points one after the other in this process."""

    workers = 1

    def __init__(self) -> None:
        self._tasks: list[Task] = []

    def submit(self, tasks: list[Task]) -> None:
        self._tasks = list(tasks)

    def results(self, stopped: Callable[[], bool]) -> Iterator[Result]:
        import contextlib

        from haptic_teleop import interrupt

        for task in self._tasks:
            if stopped():
                return
            with contextlib.ExitStack() as stack:

                def on_engine(engine: Any, stack: contextlib.ExitStack = stack) -> None:
                    stack.enter_context(interrupt.on_stop(engine.request_stop))

                try:
                    result = run_point(task, on_engine=on_engine)
                except Exception as exc:  # noqa: BLE001 - one point's failure is reported, the others run
                    yield task, None, exc
                    continue
            yield task, result, None

    def stop(self) -> None:
        pass  # interrupt.on_stop already asked the running loop to stop

    def abort(self) -> None:
        pass

    def close(self) -> None:
        pass


class LocalPool:
    """`--workers N`: a ProcessPoolExecutor of N spawned processes."""

    def __init__(self, workers: int) -> None:
        from concurrent.futures import ProcessPoolExecutor

        self.workers = workers
        self._pool = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=_worker_init)
        self._futures: dict[Any, Task] = {}

    def submit(self, tasks: list[Task]) -> None:
        for t in tasks:
            self._futures[self._pool.submit(run_point_safe, t)] = t

    def results(self, stopped: Callable[[], bool]) -> Iterator[Result]:
        from concurrent.futures import FIRST_COMPLETED, wait

        pending = set(self._futures)
        while pending:
            done, pending = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
            for f in done:
                if f.cancelled():
                    continue
                exc = f.exception()
                yield self._futures[f], (None if exc else f.result()), exc
            if stopped():
                for f in pending:
                    f.cancel()  # not started yet: never runs

    def stop(self) -> None:
        """Cancel what has not started; running loops stop at their next tick (their points are
        not results); finished ones are still collected."""
        for f in self._futures:
            f.cancel()
        for child in mp.active_children():
            if child.pid is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(child.pid, signal.SIGINT)

    def abort(self) -> None:
        """A second signal: the workers (this command's children) end now."""
        for child in mp.active_children():
            child.kill()
        self._pool.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class DaskRunner:
    """`--scheduler ADDRESS`: the points as tasks of an existing Dask distributed cluster."""

    def __init__(self, address: str) -> None:
        try:
            from distributed import Client
        except ImportError:
            raise InputError(
                f"--scheduler {address}: dask.distributed is not installed; allowed: "
                "pip install 'haptic_teleop[sweep]', or no --scheduler (local processes)"
            ) from None
        connect: Any = Client  # dask's API is not fully typed
        try:
            self.client: Any = connect(address, timeout=30)
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(
                f"--scheduler {address}: no Dask scheduler answered ({exc}); allowed: the address of a "
                "running scheduler, e.g. tcp://127.0.0.1:8786"
            ) from None
        self.workers = max(1, len(self.client.scheduler_info().get("workers", {})))
        self._futures: dict[Any, Task] = {}

    def submit(self, tasks: list[Task]) -> None:
        for t in tasks:
            # key: the run hash, so a point is never run twice on the cluster at once
            self._futures[self.client.submit(run_point_safe, t, key=f"haptic-teleop-{t.run_hash}", pure=False)] = t

    def results(self, stopped: Callable[[], bool]) -> Iterator[Result]:
        pending = dict(self._futures)
        cancelled = False
        while pending:
            if stopped() and not cancelled:
                self._cancel_waiting(pending)
                cancelled = True
            done = [f for f in pending if f.done()]
            if not done:
                time.sleep(POLL_S / 4)
            for f in done:
                task = pending.pop(f)
                if f.status == "cancelled":
                    continue
                exc = f.exception() if f.status == "error" else None
                yield task, (None if exc else f.result()), exc

    def _cancel_waiting(self, pending: dict[Any, Task]) -> None:
        """Cancel the points no worker has taken; the ones being processed finish and are kept
        (a running Dask task cannot be stopped)."""
        busy = {key for keys in self.client.processing().values() for key in keys}
        self.client.cancel([f for f in pending if not f.done() and f.key not in busy])

    def stop(self) -> None:
        pass  # from the signal handler: no call into the client there; results() cancels

    def abort(self) -> None:
        self.client.close()

    def close(self) -> None:
        self.client.close()


def make_runner(workers: int | None, scheduler: str | None, points: int) -> InProcess | LocalPool | DaskRunner:
    if scheduler:
        return DaskRunner(scheduler)
    n = workers if workers is not None else (os.cpu_count() or 1)
    n = max(1, min(n, points))
    return InProcess() if n == 1 else LocalPool(n)
