"""``tolerance_analysis MECH.yaml --out DIR``: tolerance analysis of any mechanism described as
vector loops (seed 004; the format: :mod:`positioning_cell.tolerance.model`).

Prints a summary and writes ``report.md``, ``analysis.json`` and the figures into ``DIR``.
Exit codes (:mod:`positioning_cell.tools.exits`): 0 done; 2 bad input (the file, key and value
named; nothing written); 3 the analysis is refused (a singular or ill-conditioned U, loops
that do not close near the given nominal: the reason is printed and in the report, which is
written).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from positioning_cell.errors import PositioningError
from positioning_cell.tools.exits import Exit, exit_table


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    parser = argparse.ArgumentParser(
        prog='tolerance_analysis',
        description='Tolerance analysis of a mechanism given as vector loops (seed 004): '
        'first-order sensitivities T = C − D·U⁻¹·A, worst case, RSS, contributions, Monte '
        'Carlo with the nonlinear loop closure and the yield.',
        epilog='exit codes:\n' + exit_table(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('mechanism', type=Path, help='mechanism file (YAML)')
    parser.add_argument('--out', type=Path, required=True, help='output folder')
    parser.add_argument('--samples', type=int, default=1_000_000,
                        help='Monte Carlo samples (0: none; default 1 000 000)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    parser.add_argument('--confidence', type=float, default=0.95,
                        help='confidence of the yield intervals (default 0.95)')
    parser.add_argument('--check-derivatives', action='store_true',
                        help='also compare the analytic derivatives with central differences')
    parser.add_argument('--no-plots', action='store_true', help='write no figures')
    args = parser.parse_args(argv)
    from positioning_cell.tolerance.analysis import analyse
    from positioning_cell.tolerance.model import load_mechanism
    from positioning_cell.tolerance.report import summary, write_report

    try:
        if args.samples < 0 or args.seed < 0:
            raise PositioningError(f'--samples {args.samples} --seed {args.seed}: both must '
                                   'be >= 0')
        mech = load_mechanism(args.mechanism)
        analysis = analyse(mech, samples=args.samples, seed=args.seed,
                           check=args.check_derivatives, confidence=args.confidence)
    except PositioningError as err:
        print(f'tolerance_analysis: error: {err}', file=sys.stderr)
        return Exit.USAGE
    files = write_report(analysis, args.out, plots=not args.no_plots)
    sys.stdout.write(summary(analysis))
    print('wrote: ' + ', '.join(str(f) for f in files))
    if analysis.refusal is not None:
        print(f'tolerance_analysis: refused: {analysis.refusal}', file=sys.stderr)
        return Exit.REFUSED
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
