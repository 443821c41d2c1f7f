"""The NVE transparency figures and tables (analysis/nve_transparency_plot.py): PNGs written, bad
round-trip lists refused, figures carry the curves and log axes they claim, tables hold the seed's
numbers (worked out by hand from m = 0.25, b = 0.0025, k_h = k_e = 0.5)."""

import math

import numpy as np
import pytest

from haptic_teleop.analysis.nve_transparency_plot import (
    allowable_table,
    distortion_figure,
    distortion_table,
    impedance_figure,
    write_distortion_plot,
    write_impedance_plot,
)
from haptic_teleop.core.nve_transparency import NveModel

SEED = NveModel(0.25, 0.0025, 0.5, 0.5)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_plots_write_png(tmp_path):
    a = write_impedance_plot(tmp_path / "z.png", SEED, [0.0, 0.1, 0.3])
    b = write_distortion_plot(tmp_path / "d.png", SEED, 0.5)
    for p in (a, b):
        data = p.read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000


@pytest.mark.parametrize(
    ("rtts", "match"),
    [
        ([], "1 to 10"),
        ([0.1, -0.1], "finite and >= 0"),
        ([0.1, math.nan], "finite and >= 0"),
        ([0.1, math.inf], "finite and >= 0"),
        ([0.2, 0.1], "distinct and increasing"),
        ([0.1, 0.1], "distinct and increasing"),
        ([0.01 * i for i in range(11)], "1 to 10"),
    ],
)
def test_impedance_plot_refuses_bad_rtts(tmp_path, rtts, match):
    with pytest.raises(ValueError, match=match):
        write_impedance_plot(tmp_path / "z.png", SEED, rtts)
    assert not (tmp_path / "z.png").exists()


@pytest.mark.parametrize("rtt_max", [0.0, -1.0, math.nan, math.inf])
def test_distortion_plot_refuses_bad_rtt_max(tmp_path, rtt_max):
    with pytest.raises(ValueError, match="rtt_max"):
        write_distortion_plot(tmp_path / "d.png", SEED, rtt_max)


def test_impedance_figure_content():
    fig = impedance_figure(SEED, (0.0, 0.1, 0.3))
    (ax,) = fig.axes
    assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
    assert "rad/s" in ax.get_xlabel() and "N s/m" in ax.get_ylabel()
    labels = [line.get_label() for line in ax.get_lines()]
    # one exact curve per R, one dashed approximation per R > 0, the object's |Z_e|
    assert len(labels) == 3 + 2 + 1
    assert sum("low-frequency" in s for s in labels) == 2
    # the curves span the human-input band and the R = 300 ms exact curve starts at k_h b_h / k_e
    line = ax.get_lines()[labels.index("|Z_h|, R = 300 ms")]
    x, y = line.get_xdata(), line.get_ydata()
    assert x[0] == pytest.approx(1e-6) and x[-1] == pytest.approx(1e2)
    assert y[0] == pytest.approx(0.5 * (0.0025 + 0.5 * 0.3) / 0.5, rel=1e-6)
    assert fig.axes[0].get_legend() is not None


def test_distortion_figure_content():
    fig = distortion_figure(SEED, 0.5)
    left, right = fig.axes
    assert left.get_yscale() == "log" and right.get_yscale() == "log"
    assert "[s]" in left.get_xlabel() and "N/m" in right.get_ylabel()
    khb = next(ln for ln in right.get_lines() if ln.get_label().startswith("k_hb"))
    x, y = khb.get_xdata(), khb.get_ydata()
    assert y[-1] == pytest.approx(0.5 * (0.0025 + 0.5 * 0.5) / 0.0025)  # 50.5 N/m at 0.5 s
    assert np.all(np.diff(y) > 0) and x[-1] == 0.5


def _rows(table: str) -> list[list[float]]:
    return [[float(c) for c in line.strip("| ").split(" | ")] for line in table.splitlines()[2:]]


def test_tables_hold_the_seed_numbers():
    rows = _rows(distortion_table(SEED, (0.0, 0.3)))
    # R, m_h, m_h/m, b_h, b_h/b, c_m, k_hm, k_hb, crossover
    assert rows[0] == pytest.approx([0.0, 0.25, 1.0, 0.0025, 1.0, 0.0025, 0.5, 0.5, 0.01])
    m_h = 0.25 + 0.0025 * 0.3 + 0.5 * 0.09 / 2  # 0.27325
    b_h = 0.0025 + 0.5 * 0.3  # 0.1525
    expected = [0.3, m_h, m_h / 0.25, b_h, 61.0, 0.0025 + 0.15, 0.5 * m_h / 0.25, 30.5]
    assert rows[1][:8] == pytest.approx(expected, rel=1e-4)
    assert rows[1][8] == pytest.approx(math.sqrt(0.0025 * b_h / (0.25 * m_h)), rel=1e-3)
    (row,) = _rows(allowable_table(SEED, (1.2,)))
    # m_allowable = 0.3: 0.25 R^2 + 0.0025 R - 0.05 = 0; b_allowable = 0.003: R = 0.0005 / 0.5
    r_m = (-0.0025 + math.sqrt(0.0025**2 + 4 * 0.25 * 0.05)) / (2 * 0.25)
    assert row == pytest.approx([1.2, 0.3, r_m, 0.05 / 0.0025, 0.003, 0.001], rel=1e-3)
    with pytest.raises(ValueError, match="ratio"):
        allowable_table(SEED, (0.5,))
