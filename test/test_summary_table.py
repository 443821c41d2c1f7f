"""The run summary's table (analysis/summary_table.py): what it warns of."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize(("margin", "warned"), [(-8e-35, False), (-1e-12, False), (-2e-9, True), (-0.1, True)])
def test_the_summary_warns_of_a_port_not_passive_beyond_rounding(margin: float, warned: bool) -> None:
    """A port that gave nothing can end at -8e-35 J from rounding in its sums (seen live with wave
    variables on an arm): no warning there; beyond 1e-9 J the summary says so."""
    from haptic_teleop.analysis.summary_table import format_summary

    text = format_summary({"master_energy_margin_min_j": margin, "slave_energy_margin_min_j": 0.5})
    assert ("master port was not passive" in text) == warned
