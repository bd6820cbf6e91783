"""The ``tolerance_analysis`` command: exit codes (0 done, 2 bad input with nothing written,
3 refused with the reason printed and in the report) and what the report holds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from positioning_cell.tools.exits import Exit
from positioning_cell.tools.tolerance_analysis import main

EXAMPLES = Path(__file__).resolve().parent.parent / 'examples'


def test_an_analysis_writes_the_report_and_figures(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'flap'
    code = main([str(EXAMPLES / 'seed004_flap_variant.yaml'), '--out', str(out), '--samples',
                 '20000', '--seed', '3', '--check-derivatives'])
    assert code == Exit.OK
    printed = capsys.readouterr().out
    assert 'Gap: nominal 285 mm, worst case ± 6.318 mm' in printed and 'wrote:' in printed
    assert sorted(p.name for p in out.iterdir()) == [
        'analysis.json', 'distribution_Gap.png', 'pareto_Gap.png', 'report.md']
    report = (out / 'report.md').read_text()
    for fragment in ('## Summary', '| Gap | 285 mm | 280 mm … 290 mm | ± 6.318 mm',
                     '## Gap: sensitivities and contributions', '| b | 2.60365 mm/deg | ± 1 deg |',
                     '![pareto_Gap.png](pareto_Gap.png)', '**T = C − D·U⁻¹·A**',
                     '## Monte Carlo (nonlinear loop closure)', '20000 samples (seed 3)',
                     '## Derivatives', '## Gap connectors (seed 004 §2)',
                     'follows translation (cw): α = 180 deg + a8 − 45° (seed 004 eq. 3)'):
        assert fragment in report, fragment
    data = json.loads((out / 'analysis.json').read_text())
    assert data['refusal'] is None and data['units'] == 'SI (m, rad)'
    gap = data['dimensions'][0]
    assert gap['name'] == 'Gap' and gap['nominal'] == pytest.approx(0.285)
    assert gap['yield']['trials'] == 20000
    assert sorted(gap['contributions']['order'][:2]) == ['a8', 'b']
    assert data['derivatives']['max_rel'] < 1e-6
    assert len(data['linearisation']['T'][0]) == 15


def test_bad_input_exits_2_naming_file_key_and_value_and_writes_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / 'bad.yaml'
    bad.write_text((EXAMPLES / 'four_bar.yaml').read_text().replace(
        'angle: theta3, label: coupler', 'angle: theta33, label: coupler'))
    out = tmp_path / 'out'
    assert main([str(bad), '--out', str(out)]) == Exit.USAGE
    err = capsys.readouterr().err
    assert f"{bad}: closed_loops.four_bar.vectors[1].angle = 'theta33'" in err
    assert "unknown symbol 'theta33'" in err
    assert not out.exists()
    assert main([str(tmp_path / 'missing.yaml'), '--out', str(out)]) == Exit.USAGE
    assert 'missing.yaml' in capsys.readouterr().err and not out.exists()
    assert main([str(EXAMPLES / 'four_bar.yaml'), '--out', str(out), '--samples',
                 '-1']) == Exit.USAGE
    assert not out.exists()
    with pytest.raises(SystemExit) as usage:
        main([str(EXAMPLES / 'four_bar.yaml')])   # --out is required
    assert usage.value.code == Exit.USAGE


def test_a_refused_analysis_exits_3_with_the_reason_in_the_report(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'printed'
    assert main([str(EXAMPLES / 'seed004_flap.yaml'), '--out', str(out)]) == Exit.REFUSED
    err = capsys.readouterr().err
    assert 'refused: U = dh/du is singular' in err and 'u2, u3' in err
    report = (out / 'report.md').read_text()
    assert '**The analysis is refused**' in report
    assert 'equations flap: x, flap: y, flap: theta are dependent' in report
    assert '**U = ∂h/∂u**' in report and 'Singular values of U' in report
    assert '| flap: x | 1621.8 mm |' in report   # the residual at the printed nominal
    data = json.loads((out / 'analysis.json').read_text())
    assert 'u2, u3' in data['refusal'] and data['dimensions'] == []
    assert not list(out.glob('*.png'))


def test_no_samples_and_no_plots(tmp_path: Path) -> None:
    out = tmp_path / 'lin'
    assert main([str(EXAMPLES / 'four_bar.yaml'), '--out', str(out), '--samples', '0',
                 '--no-plots']) == Exit.OK
    assert sorted(p.name for p in out.iterdir()) == ['analysis.json', 'report.md']
    report = (out / 'report.md').read_text()
    assert 'Monte Carlo (nonlinear' not in report and '± 0.17086 deg' in report
