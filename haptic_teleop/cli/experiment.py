"""`haptic-teleop experiment NAME`: the experiments of the seeds as commands, each writing its plot
(PNG) and table (CSV, and markdown printed to stdout). Command-line layer: imported by cli/main.py only.

- `nve-analysis`, `nve-compensation`: seed 000's two NVE experiments (studies/replications/nve.py,
  docs/nve_experiments.md).
- `deadband`: seed 001's deadband rate and distortion on a 3-DoF contact-rich scene
  (studies/replications/deadband.py, docs/codec_deadband_experiments.md).
- `deadband-loop`: the same deadband in the loop: the scene run through the engine with the deadband
  in the channel per p and direction, against the uncoded run (studies/replications/deadband_loop.py,
  docs/codec_deadband_experiments.md).
- `hli-filtering`: seed 000's simulation of priority-based against deadband filtering
  (studies/replications/codec.py, docs/codec_error_control.md).
- `error-control`: seed 000's experiment, prediction-based filtering with FEC or ARQ over its
  events against priority-based filtering (studies/replications/codec.py, docs/codec_error_control.md).
- `playout`: seed 000's haptic-synchronization claim, its network-adaptive buffering against the
  existing schemes on paired seeds (studies/replications/playout.py, docs/playout_claim.md).
- `stabilizers`: EBA, TDPA and wave variables side by side over delay and loss on a one-axis and an
  arm scene, and their Z-width, every run a bag (studies/replications/stabilizers.py, zwidth.py,
  docs/stabilizers_compared.md).
- `all`: every experiment behind docs/ afresh, a manifest, and every documented number checked
  (studies/replications/all_experiments.py, docs/experiments_all.md).
- `transparency`: seed 000's EBA transparency analysis, force slope, drop over delay and transparent
  loss time, predicted against measured (studies/replications/transparency.py, docs/transparency.md).
"""

from __future__ import annotations

import argparse

from haptic_teleop.studies.replications.args import OneLineParser


def _help(text: str) -> str:
    """A description as a subcommand's one-line help: argparse %-formats help strings (not
    descriptions), so a literal '%' ("a 20 % lossy link") is doubled."""
    return text.replace("%", "%%")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """`haptic-teleop experiment NAME ...` on `p` (made by cli/main.py's subparsers: it becomes a
    OneLineParser too, so an unknown NAME is one line as well)."""
    from haptic_teleop.studies.replications import (
        all_experiments,
        codec,
        deadband,
        deadband_loop,
        nve,
        nve_compensation,
        playout,
        stabilizers,
        transparency,
    )

    p.__class__ = OneLineParser
    sub = p.add_subparsers(dest="experiment", required=True, metavar="NAME", parser_class=OneLineParser)
    a = sub.add_parser("nve-analysis", help=_help(nve.ANALYSIS_HELP), description=nve.ANALYSIS_HELP)
    nve.add_analysis_arguments(a)
    a.set_defaults(func=nve.main_analysis)
    c = sub.add_parser(
        "nve-compensation",
        help=_help(nve_compensation.COMPENSATION_HELP),
        description=nve_compensation.COMPENSATION_HELP,
    )
    nve_compensation.add_compensation_arguments(c)
    c.set_defaults(func=nve_compensation.main_compensation)
    f = sub.add_parser("hli-filtering", help=_help(codec.FILTERING_HELP), description=codec.FILTERING_HELP)
    codec.add_filtering_arguments(f)
    f.set_defaults(func=codec.main_filtering)
    e = sub.add_parser("error-control", help=_help(codec.ERROR_CONTROL_HELP), description=codec.ERROR_CONTROL_HELP)
    codec.add_error_control_arguments(e)
    e.set_defaults(func=codec.main_error_control)
    d = sub.add_parser("deadband", help=_help(deadband.HELP), description=deadband.HELP)
    deadband.add_arguments(d)
    d.set_defaults(func=deadband.main)
    dl = sub.add_parser("deadband-loop", help=_help(deadband_loop.HELP), description=deadband_loop.HELP)
    deadband_loop.add_arguments(dl)
    dl.set_defaults(func=deadband_loop.main)
    tr = sub.add_parser("transparency", help=_help(transparency.HELP), description=transparency.HELP)
    transparency.add_arguments(tr)
    tr.set_defaults(func=transparency.main)
    pl = sub.add_parser("playout", help=_help(playout.HELP), description=playout.HELP)
    playout.add_arguments(pl)
    pl.set_defaults(func=playout.main)
    st = sub.add_parser("stabilizers", help=_help(stabilizers.HELP), description=stabilizers.HELP)
    stabilizers.add_arguments(st)
    st.set_defaults(func=stabilizers.main)
    al = sub.add_parser("all", help=_help(all_experiments.HELP), description=all_experiments.HELP)
    all_experiments.add_arguments(al)
    al.set_defaults(func=all_experiments.main)
