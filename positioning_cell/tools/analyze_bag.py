"""``analyze_bag BAG [--out DIR] [--config F] [--no-plots]``: the offline analysis of a
recorded cell run.

Reads the topics the analysis uses through the bag's MCAP index (a file without one, as other
recorders write them, from a scan of its records), verifying what it reads
(:mod:`positioning_cell.analysis.reading`), replays them through the accuracy monitor's rules
with the monitor's settings from ``config/cell.yaml`` (or ``--config``), and writes
``report.md``, ``summary.json`` and (unless ``--no-plots``) PNG plots into ``--out`` (default:
``<bag>_analysis`` beside the bag). Exit status (:mod:`positioning_cell.tools.exits`): 0
analysed; 1 analysed only in part (a truncated bag, or corrupt chunks: each one with the time
range and messages lost is printed and in the report, the figures cover the rest); 2 nothing
analysed (not a bag, an empty or too short ``.mcap``, a bag without the needed topics, a bad
config). :func:`analyze` does the work; :func:`main` parses the command line.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from positioning_cell.errors import PositioningError
from positioning_cell.tools.exits import Exit, exit_table

if TYPE_CHECKING:
    from positioning_cell.analysis.summary import RunAnalysis


#: The command's process environment, set before numpy loads (given values kept): one BLAS
#: thread. The plots are drawn in workers on the core the analysis leaves
#: (:mod:`positioning_cell.analysis.plot_workers`); OpenBLAS's second thread in the analysing
#: process took that core from them. On a `make run` bag tiled to 1 M messages, 2-core VM,
#: ad hoc, two pairs of runs: the plots and the analysis done at 4.5-4.7 s against 5.4-5.5 s.
ANALYSIS_ENVIRONMENT = {'OPENBLAS_NUM_THREADS': '1'}


@dataclass(frozen=True)
class AnalysisOutput:
    """The analysis and the files written: report, JSON summary, plots, acceptance record
    (Markdown; its JSON beside it)."""

    analysis: RunAnalysis
    report: Path
    summary: Path
    plots: tuple[Path, ...]
    acceptance: Path | None = None


def default_out_dir(bag: Path) -> Path:
    """``<bag>_analysis`` beside the bag (a bag folder, or an .mcap file without suffix)."""
    bag = bag.resolve()
    return bag.with_name(f'{bag.stem if bag.is_file() else bag.name}_analysis')


def analyze(bag: str | Path, out_dir: str | Path | None = None,
            config: str | Path | None = None, *, plots: bool = True,
            program: str | Path | None = None) -> AnalysisOutput:
    """Analyse the bag and write the report, summary, acceptance record (its limits from the
    ``acceptance:`` block of the ``program`` file, else the defaults) and (unless ``plots``
    is False) the plots into ``out_dir``. Raises PositioningError (BagError, ConfigError)
    when nothing can be analysed."""
    # The analysis (numpy, scipy, matplotlib, the bag reader) loads here, not with the command
    # line: --help and a usage error answer at once.
    from positioning_cell.accuracy.monitor import MonitorSettings
    from positioning_cell.analysis.acceptance import AcceptanceLimits, write_acceptance
    from positioning_cell.analysis.heap import map_large_allocations
    from positioning_cell.analysis.plot_workers import PlotWorkers
    from positioning_cell.analysis.report import write_report
    from positioning_cell.analysis.summary import analyse_bag
    from positioning_cell.config import config_path

    map_large_allocations()  # the batches' buffers freed back to the system (heap)
    bag = Path(bag)
    config = config or config_path('cell.yaml')
    settings = MonitorSettings.from_file(config)
    limits = AcceptanceLimits.from_program(program)  # a bad block stops before the read
    out = Path(out_dir) if out_dir is not None else default_out_dir(bag)
    if not plots:
        analysis = analyse_bag(bag, settings, config)
        report, summary = write_report(analysis, out)
        return AnalysisOutput(analysis, report, summary, (),
                              write_acceptance(analysis, out, limits, config)[0])
    # The plots are drawn in workers (warmed up while the bag is read) from the replay on,
    # while the error budget and the report are done here (plot_workers).
    with PlotWorkers() as workers:
        planned: list[Path] = []
        analysis = analyse_bag(
            bag, settings, config, replayed=lambda a: planned.extend(workers.start(a, out)))
        report, summary = write_report(analysis, out, planned)
        acceptance = write_acceptance(analysis, out, limits, config)[0]
        pngs = workers.paths()
    return AnalysisOutput(analysis, report, summary, tuple(pngs), acceptance)


def describe(output: AnalysisOutput) -> str:
    """What to print after an analysis: problems, the comparison table, the files."""
    from positioning_cell.analysis.report import comparison_table  # loaded by analyze()

    a = output.analysis
    lines = [f'analyze_bag: problem: {p}' for p in a.problems]
    if a.modes:
        lines.append(comparison_table(a.modes).rstrip('\n'))
    else:
        lines.append('analyze_bag: no commanded pose settled in this bag')
    lines += [f'report:  {output.report}', f'summary: {output.summary}']
    if output.acceptance is not None:
        lines.append(f'acceptance record: {output.acceptance}')
    if output.plots:
        lines.append('plots:   ' + ', '.join(str(p) for p in output.plots))
    return '\n'.join(lines) + '\n'


def main(argv: Sequence[str] | None = None) -> int:
    """Command line; see the module docstring for the exit status."""
    parser = argparse.ArgumentParser(
        prog='analyze_bag', description='Offline analysis of a recorded positioning cell run: '
        'ISO 9283 figures per pose and compensation mode, tracker error, report and plots.',
        epilog='exit codes:\n' + exit_table(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('bag', type=Path, help='the bag: a rosbag2 folder or an .mcap file')
    parser.add_argument('--out', type=Path, help='output folder (default: <bag>_analysis)')
    parser.add_argument('--config', type=Path, help='ROS 2 parameter file with the monitor\'s '
                        'settings (default: the shipped config/cell.yaml)')
    parser.add_argument('--program', type=Path, help='the run\'s program file: its '
                        'acceptance: block sets the acceptance record\'s limits (default: '
                        'the built-in ones; config/acceptance.yaml has the block)')
    parser.add_argument('--no-plots', action='store_true',
                        help='write the report and the JSON summary only (the plots take '
                        'about 2 s whatever the bag\'s length)')
    args = parser.parse_args(argv)
    for name, value in ANALYSIS_ENVIRONMENT.items():  # numpy is not loaded yet
        os.environ.setdefault(name, value)
    try:
        output = analyze(args.bag, args.out, args.config, plots=not args.no_plots,
                         program=args.program)
    except PositioningError as err:
        print(f'analyze_bag: error: {err}', file=sys.stderr)
        return Exit.USAGE
    text = describe(output)
    if output.analysis.problems:
        sys.stderr.write(text)
        return Exit.NOT_ACHIEVED
    sys.stdout.write(text)
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
