"""What the positioner says of its inputs: which nodes besides their sources publish on them
(their messages are ignored, :class:`positioning_cell.ros.latest.SourceReader`)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence


def inputs_report(foreign: Mapping[str, Sequence[str]],
                  sources: Iterable[str]) -> tuple[str, str, dict[str, str]]:
    """(level, message, values) of the ``positioner: inputs`` status: ERROR naming every
    second publisher per topic (``foreign``: topic → nodes other than its source), else OK
    naming the ``sources``; the values: per topic the other nodes, space-separated."""
    values = {topic: ' '.join(nodes) for topic, nodes in foreign.items()}
    others = {topic: nodes for topic, nodes in foreign.items() if nodes}
    if not others:
        return 'ok', 'inputs from ' + ' and '.join(sorted(set(sources))), values
    message = '; '.join(f'second publisher on {topic}: {", ".join(nodes)}'
                        for topic, nodes in others.items()) + ' (ignored)'
    return 'error', message, values
