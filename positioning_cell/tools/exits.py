"""The exit codes of every command line of the cell, one table: a number means the same in
``cell``, ``run_cell``, ``calibrate_cell``, ``axis_test``, ``analyze_bag`` and the others (each
tool's ``--help`` and the reference page of the docs print it from here)."""

from __future__ import annotations

from enum import IntEnum


class Exit(IntEnum):
    """What a command's exit status means (:data:`MEANINGS` says when each is given)."""

    OK = 0
    NOT_ACHIEVED = 1
    USAGE = 2
    REFUSED = 3
    ABORTED = 4
    NOT_THERE = 5
    INTERRUPTED = 130

    @property
    def label(self) -> str:
        """Its name in a JSON document: lower case (``out_of_tolerance`` for 1, as ``cell``
        has always named it)."""
        return _LABELS.get(self, self.name.lower())

    @property
    def meaning(self) -> str:
        """When it is given, in a sentence."""
        return MEANINGS[self]


_LABELS = {Exit.OK: 'success', Exit.NOT_ACHIEVED: 'out_of_tolerance'}

#: When each exit code is given.
MEANINGS = {
    Exit.OK: 'done as asked: settled within the tolerance, a valid check, a query answered, a '
             'setting taken, a file written, a run completed, a cell brought up (cell up) '
             'stopped cleanly',
    Exit.NOT_ACHIEVED: 'done, but short of what was asked: settled out of the tolerance, a move '
                       'of a run failed, the data did not identify the machine, an analysis '
                       'was partial, a fault trial missed its expectation, a node of cell up '
                       'did not stop cleanly, two mobility analyses disagreed',
    Exit.USAGE: 'the command line or a file it names cannot be used (argparse, a bad program, '
                'configuration or bag); nothing was sent',
    Exit.REFUSED: 'the cell refused, nothing moved (any refused_* code, a goal rejected, an '
                  'invalid check, a setting or jog refused, a tolerance stack-up refused)',
    Exit.ABORTED: 'aborted, the drives were stopped (any aborted_* code, a cancel, a procedure '
                  'the cell could not complete), or no outcome given',
    Exit.NOT_THERE: 'the cell is not there: a node, service, action server, status or answer '
                    'did not come within the time allowed, or the cell did not start',
    Exit.INTERRUPTED: 'SIGINT, SIGTERM or SIGHUP: the drives were stopped and what was '
                      'recorded kept',
}


def exit_table() -> str:
    """The table as text (``--help``)."""
    return '\n'.join(f'  {code.value:>3}  {code.label:<17} {code.meaning}' for code in Exit)


def markdown_table() -> str:
    """The table in Markdown (the docs' reference page)."""
    rows = [f'| {code.value} | `{code.label}` | {code.meaning} |' for code in Exit]
    return '\n'.join(['| exit | name | when |', '|---:|---|---|', *rows])


def procedure_exit(code: str, refused: bool = False) -> Exit:
    """The exit status of a procedure the cell ended with result ``code`` (its wire name, empty
    when there was none): refused (``refused``, or a refusal: nothing moved by that step),
    aborted (any other code), or the cell not there (no code: no answer, no readings)."""
    if refused or code.startswith('refused'):
        return Exit.REFUSED
    return Exit.ABORTED if code else Exit.NOT_THERE
