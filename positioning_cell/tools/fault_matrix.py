"""The fault matrix on a fresh live cell: one trial of each named fault (all without names),
a line per trial. The matrix, its trials and their judging are
:mod:`positioning_cell.procedures.fault_trials`; the cell is
:class:`positioning_cell.ros.fault_cell.FaultCell` (the four nodes and the recorder as
processes on a private domain, homed).

``python -m positioning_cell.tools.fault_matrix [fault ...]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from positioning_cell.procedures.fault_trials import FAULTS, fault, markdown_table, run_matrix
from positioning_cell.ros.fault_cell import FaultCell
from positioning_cell.tools.exits import Exit, exit_table
from positioning_cell.tools.interruption import Interrupted, interruptible

__all__ = ['FAULTS', 'main', 'markdown_table']


def main(argv: Sequence[str] | None = None) -> int:
    """Run the trials; the exit code (:class:`~positioning_cell.tools.exits.Exit`): OK when
    every trial gave its expected reaction, NOT_ACHIEVED when one missed it, NOT_THERE when
    the cell did not start, INTERRUPTED on SIGINT / SIGTERM (the drives stopped)."""
    parser = argparse.ArgumentParser(
        description=__doc__.split('\n\n')[0], epilog='exit codes:\n' + exit_table(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('faults', nargs='*', help='names of rows (default: all): '
                        + ', '.join(f.name for f in FAULTS))
    args = parser.parse_args(argv)
    try:
        chosen = [fault(n) for n in args.faults] or list(FAULTS)
    except KeyError as err:
        parser.error(str(err.args[0]))
    with interruptible() as signals, tempfile.TemporaryDirectory(prefix='fault_matrix_') as tmp:
        cell: FaultCell | None = None
        try:
            cell = FaultCell(Path(tmp))
            cell.start()
            trials = run_matrix(cell, chosen, print)
        except Interrupted as why:
            print(f'interrupted ({why}): stopping the drives', file=sys.stderr)
            with signals.ignored():
                if cell is not None:
                    cell.stop()
            return Exit.INTERRUPTED
        except TimeoutError as err:
            print(f'the cell is not there: {err}', file=sys.stderr)
            return Exit.NOT_THERE
        finally:
            if cell is not None:
                with signals.ignored():
                    cell.close()
    return Exit.OK if all(t.ok for t in trials) else Exit.NOT_ACHIEVED


if __name__ == '__main__':
    sys.exit(main())
