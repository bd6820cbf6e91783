"""``recover_bag BAG``: make a bag whose recorder was killed, or whose files are damaged,
readable again.

Every ``.mcap`` of the bag directory is verified (chunk CRCs, data-section CRC). Each truncated
one is rewritten from its readable records (every complete chunk), each damaged one from its
sound chunks (the corrupt ones are left out and listed with the log times they covered), into
a valid, indexed file; the original is kept as ``<name>.mcap.truncated`` or
``<name>.mcap.damaged``, and ``metadata.yaml`` is rebuilt. A sound bag is left untouched.
Exit status (:mod:`positioning_cell.tools.exits`): 0 recovered or already complete; 2 not a
bag, unreadable or unrecoverable (nothing changed).
:func:`recover` does the work (tests call it); :func:`main` parses the command line.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from positioning_cell.bag import BagError, RecoveryReport, recover_bag
from positioning_cell.tools.exits import Exit, exit_table


def recover(bag: Path, compression: str = 'zstd') -> RecoveryReport:
    """Recover ``bag`` (see :func:`positioning_cell.bag.recover_bag`)."""
    return recover_bag(bag, compression)


def describe(report: RecoveryReport) -> str:
    """A few human-readable lines about what :func:`recover` did."""
    lines = []
    for item in report.files:
        if item.status == 'complete':
            lines.append(f'{item.path.name}: complete, {item.message_count} messages')
            continue
        lines.append(f'{item.path.name}: {item.status} {item.message_count} messages '
                     f'(damaged original kept as {item.backup.name if item.backup else "-"})')
        lines += [f'  {item.path.name}: {p}' for p in item.problems]
        lines += [f'  left out: {d.describe()}' for d in item.lost]
    if report.metadata_written:
        lines.append(f'wrote {report.bag / "metadata.yaml"}')
    if not report.changed:
        lines.append('the bag was complete: nothing changed')
    lines.append(f'{report.bag}: {report.message_count} messages')
    return '\n'.join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``recover_bag BAG [--compression zstd|none]``."""
    parser = argparse.ArgumentParser(
        prog='recover_bag', description='Rewrite the readable prefix of a truncated rosbag2 '
                                        'MCAP bag into a valid, indexed bag with metadata.yaml.',
        epilog='exit codes:\n' + exit_table(),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('bag', type=Path, help='bag directory (or one of its .mcap files)')
    parser.add_argument('--compression', choices=('zstd', 'none'), default='zstd',
                        help='chunk compression of rewritten files (default zstd)')
    args = parser.parse_args(argv)
    try:
        report = recover(args.bag, args.compression)
    except BagError as err:
        print(f'recover_bag: {err}', file=sys.stderr)
        return Exit.USAGE
    except OSError as err:
        print(f'recover_bag: {args.bag}: {err}', file=sys.stderr)
        return Exit.USAGE
    print(describe(report))
    return Exit.OK


if __name__ == '__main__':
    sys.exit(main())
