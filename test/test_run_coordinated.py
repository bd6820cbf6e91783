"""``run_cell --cell`` (issue 27): the coordinated cell run end to end as a command: two
positioners installed off their cell file, the cell calibrated from the panel's targets and
relaxed from the legs' load cells, a short panel program recorded and analysed into the
panel's ISO 9283 figures. Judged by what the command wrote (its exit status, the report) and
by the simulation's truth the analysis carries (the run folder's panel_report.json), and by
the legs' load cells against it."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest
import yaml
from cell_harness import CELL_YAML, executable, isolated_domain
from test_coordinated_cell import CELL_FILE, OVERRIDES
from test_panel_calibration import INSTALLATION, PANEL

from positioning_cell import names
from positioning_cell.config import load_parameter_file, merged
from positioning_cell.ros.processes import cell_environment
from positioning_cell.tools import run_cell

pytestmark = [pytest.mark.nodes, pytest.mark.slow]

#: Two poses, two cycles; the calibration on six poses (as test_panel_calibration's).
PROGRAM = {'panel_program': {'cycles': 2, 'readings': 5, 'speed_scale': 0.25},
           'poses': {'A': [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                     'B': [0.003, -0.002, 0.002, 0.002, -0.003, 0.002]},
           'panel_calibration': {'poses': 6, 'speed_scale': 0.25},
           # the machines are error-free (OVERRIDES): their own calibrations are left out
           'positioner_calibration': {'enabled': False}}


def _config(tmp_path: Path) -> Path:
    """config/cell.yaml with the coordination tests' overrides (exact machines, fast motion,
    liveness for a loaded machine) and the panel installed off its file."""
    doc = load_parameter_file(CELL_YAML)
    more = {**OVERRIDES, names.NODE_PANEL_SIMULATOR: {'installation': INSTALLATION}}
    doc = merged(doc, {node: {'ros__parameters': params} for node, params in more.items()})
    path = tmp_path / 'cell.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


def test_the_coordinated_cell_runs_end_to_end(tmp_path: Path) -> None:
    cell = tmp_path / 'two_positioners.yaml'
    cell.write_text(yaml.safe_dump({'cell': {**CELL_FILE['cell'], 'panel': PANEL}}))
    program = tmp_path / 'panel_program.yaml'
    program.write_text(yaml.safe_dump(PROGRAM))
    config = _config(tmp_path)  # its own liveness and timing after it too
    command = [executable('run_cell'), '--cell', str(cell), '--panel-program', str(program),
               '--config', str(config), '--cell-config', str(config),
               '--runs', str(tmp_path / 'runs')]
    with isolated_domain() as domain:  # the command takes a free domain of its own
        ran = subprocess.run(command, env=cell_environment(domain), capture_output=True,
                             text=True, timeout=400, check=False)
    said = ran.stdout.splitlines()
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert sum(line.startswith('panel pose ') for line in said) == 6, said
    assert sum(line.startswith('cycle ') for line in said) == 4, said
    (run_dir,) = (tmp_path / 'runs').iterdir()
    assert (run_dir / 'cell_calibration' / 'cell.yaml').is_file()
    report = json.loads((run_dir / 'panel_report.json').read_text())
    assert report['steps'] == 4 and report['failed'] == [] and report['same_as_live']
    assert report['poses'] == ['A', 'B']
    assert [f['n'] for f in report['measured']] == [2, 2]
    print(f"true errors {report['true_error_um']} um, tracker {report['tracker_error_um']} um; "
          f"moving {report['moving']}, at rest {report['at_rest']}")
    # the calibrated cell puts the panel where it is sent (test_panel_calibration's bound)
    assert max(report['true_error_um']) <= 30.0
    assert report['moving']['largest_stretch_um'] is not None
    # the strain the installation puts in the panel (bases and sockets off their file: ~1.9
    # kN here, the same at every pose, which no pose measurement shows): the legs' load cells
    # see it, and the relax from them takes it away once the panel is mounted, in steps (the
    # panel is 0.8 as stiff as its file: each leaves a fifth)
    mounted, calibrated = [line for line in said if line.startswith('relax from the load')]

    def trail(line: str) -> tuple[list[float], int]:
        found = re.search(r': success: relaxed by the load cells: internal force ([\d >-]+) N '
                          r'in (\d) moves', line)
        assert found is not None, line
        return [float(f) for f in found.group(1).split(' -> ')], int(found.group(2))

    assert mounted.startswith('relax from the load cells (mounted)'), mounted
    forces, moves = trail(mounted)
    assert forces[0] > 1000.0 and forces[-1] <= 50.0 and moves >= 2, mounted
    # the cell calibrated on the relaxed panel is strained again without the corrections
    # (seen: 1506 N), and the relax once calibrated takes it away again
    assert calibrated.startswith('relax from the load cells (calibrated)'), calibrated
    again, _ = trail(calibrated)
    assert again[-1] <= 50.0, calibrated
    # judged by the truth at every pose of the program: what is left is what the relaxes left
    # at their pose and what changes from pose to pose, which a relax at one pose leaves
    # (where the attachments were 375 um apart without the relax); and the load cells agree
    said_n, truth = max(report['load_cells_internal_n']), report['at_rest']['largest_force_n']
    assert truth <= 0.1 * max(forces[0], again[0]), (report['at_rest'], mounted, calibrated)
    # Both relaxes nearly always end at 11-13 N, their third move taking the 54-61 N their
    # second left (over `enough`, 50 N): then 26-58 N at rest, the attachments 7-15 um apart
    # (11 runs, Dec 7). A relax whose second move lands under 50 N ends there, within its
    # tolerance, and a calibration made on a panel still so strained leaves more from pose to
    # pose: with `enough` at 60 N (relaxes ending after two moves at 54-59 N) 83 and 112 N at
    # rest, 21 and 28 um, which the 10 % bound above holds. One CI run failed a plain 20 um
    # bound with 86 N, 21.6 um (its relax lines were not kept): of this kind, not of the
    # full relaxes' 26-58 N. The tighter bound is for the full relaxes.
    if max(forces[-1], again[-1]) <= 20.0:
        assert report['at_rest']['largest_stretch_um'] <= 20.0, (report['at_rest'], mounted,
                                                                 calibrated)
    assert len(report['load_cells_internal_n']) == 4
    assert abs(said_n - truth) <= 0.1 * truth + 10.0, (said_n, truth)
    table = (run_dir / 'panel_report.md').read_text()
    assert '| A | 2 |' in table and '| B | 2 |' in table


def test_the_cells_options_need_the_cell(capsys: pytest.CaptureFixture[str]) -> None:
    for option in ('--panel-program', '--cell-config'):
        with pytest.raises(SystemExit) as ended:
            run_cell.main([option, 'x.yaml'])
        assert ended.value.code == 2
        assert '--panel-program and --cell-config need --cell' in capsys.readouterr().err
