"""The static compliance test (ISO 9283:1998 §10; a program's ``compliance:`` block, run by
``run_cell`` after the program's moves): pure library (no ROS).

- the test as the program gives it (:class:`ComplianceTest`): the pose, the largest load, its
  steps, the directions, the readings per step;
- the marker published on ``/cell/compliance_test`` per load step (:class:`ComplianceMarker`,
  JSON), as the procedure (:mod:`positioning_cell.procedures.compliance_test`) sends it and a
  bag keeps it;
- from markers, the compliance per run and direction with its U
  (:func:`compliance_results`, :mod:`positioning_cell.accuracy.compliance`), its JSON and its
  Markdown table.

At each step the load rig pushes the platform origin with the step's load along the direction
(base frame) while the drives hold the pose; the averaged tracker position and the
independent part of its covariance (the readings' own noise, without the registration they
share) are the marker's.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from positioning_cell.accuracy.compliance import DIRECTIONS, Compliance, static_compliance
from positioning_cell.analysis.tables import markdown_table
from positioning_cell.errors import InputError
from positioning_cell.parameters import ParameterError, check_fields, setting

#: The standard's clause.
CLAUSE = '10'


@dataclass(frozen=True)
class ComplianceTest:
    """A program's ``compliance:`` block: at program pose ``pose``, per load direction of
    ``directions`` (``+x`` … ``-z``, base frame), the load stepped from 0 to ``load`` N in
    ``steps`` equal steps (ISO 9283 §10: 10 % of the rated load each), ``dwell`` s at rest
    after each step, then ``samples`` tracker readings averaged; ``force_accuracy`` the load
    rig's stated accuracy (a share of the load, a bound)."""

    pose: str = setting('P1', 'the program pose the test loads the platform at')
    load: float = setting(60.0, 'the largest load (the rated load)', 'N', low=0.0,
                          low_open=True, high=1e5)
    steps: int = setting(10, 'load steps up to the largest', low=2, high=100)
    directions: tuple[str, ...] = setting(tuple(DIRECTIONS), 'load directions, base frame '
                                          '(+x, -x, +y, -y, +z, -z)')
    samples: int = setting(10, 'tracker readings averaged per step', low=1, high=1000)
    dwell: float = setting(0.1, 'rest after each load step before its readings', 's', low=0.0,
                           high=60.0)
    force_accuracy: float = setting(0.005, 'the load rig\'s stated accuracy, share of the '
                                    'load (a bound)', '1', low=0.0, high=0.2)

    def __post_init__(self) -> None:
        check_fields(self)
        if (not self.directions or len(set(self.directions)) != len(self.directions)
                or any(d not in DIRECTIONS for d in self.directions)):
            raise ParameterError('directions', list(self.directions),
                                 f'expected distinct directions from {", ".join(DIRECTIONS)}')

    def loads(self) -> list[float]:
        """The load of each step, N: 0 (unloaded) then ``load``/``steps`` up to ``load``."""
        return [self.load * k / self.steps for k in range(self.steps + 1)]

    @property
    def measured_steps(self) -> int:
        """Steps measured in the whole test (the unloaded one of each direction included)."""
        return len(self.directions) * (self.steps + 1)


@dataclass(frozen=True)
class ComplianceMarker:
    """One measured load step, as published on ``/cell/compliance_test`` (JSON): the ``run``
    (its start, UTC ISO 8601), the program ``pose``, the ``direction`` and ``step`` (0: no
    load), the ``load`` N along the direction, the averaged tracker ``position`` (3,) m and
    the independent part of its ``covariance`` (3, 3) m² (base frame), the window of readings
    ``start`` … ``end`` s and their number ``samples``, and the rig's ``force_accuracy``."""

    run: str
    pose: str
    direction: str
    step: int
    load: float
    position: tuple[float, float, float]
    covariance: tuple[tuple[float, ...], ...]
    start: float
    end: float
    samples: int
    force_accuracy: float

    def to_json(self) -> str:
        """The JSON text published on /cell/compliance_test."""
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> ComplianceMarker:
        """A marker from its JSON (InputError naming what is wrong)."""
        try:
            d = json.loads(text)
            position = np.asarray(d['position'], dtype=float)
            covariance = np.asarray(d['covariance'], dtype=float)
            marker = cls(str(d['run']), str(d['pose']), str(d['direction']), int(d['step']),
                         float(d['load']), tuple(position.tolist()),
                         tuple(tuple(r) for r in covariance.tolist()), float(d['start']),
                         float(d['end']), int(d['samples']), float(d['force_accuracy']))
        except (ValueError, KeyError, TypeError) as err:
            raise InputError(f'not a compliance-test marker: {text[:80]!r} ({err})') from None
        numbers = [marker.load, marker.start, marker.end, marker.force_accuracy,
                   *position.ravel(), *covariance.ravel()]
        why = ('unknown direction' if marker.direction not in DIRECTIONS
               else 'position not 3 numbers or covariance not 3 x 3' if (
                   position.shape != (3,) or covariance.shape != (3, 3))
               else 'a value is not finite' if not all(map(math.isfinite, numbers))
               else 'step, samples, load or force accuracy out of range' if (
                   marker.step < 0 or marker.samples < 1 or marker.load < 0.0
                   or marker.force_accuracy < 0.0)
               else '')
        if why:
            raise InputError(f'not a compliance-test marker ({why}): {text[:80]!r}')
        return marker


def parse_markers(texts: Sequence[str]) -> tuple[list[ComplianceMarker], list[str]]:
    """Markers from /cell/compliance_test message texts, and a line per text that is not
    one."""
    markers, problems = [], []
    for text in texts:
        try:
            markers.append(ComplianceMarker.from_json(text))
        except InputError as err:
            problems.append(str(err))
    return markers, problems


@dataclass(frozen=True, eq=False)
class ComplianceResult:
    """The compliance of one direction of one test ``run`` at ``pose``."""

    run: str
    pose: str
    direction: str
    figures: Compliance

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI: m/N, m, N)."""
        f = self.figures
        return {'run': self.run, 'pose': self.pose, 'direction': self.direction,
                'compliance': f.compliance, 'u_compliance': f.u_compliance, 'along': f.along,
                'slope': f.slope.tolist(), 'nonlinearity': f.nonlinearity,
                'largest_load': f.largest_load, 'steps': f.steps}


def compliance_results(markers: Sequence[ComplianceMarker]
                       ) -> tuple[tuple[ComplianceResult, ...], list[str]]:
    """The compliance of each run's directions, in the order measured, and a line per
    direction whose steps give none (fewer than two loads), naming it."""
    groups: dict[tuple[str, str], list[ComplianceMarker]] = {}
    for marker in sorted(markers, key=lambda m: m.start):
        groups.setdefault((marker.run, marker.direction), []).append(marker)
    results, problems = [], []
    for (run, direction), steps in groups.items():
        try:
            figures = static_compliance(
                DIRECTIONS[direction], [m.load for m in steps], [m.position for m in steps],
                [m.covariance for m in steps], max(m.force_accuracy for m in steps))
        except InputError as err:
            problems.append(f'compliance test {run}, {direction}: {err}')
            continue
        results.append(ComplianceResult(run, steps[0].pose, direction, figures))
    return tuple(results), problems


#: The compliance table's header (µm/N, µm, N).
HEADER = ('direction', 'pose', 'largest load (N)', 'steps', 'compliance ± U (µm/N)',
          'along the load (µm/N)', 'slope x, y, z (µm/N)', 'off the line (µm)')


def markdown(results: Sequence[ComplianceResult]) -> list[str]:
    """The table of ``results`` (one row per direction), for people."""
    return markdown_table(HEADER, [
        [r.direction, r.pose, f'{r.figures.largest_load:.1f}', str(r.figures.steps),
         f'{r.figures.compliance * 1e6:.4f} ± {r.figures.u_compliance * 1e6:.4f}',
         f'{r.figures.along * 1e6:+.4f}',
         ', '.join(f'{v * 1e6:+.4f}' for v in r.figures.slope),
         f'{r.figures.nonlinearity * 1e6:.2f}'] for r in results])
