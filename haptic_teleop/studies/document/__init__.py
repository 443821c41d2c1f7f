"""`haptic-teleop report RESULTS_OR_BAGS`: one self-contained HTML report and its Markdown twin.

- `inputs.py`: sweep tables (today's sweep.csv, the Parquet/CSV results table), run directories and
  bags, read into one list of `Run`s (scene keys, seed, metrics, where its bag or plots are);
- `stats.py`: what the report computes from them (swept keys, predicted/measured pairs, means and
  spreads over seeds, differences paired by seed), without plotting;
- `figures.py`: the report's own matplotlib figures; the per-run time plots are analysis/plots.py's;
- `document.py`: the report as sections of paragraphs, tables and figures, written as HTML (figures
  as base64 PNG) and as Markdown (figures as PNG files beside it);
- `command.py`: the subcommand (arguments, building the sections, writing the files).

docs/report.md describes the sections.
"""
