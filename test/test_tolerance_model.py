"""The mechanism format (positioning_cell.tolerance.model, .expressions): affine expressions
with units, the loader's structure and every refusal with the file, key and value named."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest

from positioning_cell.errors import ConfigError
from positioning_cell.tolerance.expressions import ANGLE, LENGTH, parse_affine, parse_quantity
from positioning_cell.tolerance.model import load_mechanism, parse_mechanism

BASE: dict[str, Any] = {
    'name': 'four-bar',
    'units': {'length': 'mm'},
    'inputs': {'theta2': '60 deg'},
    'sources': {'r1': {'nominal': 100, 'tolerance': 0.05},
                'r2': {'nominal': 40, 'tolerance': 0.05, 'distribution': 'uniform'},
                'r3': {'nominal': 90, 'tolerance': 0.05},
                'r4': {'nominal': 70, 'tolerance': 0.05},
                'g': {'nominal': '0 deg', 'tolerance': '0.1 deg', 'sigmas': 2}},
    'unknowns': {'theta3': '20 deg', 'theta4': '80 deg'},
    'closed_loops': {'loop': {'vectors': [
        {'length': 'r2', 'angle': 'theta2 + g'}, {'length': 'r3', 'angle': 'theta3'},
        {'length': '-r4', 'angle': 'theta4'}, {'length': '-r1', 'angle': 'g'}]}},
    'open_loops': {'rocker': {'expression': 'theta4', 'requirement': {'tolerance': '0.2 deg'}}},
}


def variant(**changes: Any) -> dict[str, Any]:
    """BASE with top-level keys replaced (None deletes)."""
    data = copy.deepcopy(BASE)
    for key, value in changes.items():
        if value is None:
            data.pop(key)
        else:
            data[key] = value
    return data


def refused(data: Any, *fragments: str) -> str:
    with pytest.raises(ConfigError) as info:
        parse_mechanism(data, 'mech.yaml')
    message = str(info.value)
    assert message.startswith('mech.yaml: '), message
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_expressions_are_affine_with_units_in_si() -> None:
    symbols = {'a8': ANGLE, 'u1': ANGLE, 'r': LENGTH, 's': LENGTH}
    e = parse_affine('45 deg - a8', symbols, 'k', length_scale=1e-3)
    assert e.dimension == ANGLE and e.terms == (('a8', -1.0),)
    assert e.constant == pytest.approx(math.pi / 4, abs=1e-15)
    e = parse_affine('0.5 * (r + s) - 2 - s/4 + 3 mm', symbols, 'k', length_scale=1e-3)
    assert dict(e.terms) == {'r': 0.5, 's': 0.25} and e.constant == pytest.approx(1e-3)
    assert parse_affine('-(r)', symbols, 'k', length_scale=1.0).terms == (('r', -1.0),)
    assert parse_affine('2*u1 + 90deg', symbols, 'k', length_scale=1.0).constant == \
        pytest.approx(math.pi / 2)
    assert parse_quantity(85, 'k', length_scale=1e-3).constant == pytest.approx(0.085)
    assert parse_quantity('0.085 m', 'k', length_scale=1e-3).constant == pytest.approx(0.085)
    assert parse_quantity('1 rad', 'k', length_scale=1e-3).dimension == ANGLE
    assert parse_affine('0', symbols, 'k', length_scale=1e-3, expect=ANGLE).constant == 0.0
    derived = {'alpha': parse_affine('u1 + 90 deg', symbols, 'k', length_scale=1.0)}
    e = parse_affine('180 deg - alpha', {**symbols, **derived}, 'k', length_scale=1.0)
    assert e.terms == (('u1', -1.0),) and e.constant == pytest.approx(math.pi / 2)


@pytest.mark.parametrize(('text', 'why'), [
    ('a8 + r', 'mixes lengths and angles'),
    ('a8 + 5', 'needs a unit'),
    ('a8 * u1', 'not affine'),
    ('r / s', 'division only by a non-zero plain number'),
    ('r / 0', 'division only by a non-zero plain number'),
    ('deg', 'without a number'),
    ('r + nan', 'not a finite number'),
    ('r + x9', "unknown symbol 'x9'"),
    ('(r + s', 'missing )'),
    ('r + ', 'unexpected end'),
    ('r $ s', "unexpected character '$'"),
    ('', 'empty expression'),
])
def test_bad_expressions_are_refused_with_key_and_text(text: str, why: str) -> None:
    symbols = {'a8': ANGLE, 'u1': ANGLE, 'r': LENGTH, 's': LENGTH}
    with pytest.raises(ConfigError) as info:
        parse_affine(text, symbols, 'f.yaml: loops.x.angle', length_scale=1e-3)
    assert str(info.value).startswith(f'f.yaml: loops.x.angle = {text!r}: ')
    assert why in str(info.value)


def test_the_loader_builds_the_mechanism_in_si() -> None:
    mech = parse_mechanism(BASE, 'mech.yaml')
    assert mech.source_names == ('r1', 'r2', 'r3', 'r4', 'g')
    assert mech.unknown_names == ('theta3', 'theta4')
    assert mech.equation_names == ('loop: x', 'loop: y')
    assert mech.sources[0].nominal == pytest.approx(0.1)
    assert mech.sources[0].tolerance == pytest.approx(5e-5)
    assert mech.sources[1].distribution == 'uniform'
    assert mech.sources[1].std == pytest.approx(5e-5 / math.sqrt(3.0))
    assert mech.sources[4].sigmas == 2.0 and mech.sources[4].dimension == ANGLE
    assert mech.sources[4].std < math.radians(0.1) / 2.0   # truncated at 2σ: below t/2
    assert mech.unknowns[0].guess == pytest.approx(math.radians(20.0))
    req = mech.open_loops[0].requirement
    assert req is not None and req.upper == pytest.approx(math.radians(0.2)) == -req.lower
    assert mech.with_inputs(theta2=1.0).inputs[0].value == 1.0
    with pytest.raises(ConfigError, match='no input'):
        mech.with_inputs(theta9=1.0)


def test_gap_connectors_follow_seed_004_rules() -> None:
    data = variant(gaps={
        'r12': {'clearance': {'nominal': 0.5, 'tolerance': 0.01}, 'follows': 'rotation',
                'input': 'theta2', 'sense': 'cw'},
        'r23': {'clearance': {'nominal': 0.5, 'tolerance': 0.01}, 'follows': 'rotation',
                'input': 'theta2', 'sense': 'ccw', 'alpha': 'a23'},
        'r34': {'radii': ['r3', 'r4'], 'follows': 'translation', 'input': '180 deg + g',
                'sense': 'cw'},
        'r56': {'clearance': {'nominal': 1.5, 'tolerance': 0.02}, 'load': '270 deg'}})
    data['closed_loops']['loop']['vectors'].append({'gap': 'r12'})
    data['open_loops']['y'] = {'vectors': [{'gap': 'r23', 'angle': '180 deg - a23'},
                                           {'gap': 'r34'}, {'gap': 'r56'}], 'component': 'y'}
    mech = parse_mechanism(data, 'mech.yaml')
    gaps = {g.name: g for g in mech.gaps}
    values = {'theta2': math.radians(60.0)}
    assert gaps['r12'].alpha.terms == (('theta2', 1.0),)
    assert gaps['r12'].alpha.evaluate(values) == pytest.approx(math.radians(-30.0))  # eq. 2, cw
    assert gaps['r23'].alpha_name == 'a23'
    assert gaps['r23'].alpha.evaluate(values) == pytest.approx(math.radians(150.0))  # ccw
    assert gaps['r34'].alpha.terms == (('g', 1.0),)                             # eq. 3, cw
    assert gaps['r34'].alpha.constant == pytest.approx(math.radians(135.0))
    assert dict(gaps['r34'].length.terms) == {'r3': 1.0, 'r4': -1.0}             # eq. 1
    assert gaps['r56'].alpha.constant == pytest.approx(math.radians(270.0))
    assert 'r12' in mech.source_names and 'r34' not in mech.source_names
    assert mech.sources[mech.source_names.index('r12')].origin == 'gap r12'
    loop_gap = mech.closed_loops[0].vectors[-1]
    assert loop_gap.length.terms == (('r12', 1.0),) and loop_gap.azimuth == gaps['r12'].alpha
    assert mech.open_loops[1].vectors[0].azimuth.evaluate(values) == pytest.approx(
        math.radians(30.0))


def test_spatial_vectors() -> None:
    data = variant(space='spatial', unknowns={'l': 100, 'az': '10 deg', 'el': '20 deg'},
                   closed_loops={'leg': {'vectors': [
                       {'length': 'r1', 'direction': [1, 1, 0]},
                       {'length': 'l', 'azimuth': 'az', 'elevation': 'el'},
                       {'length': '-r2', 'azimuth': 'theta2', 'elevation': 'g'}]}},
                   open_loops=None)
    mech = parse_mechanism(data, 'mech.yaml')
    assert mech.equation_names == ('leg: x', 'leg: y', 'leg: z')
    fixed = mech.closed_loops[0].vectors[0]
    assert fixed.azimuth.constant == pytest.approx(math.pi / 4) and fixed.elevation.constant == 0
    refused(variant(space='spatial'), "closed_loops.loop.vectors[0]",
            'a spatial vector has azimuth and elevation')


def test_a_file_is_read_and_its_name_is_in_every_error(tmp_path: Path) -> None:
    import yaml

    path = tmp_path / 'm.yaml'
    path.write_text(yaml.safe_dump(BASE))
    assert load_mechanism(path).origin == str(path)
    path.write_text(yaml.safe_dump(variant(space='curved')))
    with pytest.raises(ConfigError, match=f"^{path}: space = 'curved'"):
        load_mechanism(path)
    path.write_text('a: [1, 2')
    with pytest.raises(ConfigError,
                       match=f"^mechanism file '{path}': not valid YAML \\(while parsing"):
        load_mechanism(path)
    path.write_text('- 1\n- 2\n')
    with pytest.raises(ConfigError, match=f"^mechanism file '{path}': expected a mapping"):
        load_mechanism(path)
    with pytest.raises(ConfigError, match='cannot be read'):
        load_mechanism(tmp_path / 'missing.yaml')


def with_source(**spec: Any) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    data['sources']['r1'] = spec
    return data


def with_vector(index: int, **spec: Any) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    data['closed_loops']['loop']['vectors'][index] = spec
    return data


@pytest.mark.parametrize(('data', 'fragments'), [
    # unknown symbols
    (with_vector(1, length='r3', angle='theta9'),
     ("closed_loops.loop.vectors[1].angle = 'theta9'", "unknown symbol 'theta9'")),
    (with_vector(0, gap='r99'), ("closed_loops.loop.vectors[0].gap = 'r99'",
                                 'not a gap connector')),
    # missing keys
    (variant(units=None), ("file: missing key 'units'",)),
    (variant(unknowns=None), ("file: missing key 'unknowns'",)),
    (with_source(nominal=100), ("sources.r1: missing key 'tolerance'",)),
    (with_vector(1, length='r3'), ("closed_loops.loop.vectors[1]: missing key 'angle'",)),
    (with_vector(1, angle='theta3'), ("closed_loops.loop.vectors[1]: missing key 'length'",)),
    # units
    (variant(units={'length': 'inch'}), ("units.length = 'inch'", 'expected one of mm, m')),
    (with_source(nominal='9 deg', tolerance=1), ('sources.r1.tolerance = 1',
                                                'bad unit', 'deg or rad')),
    (with_source(nominal=100, tolerance='1 deg'), ("sources.r1.tolerance = '1 deg'",
                                                  'is an angle, expected a length')),
    (with_vector(1, length='r3', angle='theta3 + 5'),
     ("vectors[1].angle = 'theta3 + 5'", 'needs a unit')),
    (with_vector(1, length='theta3', angle='theta3'),
     ("vectors[1].length = 'theta3'", 'is an angle, expected a length')),
    # not finite
    (with_source(nominal=float('nan'), tolerance=0.1), ('sources.r1.nominal = nan',
                                                        'not a finite number')),
    (with_source(nominal=100, tolerance=float('inf')), ('sources.r1.tolerance = inf',
                                                        'not a finite number')),
    (with_source(nominal='nan mm', tolerance=0.1), ("sources.r1.nominal = 'nan mm'",
                                                    'not a finite number')),
    # negative tolerance, bad law
    (with_source(nominal=100, tolerance=-0.1), ('sources.r1.tolerance = -0.1', '>= 0')),
    (with_source(nominal=100, tolerance=0.1, distribution='cauchy'),
     ("sources.r1.distribution = 'cauchy'", 'normal, uniform')),
    (with_source(nominal=100, tolerance=0.1, sigmas=0), ('sources.r1.sigmas = 0', '> 0')),
    (with_source(nominal=100, tolerance=0.1, distribution='uniform', sigmas=3),
     ('sources.r1.sigmas = 3', 'only a normal law')),
    # counts of unknowns and equations
    (variant(unknowns={'theta3': '20 deg', 'theta4': '80 deg', 'theta5': '0 deg'}),
     ('closed_loops: 2 closure equations (loop: x, loop: y) for 3 unknowns '
      '(theta3, theta4, theta5)',)),
    (variant(closed_loops={'loop': {**BASE['closed_loops']['loop'],
                                    'equations': {'extra': 'theta3 - theta4'}}}),
     ('3 closure equations (loop: x, loop: y, loop: extra) for 2 unknowns',)),
    # structure
    (variant(sources={'r1': {'nominal': 1, 'tolerance': 0, 'tolerence': 1}}),
     ("sources.r1: unknown key 'tolerence'",)),
    (variant(extra=1), ("file: unknown key 'extra'",)),
    (variant(inputs={'r1': 5}), ("sources.r1 = 'r1'", 'already declared as an input')),
    (variant(inputs={'deg': 5}), ("inputs.deg = 'deg'", 'reserved')),
    (variant(inputs={'2x': 5}), ("inputs.2x = '2x'", 'identifier')),
    (variant(space='spatial'), ('a spatial vector',)),
    (with_vector(1, length='r3', azimuth='theta3'), ('azimuth is for a spatial mechanism',)),
    (variant(gaps={'r12': {'clearance': {'nominal': 0.5, 'tolerance': 0.01}}}),
     ('gaps.r12: give one of follows',)),
    (variant(gaps={'r12': {'clearance': {'nominal': 0.5, 'tolerance': 0.01},
                           'follows': 'rotation', 'input': 'theta2', 'sense': 'left'}}),
     ("gaps.r12.sense = 'left'", 'ccw or cw')),
    (variant(gaps={'r12': {'clearance': {'nominal': 0.5, 'tolerance': 0.01},
                           'follows': 'rotation', 'input': 'theta2'}}),
     ("gaps.r12: missing key 'sense'",)),
    (variant(open_loops={'o': {'vectors': [{'length': 'r1', 'angle': '0 deg'}]}}),
     ('open_loops.o.component = None',)),
    (variant(open_loops={'o': {'expression': 'theta4', 'requirement': {'lower': 1}}}),
     ('open_loops.o.requirement: give tolerance, or lower and upper',)),
    (variant(open_loops={'o': {'expression': 'theta4',
                               'requirement': {'tolerance': '-1 deg'}}}),
     ("open_loops.o.requirement.tolerance = '-1 deg'", 'must be > 0')),
    (variant(unknowns={'theta3': '20 deg', 'theta4': '80 deg'},
             closed_loops={'loop': {'vectors': [{'length': 'r2', 'angle': 'theta3'}],
                                    'components': ['x'], 'equations': ['theta2 - theta3']}}),
     ('unknowns.theta4: appears in no closed loop',)),
])
def test_every_refusal_names_the_key_and_value(data: dict[str, Any],
                                               fragments: tuple[str, ...]) -> None:
    refused(data, *fragments)
