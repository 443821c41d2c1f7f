"""A Plant with sensor and actuator effects composed around it: only the effects it is given.

Measurement effects act on what `read()` and `contact_force()` report, actuator effects on the
force `step()` applies; the true state stays inside the wrapped plant (`.plant`). Physical effects
(gravity, friction) are not wrappers: the factory in `haptic_teleop.plants` writes them into the
MuJoCo model. See docs/effects.md.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol

from haptic_teleop.plants.base import Plant


class SignalEffect(Protocol):
    name: str

    def apply(self, values: list[float]) -> list[float]: ...


class EffectsPlant:
    """`plant` seen through the given effects, applied in the order given.

    `position`, `velocity`, `force`: measurement effects on `read()`'s positions and velocities
    and on `contact_force()`; `actuator`: effects on the commanded force, whose result is passed
    to the plant (and what the plant reports as applied is returned). `contact_source` replaces
    `plant.contact_force` as the true contact force (used to take joint friction out of MuJoCo's
    constraint force). Call `read()` and `contact_force()` once per period: noise is drawn per call.
    """

    def __init__(
        self,
        plant: Plant,
        position: Sequence[SignalEffect] = (),
        velocity: Sequence[SignalEffect] = (),
        force: Sequence[SignalEffect] = (),
        actuator: Sequence[SignalEffect] = (),
        contact_source: Callable[[], list[float]] | None = None,
        physical: Sequence[str] = (),
    ) -> None:
        self.plant = plant
        self.axes = plant.axes
        self.position_effects = tuple(position)
        self.velocity_effects = tuple(velocity)
        self.force_effects = tuple(force)
        self.actuator_effects = tuple(actuator)
        self.physical_effects = tuple(physical)
        # The per-tick methods are composed once here: a method with nothing to do is the wrapped
        # plant's own bound method, and a chain of one effect calls it directly (a wrapper call
        # and an empty loop cost about as much as an effect).
        pos = _chain(position)
        vel = _chain(velocity)
        force_chain = _chain(force)
        act = _chain(actuator)
        plant_read = plant.read
        plant_step = plant.step
        true_contact = contact_source if contact_source is not None else plant.contact_force
        if pos is not None or vel is not None:
            self.read = _read(plant_read, pos, vel)  # type: ignore[method-assign]
        else:
            self.read = plant_read  # type: ignore[method-assign]
        if force_chain is not None:

            def contact_force() -> list[float]:
                return force_chain(true_contact())

            self.contact_force = contact_force  # type: ignore[method-assign]
        else:
            self.contact_force = true_contact  # type: ignore[method-assign]
        if act is not None:

            def step(actuator_force_n: list[float], external_force_n: list[float] | None = None) -> list[float]:
                return plant_step(act(actuator_force_n), external_force_n)

            self.step = step  # type: ignore[method-assign]
        else:
            self.step = plant_step  # type: ignore[method-assign]

    @property
    def effects(self) -> tuple[str, ...]:
        """Names of every effect this plant applies (physical ones included), for inspection."""
        chain = self.position_effects + self.velocity_effects + self.force_effects + self.actuator_effects
        return self.physical_effects + tuple(e.name for e in chain)

    def __getattr__(self, name: str) -> Any:
        # model / data of the MuJoCo plant (benchmarks and tests read them); only reached for
        # attributes this class does not define.
        if name == "plant":
            raise AttributeError(name)
        return getattr(self.plant, name)

    # The methods below document the protocol; __init__ replaces them per instance.
    def read(self) -> tuple[list[float], list[float]]:
        return self.plant.read()

    def step(self, actuator_force_n: list[float], external_force_n: list[float] | None = None) -> list[float]:
        return self.plant.step(actuator_force_n, external_force_n)

    def contact_force(self) -> list[float]:
        return self.plant.contact_force()

    def joint_damping(self) -> list[float]:
        return self.plant.joint_damping()

    def close(self) -> None:
        self.plant.close()


Signal = Callable[[list[float]], list[float]]


def _chain(effects: Sequence[SignalEffect]) -> Signal | None:
    """One function applying `effects` in order; None when there are none."""
    fns = tuple(e.apply for e in effects)
    if not fns:
        return None
    if len(fns) == 1:
        return fns[0]

    def run(values: list[float]) -> list[float]:
        for f in fns:
            values = f(values)
        return values

    return run


def _read(
    plant_read: Callable[[], tuple[list[float], list[float]]], pos: Signal | None, vel: Signal | None
) -> Callable[[], tuple[list[float], list[float]]]:
    if vel is None:
        assert pos is not None

        def read_x() -> tuple[list[float], list[float]]:
            x, v = plant_read()
            return pos(x), v

        return read_x
    if pos is None:

        def read_v() -> tuple[list[float], list[float]]:
            x, v = plant_read()
            return x, vel(v)

        return read_v

    def read_xv() -> tuple[list[float], list[float]]:
        x, v = plant_read()
        return pos(x), vel(v)

    return read_xv
