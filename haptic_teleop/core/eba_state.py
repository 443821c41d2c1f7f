"""What a one-axis energy bound carries from one tick to the next (`core.eba.EnergyBound`,
`core.eba_two_condition.TwoConditionBound`): its own module so that both laws use it without
importing each other."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class AxisBoundState:
    """What a one-axis `EnergyBound` carries from one tick to the next: the reservoir, the force
    held over the current period (the reservoir's F(n-1)), the position of the last step and
    whether there was one. `EnergyBound.axis_state`
    and `set_axis_state` move it in and out (the compiled loop, engine/compiled_loop.py, carries it)."""

    energy_j: float
    held_n: float
    last_x_m: float
    has_last: bool
