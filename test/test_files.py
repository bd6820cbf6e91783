"""Every file the cell reads by parameter or option goes through one checked, bounded reader
(positioning_cell.files): a named pipe, /dev/zero, a directory, a 100 MB file, a YAML alias
bomb and a missing file are refused by every kind of reader, quickly (a pipe or a device
would otherwise block or never end: pytest-timeout turns a hang into a failure), with the
reader's own error type and a short message naming the file; real files stay well within
the limits; the YAML loader refuses what could build without bound and keeps plain YAML.
"""

from __future__ import annotations

import ast
import os
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from workspace import MECH

from positioning_cell import files
from positioning_cell.accuracy.monitor import MonitorSettings
from positioning_cell.analysis.axis_test import load_axis_test
from positioning_cell.analysis.program import load_program
from positioning_cell.calibration import file as calfile
from positioning_cell.calibration.calibrated import calibrated_machine
from positioning_cell.config import config_path, load_parameter_file
from positioning_cell.errors import ConfigError
from positioning_cell.frames import file as frames_file
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.motion.settings import CALIBRATION_FILE, PositionerSettings, machine_settings
from positioning_cell.parameters import parse
from positioning_cell.prediction.sources import load_tolerance_spec
from positioning_cell.tolerance.model import load_mechanism
from positioning_cell.tools import predict_accuracy

REPO = Path(__file__).resolve().parent.parent
#: A refusal message is at most this long (the issue's bound; the reader's is 300).
MESSAGE_BOUND = 400

#: "Billion laughs": 9 levels of 9 aliases, 10^9 strings once expanded, 400-odd bytes.
ALIAS_BOMB = ('a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
              + ''.join(f'{b}: &{b} [{", ".join(["*" + a] * 9)}]\n'
                        for a, b in zip('abcdefgh', 'bcdefghi', strict=True)))


# -- the probes --------------------------------------------------------------------------------
def _fifo(tmp: Path) -> Path:
    path = tmp / 'pipe.yaml'
    os.mkfifo(path)  # no writer: opening it for reading would wait for one
    return path


def _bomb(tmp: Path) -> Path:
    path = tmp / 'bomb.yaml'
    path.write_text(ALIAS_BOMB)
    return path


def _huge(tmp: Path) -> Path:
    path = tmp / 'huge.yaml'
    with path.open('wb') as stream:
        stream.truncate(100 * files.MIB)  # sparse: no disk
    return path


def _directory(tmp: Path) -> Path:
    path = tmp / 'folder.yaml'
    path.mkdir()
    return path


PROBES: dict[str, tuple[Callable[[Path], Path], str]] = {
    'fifo': (_fifo, 'cannot be read (a named pipe, not a regular file)'),
    'dev_zero': (lambda tmp: Path('/dev/zero'), 'cannot be read (a character device, not a '
                                                'regular file)'),
    'alias_bomb': (_bomb, 'refused: '),
    'huge': (_huge, 'too large (100.0 MiB; a '),
    'directory': (_directory, 'cannot be read (a directory, not a regular file)'),
    'missing': (lambda tmp: tmp / 'missing.yaml', 'cannot be read (No such file or directory)'),
}


def _positioner_settings(path: Path) -> PositionerSettings:
    return parse(PositionerSettings, {CALIBRATION_FILE: str(path)})


#: Every reader of a file named by a parameter or option: (read it, its error type, the
#: kind its messages name).
READERS: dict[str, tuple[Callable[[Path], Any], type[ConfigError], str]] = {
    'calibration': (lambda p: calfile.load(p, MECH), calfile.CalibrationFileError,
                    'calibration file'),
    'positioner_calibration': (lambda p: calibrated_machine(_positioner_settings(p)),
                               calfile.CalibrationFileError, 'calibration file'),
    'coordinate_systems': (frames_file.load, frames_file.CoordinateSystemsFileError,
                           'coordinate systems file'),
    'parameter_file': (load_parameter_file, ConfigError, 'parameter file'),
    'program': (lambda p: load_program(p, MECH), ConfigError, 'parameter file'),
    'axis_test': (lambda p: load_axis_test(p, MECH), ConfigError, 'parameter file'),
    'tolerance_spec': (lambda p: load_tolerance_spec(p, MECH), ConfigError, 'parameter file'),
    'mechanism': (load_mechanism, ConfigError, 'mechanism file'),
    'monitor_settings': (MonitorSettings.from_file, ConfigError, 'parameter file'),
    'positioner_machine': (machine_settings, ConfigError, 'parameter file'),
    'predict_accuracy_config': (predict_accuracy.load_mechanism, ConfigError, 'parameter file'),
}


@pytest.fixture(params=sorted(PROBES))
def probe(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[str, Path, str]]:
    make, words = PROBES[request.param]
    yield request.param, make(tmp_path), words


@pytest.mark.timeout(60)
@pytest.mark.parametrize('reader', sorted(READERS))
def test_every_reader_refuses_every_probe_with_a_short_reason(
        reader: str, probe: tuple[str, Path, str]) -> None:
    read, error, kind = READERS[reader]
    name, path, words = probe
    if reader == 'coordinate_systems' and name == 'missing':
        assert read(path) == CoordinateSystems()  # nothing defined yet: the identity
        return
    with pytest.raises(error) as caught:
        read(path)
    text = str(caught.value)
    assert len(text) < MESSAGE_BOUND, (len(text), text[:500])
    assert f'{kind} ' in text and path.name in text and words in text, text


def test_the_alias_bomb_is_refused_at_the_alias_that_crosses_the_bound() -> None:
    assert len(ALIAS_BOMB) < 500
    with pytest.raises(ConfigError) as caught:
        files.parse_yaml(ALIAS_BOMB, 'bomb')
    assert str(caught.value) == ('bomb: refused: its aliases name more than 100000 nodes (an '
                                 'alias bomb) at line 6, column 8')
    # one level less names 9^5 = 59049 strings: within the bound, built as shared references
    small = ALIAS_BOMB.split('f:')[0]
    assert len(files.parse_yaml(small, 'small')['e']) == 9


# -- the reader --------------------------------------------------------------------------------
def test_a_file_at_its_kind_limit_is_read_and_one_byte_more_is_not(tmp_path: Path) -> None:
    kind = files.FileKind('test file', 64)
    path = tmp_path / 'f.yaml'
    path.write_bytes(b'a: ' + b'1' * 60 + b'\n')
    assert len(files.read_bytes(path, kind)) == 64  # type: ignore[arg-type]
    path.write_bytes(b'a: ' + b'1' * 61 + b'\n')
    with pytest.raises(ConfigError, match=r"^test file '.*f.yaml': too large \(65 bytes; a test "
                                          r'file may have at most 64 bytes\)$'):
        files.read_bytes(path, kind)


def test_a_missing_file_is_missing_only_when_allowed(tmp_path: Path) -> None:
    kind = files.FileKind('test file', 64)
    assert files.load_yaml(tmp_path / 'none.yaml', kind, missing_ok=True) is files.MISSING
    with pytest.raises(ConfigError, match='cannot be read'):
        files.load_yaml(tmp_path / 'none.yaml', kind)


def test_text_that_is_not_utf8_is_refused_naming_the_byte(tmp_path: Path) -> None:
    path = tmp_path / 'latin1.yaml'
    path.write_bytes('a: café'.encode('latin-1'))
    with pytest.raises(ConfigError, match=r'not UTF-8 text \(byte 0xe9 at offset 6\)'):
        files.load_yaml(path, files.PARAMETER_FILE)
    path.write_bytes('\ufeffa: café'.encode())  # a byte-order mark is fine
    assert files.load_yaml(path, files.PARAMETER_FILE) == {'a': 'café'}


def test_a_long_path_is_cut_in_the_middle() -> None:
    path = '/' + 'x' * 500 + '/calibration.yaml'
    shown = files.describe(files.CALIBRATION_FILE, path)
    assert len(shown) < files.PATH_CHARS + 25 and shown.endswith("calibration.yaml'")
    assert '…' in shown


# -- the YAML loader ---------------------------------------------------------------------------
@pytest.mark.parametrize(('text', 'words'), [
    ('a: &a [1]\n' + ''.join(f'k{i}: *a\n' for i in range(101)), 'more than 100 aliases'),
    ('a: &a [1, *a]\n', 'alias *a inside the node it names (a recursive structure)'),
    ('!!python/object/apply:os.system ["true"]\n', 'tag !!python/object/apply:os.system'),
    ('a: !!python/name:os.system\n', 'tag !!python/name:os.system'),
    ('a: !custom 1\n', 'tag !custom'),
    ('a: !!binary aGVsbG8=\n', 'tag !!binary'),
    ('[' * 51 + ']' * 51, 'nested more than 50 levels deep at line 1, column 51'),
])
def test_what_could_build_without_bound_is_refused(text: str, words: str) -> None:
    with pytest.raises(ConfigError) as caught:
        files.parse_yaml(text, 'f')
    assert str(caught.value).startswith('f: refused: ') and words in str(caught.value)


def test_plain_yaml_with_a_few_aliases_and_plain_tags_is_read() -> None:
    text = ('base: &base {x: 1.0, y: [1, 2]}\nuse: *base\nmerged: {<<: *base, z: 3}\n'
            "tagged: [!!float 1, !!str 2, !!int '3', !!bool 'true', !!null '']\n"
            'deep: ' + '[' * 49 + ']' * 49 + '\n')  # 50 levels with the top mapping
    data = files.parse_yaml(text, 'f')
    assert data['use'] == {'x': 1.0, 'y': [1, 2]}
    assert data['merged'] == {'x': 1.0, 'y': [1, 2], 'z': 3}
    assert data['tagged'] == [1.0, '2', 3, True, None]
    assert yaml.safe_load(text) == data  # the same values as PyYAML's safe loader


def test_without_libyaml_the_bounds_are_the_same(monkeypatch: pytest.MonkeyPatch) -> None:
    """PyYAML's own parser (a PyYAML built without libyaml) gives the composer the same
    events: the same refusals, the same values."""
    monkeypatch.setattr(files, '_EVENTS', yaml.SafeLoader)
    with pytest.raises(ConfigError, match='refused: its aliases name more than 100000 nodes'):
        files.parse_yaml(ALIAS_BOMB, 'bomb')
    with pytest.raises(ConfigError, match=r'refused: tag !!python/object/apply:os\.system'):
        files.parse_yaml('!!python/object/apply:os.system ["true"]\n', 'f')
    assert files.parse_yaml('a: &a [1.5, x]\nb: *a\n', 'f') == {'a': [1.5, 'x'],
                                                                'b': [1.5, 'x']}


@pytest.mark.parametrize(('text', 'words'), [
    ('a: [1, 2', "while parsing a flow sequence, did not find expected ',' or ']' at line 2"),
    ('a: 1\n---\nb: 2\n', 'expected a single document in the stream'),
    ('a: ' + '9' * 5000, 'Exceeds the limit (4300 digits)'),
    ('a: "' + 'x' * 100_000, 'found unexpected end of stream at line 1, column 100005'),
    ('a: *nowhere', "found undefined alias 'nowhere'"),
])
def test_invalid_yaml_is_refused_in_one_short_line(text: str, words: str) -> None:
    with pytest.raises(ConfigError) as caught:
        files.parse_yaml(text, 'f')
    message = str(caught.value)
    assert message.startswith('f: not valid YAML (') and words in message, message
    assert len(message) < 250 and '\n' not in message


def test_shipped_and_example_files_are_far_within_their_limits() -> None:
    """The limits are generous: every real file is under a tenth of its kind's."""
    for path in (REPO / 'config').glob('*.yaml'):
        assert path.stat().st_size * 10 < files.PARAMETER_FILE.max_bytes, path
        load_parameter_file(path)
    for path in (REPO / 'examples').glob('*.yaml'):
        assert path.stat().st_size * 10 < files.MECHANISM_FILE.max_bytes, path
        load_mechanism(path)


def test_a_real_calibration_file_is_far_within_its_limit(tmp_path: Path) -> None:
    from positioning_cell.calibration import parameters as cp

    params = {n: {'value': 1e-5, 'sigma': 1e-6, 'unit': cp.UNITS[k], 'identified': True}
              for k, n in enumerate(cp.PARAMETER_NAMES)}
    covariance = np.random.default_rng(0).normal(0.0, 1e-9, (cp.COUNT, cp.COUNT))
    body = {'format': calfile.FORMAT, 'mechanism_fingerprint': calfile.fingerprint(MECH),
            'date': '2026-01-01T00:00:00+00:00', 'program': {'poses': 60, 'hold_out': 20},
            'seating_force': 1.0, 'parameters': params,
            'covariance': (covariance @ covariance.T).tolist(),
            'residuals': {'chi2': 1.0, 'dof': 300, 'pose_position_um': [1.234] * 1000},
            'reference_temperature': 20.5,
            'model_error': {'length_m': 1.2345678e-6, 'theta_rad': 5.4321e-6}}
    path = calfile.write(tmp_path / 'calibration.yaml', {'calibration': body})
    assert path.stat().st_size * 5 < files.CALIBRATION_FILE.max_bytes
    assert calfile.load(path, MECH).x[0] == 1e-5


# -- messages ----------------------------------------------------------------------------------
def test_a_value_quoted_from_a_file_is_an_excerpt(tmp_path: Path) -> None:
    path = tmp_path / 'cs.yaml'
    path.write_text('coordinate_systems:\n  user: {position_m: "' + 'x' * 30_000 + '", '
                    'quaternion_xyzw: [0, 0, 0, 1]}\n  object: {position_m: [0, 0, 0], '
                    'quaternion_xyzw: [0, 0, 0, 1]}\n')
    with pytest.raises(frames_file.CoordinateSystemsFileError) as caught:
        frames_file.load(path)
    assert len(str(caught.value)) < 250 and 'expected a list of 3 numbers' in str(caught.value)
    shown = files.excerpt('y' * 1000)
    assert len(shown) == files.EXCERPT_CHARS and "'yyy" in shown and '...' in shown
    assert len(files.excerpt(list(range(10**5)))) <= files.EXCERPT_CHARS
    assert files.excerpt(10**5000) == '<int>'


def test_brief_errors_cuts_a_long_message_and_keeps_the_type() -> None:
    with pytest.raises(calfile.CalibrationFileError) as caught, files.brief_errors():
        raise calfile.CalibrationFileError('x' * 1000)
    assert len(str(caught.value)) == files.MESSAGE_CHARS and str(caught.value).endswith('…')


# -- time --------------------------------------------------------------------------------------
def test_within_gives_up_on_a_load_that_does_not_finish() -> None:
    release = threading.Event()
    with pytest.raises(calfile.CalibrationFileError,
                       match=r"^calibration file 'x': not loaded within 0.2 s"):
        files.within(0.2, lambda: release.wait(60.0), "calibration file 'x'",
                     calfile.CalibrationFileError)
    stopping = threading.Event()
    threading.Timer(0.2, stopping.set).start()
    with pytest.raises(ConfigError, match=r"^calibration file 'x': not loaded: the process "
                                          r'is stopping$'):
        files.within(60.0, lambda: release.wait(60.0), "calibration file 'x'", cancel=stopping)
    with pytest.raises(ConfigError, match='the process is stopping'):  # a later load too
        files.within(60.0, lambda: 42, 'w', cancel=stopping)
    release.set()
    assert files.within(5.0, lambda: 42, 'w') == 42
    with pytest.raises(ZeroDivisionError):
        files.within(5.0, lambda: 1 / 0, 'w')


def test_a_stopping_process_parses_no_further(monkeypatch: pytest.MonkeyPatch) -> None:
    """Once the process stops (abandon_loads: SIGINT / SIGTERM in a node), a parse stops at
    its next node: a large file read at a node's start does not hold its stop."""
    stopping = threading.Event()
    monkeypatch.setattr(files, '_STOPPING', stopping)
    assert files.parse_yaml('a: [1, 2]', 'f') == {'a': [1, 2]}
    files.abandon_loads()
    with pytest.raises(ConfigError, match=r'^f: not loaded: the process is stopping$'):
        files.parse_yaml('a: [1, 2]', 'f')


# -- one reader --------------------------------------------------------------------------------
def test_no_module_but_the_reader_parses_yaml() -> None:
    """Files named by parameters or options are parsed in positioning_cell/files.py only (the
    bag modules read the bags' own metadata)."""
    found = []
    for path in sorted((REPO / 'positioning_cell').rglob('*.py')):
        rel = path.relative_to(REPO).as_posix()
        if rel == 'positioning_cell/files.py' or rel.startswith('positioning_cell/bag/'):
            continue
        for node in ast.walk(ast.parse(path.read_text(), rel)):
            if isinstance(node, ast.Attribute) and node.attr in (
                    'safe_load', 'load', 'full_load', 'unsafe_load', 'load_all') and \
                    isinstance(node.value, ast.Name) and node.value.id == 'yaml':
                found.append(f'{rel}:{node.lineno} yaml.{node.attr}')
    assert not found, found
    # the rule can fail: the reader itself parses
    assert 'get_single_data' in (REPO / 'positioning_cell' / 'files.py').read_text()
    assert config_path('cell.yaml').is_file()
