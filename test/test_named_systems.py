"""Named coordinate systems (positioning_cell.frames.named) and their file
(positioning_cell.frames.file): several user and object systems by name, one active of each,
switched, persisted, and the single-system file of earlier versions read as "default"."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from positioning_cell.errors import InputError
from positioning_cell.frames import file as frames_file
from positioning_cell.frames.named import DEFAULT_NAME, MAX_SYSTEMS, NamedSystems
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.frames.transforms import Transform, distance

WORK = Transform.from_human([10, 0, 0, 0, 0, 90])
LEVELLING = Transform.from_human([0, 0, 0, 0.5, -0.2, 0])
TOOL = Transform.from_human([0, 0, 35, 0, 0, 0])


def test_define_select_and_set_the_active_values() -> None:
    named = NamedSystems().defined('user', 'work', WORK, activate=True)
    assert named.active_user == 'work' and named.active.user == WORK
    assert named.active.object == Transform.identity()
    named = named.defined('user', 'levelling', LEVELLING).defined('object', 'tool', TOOL)
    assert named.active_user == 'work' and named.active_object == DEFAULT_NAME
    named = named.selected(user='levelling', object='tool')
    assert named.active == CoordinateSystems(LEVELLING, TOOL)
    assert named.selected(object=DEFAULT_NAME).active_user == 'levelling'  # user unchanged
    moved = named.with_active(CoordinateSystems(WORK, TOOL))
    assert moved.users['levelling'] == WORK and moved.users['work'] == WORK


@pytest.mark.parametrize(('change', 'words'), [
    (lambda n: n.selected(user='nowhere'), "no user system named 'nowhere'; stored: default"),
    (lambda n: n.defined('user', '9lives', WORK), "user system name '9lives'"),
    (lambda n: n.defined('user', 'a' * 33, WORK), 'at most 32 characters'),
    (lambda n: n.defined('tool', 'x', WORK), "kind 'tool'"),
])
def test_bad_names_and_kinds_are_refused_and_change_nothing(change: object,
                                                           words: str) -> None:
    named = NamedSystems()
    with pytest.raises(InputError, match=words):
        change(named)  # type: ignore[operator]
    assert named == NamedSystems()


def test_at_most_so_many_systems_of_a_kind() -> None:
    named = NamedSystems()
    for i in range(MAX_SYSTEMS - 1):
        named = named.defined('user', f'u{i}', WORK)
    with pytest.raises(InputError, match=f'at most {MAX_SYSTEMS}'):
        named.defined('user', 'one_more', WORK)


def test_the_file_keeps_every_named_system_and_the_active_ones(tmp_path: Path) -> None:
    named = (NamedSystems().defined('user', 'work', WORK, activate=True)
             .defined('user', 'levelling', LEVELLING).defined('object', 'tool', TOOL,
                                                               activate=True))
    path = frames_file.write(tmp_path / 'cs.yaml', named)
    again = frames_file.load_named(path)
    assert again.active_user == 'work' and again.active_object == 'tool'
    assert set(again.users) == {DEFAULT_NAME, 'work', 'levelling'}
    for name, value in named.users.items():
        assert distance(again.users[name], value)[0] < 1e-15
    assert frames_file.load(path) == again.active  # what the single-pair reader sees


def test_a_single_system_file_reads_as_the_default_ones(tmp_path: Path) -> None:
    """The form of earlier versions (only user and object): both named "default"."""
    path = tmp_path / 'old.yaml'
    doc = frames_file.document(CoordinateSystems(WORK, TOOL))['coordinate_systems']
    path.write_text(yaml.safe_dump({'coordinate_systems': {'user': doc['user'],
                                                           'object': doc['object']}}))
    named = frames_file.load_named(path)
    assert (named.active_user, named.active_object) == (DEFAULT_NAME, DEFAULT_NAME)
    assert distance(named.active.user, WORK)[0] < 1e-15


def test_an_active_entry_that_disagrees_with_its_named_one_is_refused(tmp_path: Path) -> None:
    """A hand edit of one of the two copies: refused, naming both."""
    path = frames_file.write(tmp_path / 'cs.yaml',
                             NamedSystems().defined('user', 'work', WORK, activate=True))
    doc = yaml.safe_load(path.read_text())
    doc['coordinate_systems']['named']['user']['work']['position_m'][0] += 0.001
    doc['coordinate_systems']['named']['user']['work'].pop('human')
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(frames_file.CoordinateSystemsFileError,
                       match="user is not the active named system 'work'"):
        frames_file.load_named(path)
    doc['coordinate_systems']['active']['user'] = 'gone'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(frames_file.CoordinateSystemsFileError, match="'gone' is not one of"):
        frames_file.load_named(path)
