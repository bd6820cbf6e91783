"""Self-describing bags (issue 26, item 7): the writer's metadata and attachment records read
back by the mcap library itself (an independent reader) and by rosbags, in every file of a
split and through a recovery; the run description a launcher writes and the recorder stores;
the calibrations the positioner takes, followed on /diagnostics; a bag's run kind and the
fleet's selection by key."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from positioning_cell import names
from positioning_cell.analysis.fleet import (
    ABORTED_RUN,
    INTERACTIVE_RUN,
    PROGRAM_RUN,
    RunDigest,
    digest_bag,
    run_kind,
    select_bags,
)
from positioning_cell.analysis.program import ProgramStep
from positioning_cell.bag.description import (
    CALIBRATION_RECORD,
    MAX_ATTACHMENT_BYTES,
    RUN_RECORD,
    Attachment,
    MetadataRecord,
    bag_description,
    parse_where,
)
from positioning_cell.bag.errors import BagError
from positioning_cell.bag.recovery import recover_bag
from positioning_cell.bag.settings import RecorderSettings
from positioning_cell.bag.verify import storage_files, verify_bag
from positioning_cell.bag.writer import BagWriter
from positioning_cell.config import config_path
from positioning_cell.errors import ConfigError
from positioning_cell.recording.description import (
    DESCRIPTION_FILE,
    CalibrationWatch,
    load_description,
    mechanism_fingerprint,
    write_description_file,
)
from positioning_cell.recording.recorder import Recorder
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag

STRING = 'std_msgs/msg/String'
T0 = 1_780_000_000_000_000_000  # ns
STORE = get_typestore(Stores.ROS2_JAZZY)


def _text(i: int) -> bytes:
    return bytes(STORE.serialize_cdr(STORE.types[STRING](data=f'message {i}'), STRING))


def _diagnostics(calibration: str, name: str = names.STATUS_POSITIONER) -> bytes:
    t = STORE.types
    status = t['diagnostic_msgs/msg/DiagnosticStatus'](
        level=0, name=name, message='settled', hardware_id='cell',
        values=[t['diagnostic_msgs/msg/KeyValue']('calibration', calibration),
                t['diagnostic_msgs/msg/KeyValue']('mode', 'model')])
    array = t['diagnostic_msgs/msg/DiagnosticArray'](
        header=t['std_msgs/msg/Header'](stamp=t['builtin_interfaces/msg/Time'](1, 0),
                                        frame_id=''), status=[status])
    return bytes(STORE.serialize_cdr(array, 'diagnostic_msgs/msg/DiagnosticArray'))


RUN = MetadataRecord(RUN_RECORD, {'kind': 'program', 'program_moves': '30'})
CONFIG = Attachment('config/cell.yaml', 'application/yaml', b'a: 1\n', T0)
LATER = MetadataRecord(CALIBRATION_RECORD, {'calibration_file': 'cal.yaml'})
CAL = Attachment('calibration/cal.yaml', 'application/yaml', b'x: [1, 2]\n', T0 + 500)


def _bag(path: Path, split_bytes: int = 0, messages: int = 1000) -> Path:
    with BagWriter(path, split_max_bytes=split_bytes, chunk_bytes=1024) as bag:
        bag.describe([RUN], [CONFIG])
        for i in range(messages):
            bag.write('/a', STRING, _text(i), T0 + i)
            if i == messages // 2:
                bag.describe([LATER], [CAL])
    return path


def test_every_file_of_a_split_bag_describes_itself(tmp_path: Path) -> None:
    bag = _bag(tmp_path / 'bag', split_bytes=8000)
    files = storage_files(bag)
    assert len(files) >= 3
    assert verify_bag(bag).sound
    for i, file in enumerate(files):
        with file.open('rb') as stream:  # the mcap library's own reader, from the summary
            reader = make_reader(stream)
            found = {m.name: m.metadata for m in reader.iter_metadata()}
            attached = {a.name: a.data for a in reader.iter_attachments()}
            stats = reader.get_summary().statistics
        assert found[RUN_RECORD] == dict(RUN.values) and 'rosbag2' in found, i
        assert attached[CONFIG.name] == CONFIG.data, i
        assert stats.metadata_count == len(found) and stats.attachment_count == len(attached)
    with files[-1].open('rb') as stream:  # after the calibration: in the later files too
        assert CAL.name in {a.name for a in make_reader(stream).iter_attachments()}
    with Reader(bag) as reader:  # rosbags reads every message past the new records
        assert reader.message_count == 1000
    description = bag_description(bag)
    assert description.records == (RUN, LATER)  # repeats kept once, in order
    assert description.attachments == (CONFIG, CAL)
    assert description.keys() == {'kind': 'program', 'program_moves': '30',
                                  'calibration_file': 'cal.yaml'}
    assert description.matches({'kind': 'program'})
    assert not description.matches({'kind': 'interactive'})


def test_a_killed_recording_keeps_its_description_through_recovery(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    writer = BagWriter(bag)
    writer.describe([RUN], [CONFIG])
    for i in range(300):
        writer.write('/a', STRING, _text(i), T0 + i)
    writer.describe([LATER], [CAL])
    writer.write('/a', STRING, _text(300), T0 + 300)
    writer.flush()
    killed = tmp_path / 'killed'  # the files as a SIGKILL leaves them: no summary, no yaml
    shutil.copytree(bag, killed, ignore=shutil.ignore_patterns('.close_reserve'))
    writer.close()
    report = recover_bag(killed)
    assert [f.status for f in report.files] == ['recovered'] and report.message_count == 301
    recovered = bag_description(killed)
    assert recovered.records == (RUN, LATER) and recovered.attachments == (CONFIG, CAL)


def test_bad_records_are_refused_and_change_nothing(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='strings'):
        MetadataRecord(RUN_RECORD, {'moves': 30})  # type: ignore[dict-item]
    with pytest.raises(BagError, match='non-empty name'):
        Attachment('', 'text/plain', b'')
    with pytest.raises(BagError, match='at most'):
        Attachment('big', 'text/plain', bytes(MAX_ATTACHMENT_BYTES + 1))
    with pytest.raises(ValueError, match='KEY=VALUE'):
        parse_where(['kind'])
    assert parse_where(['kind=program', 'a=b=c']) == {'kind': 'program', 'a': 'b=c'}


def test_a_launcher_description_is_what_the_recorder_stores(tmp_path: Path) -> None:
    config, program = config_path('cell.yaml'), config_path('program.yaml')
    path = write_description_file(tmp_path, 'program', [config], program, 30,
                                  ['run_cell', '--program', str(program)])
    assert path == tmp_path / DESCRIPTION_FILE
    settings = RecorderSettings(output=str(tmp_path / 'bag'), description_file=str(path))
    recorder = Recorder(settings)
    assert recorder.record('/a', STRING, _text(0), T0) is None
    assert recorder.close() is None
    described = bag_description(tmp_path / 'bag')
    run = described.run()
    assert run['kind'] == 'program' and run['program'] == 'program.yaml'
    assert run['program_moves'] == '30' and run['ros_distro'] == 'jazzy'
    assert run['mechanism_fingerprint'] == mechanism_fingerprint([config])
    assert described.attachment('config/cell.yaml').data == config.read_bytes()
    assert described.attachment('program/program.yaml').data == program.read_bytes()
    with pytest.raises(ValueError, match='run kind'):
        write_description_file(tmp_path, 'replay', [config])


def test_an_unusable_description_starts_no_bag(tmp_path: Path) -> None:
    described = tmp_path / DESCRIPTION_FILE
    described.write_text(yaml.safe_dump({'metadata': {'kind': 'program'},
                                         'attach': {'config/x.yaml': str(tmp_path / 'gone')}}))
    with pytest.raises(ConfigError, match='cannot attach'):
        load_description(described, T0)
    with pytest.raises(ConfigError, match='cannot attach'):
        Recorder(RecorderSettings(output=str(tmp_path / 'bag'),
                                  description_file=str(described)))
    assert not (tmp_path / 'bag').exists()


def test_each_calibration_the_positioner_takes_is_stored(tmp_path: Path) -> None:
    watch = CalibrationWatch()
    calibration = tmp_path / 'calibration.yaml'
    calibration.write_text('calibration:\n  x: [1.0, 2.0]\n')
    assert watch.observe(_text(1), T0) is None  # not a diagnostics message of the kind
    assert watch.observe(_diagnostics('other', name='leg_driver: state'), T0) is None
    records, attachments = watch.observe(_diagnostics(names.NO_CALIBRATION), T0) or ([], [])
    assert records[0].values['calibration_file'] == 'none' and attachments == []
    assert watch.observe(_diagnostics(names.NO_CALIBRATION), T0 + 1) is None  # no change
    records, attachments = watch.observe(_diagnostics(str(calibration)), T0 + 2) or ([], [])
    assert attachments[0].name == 'calibration/calibration.yaml'
    assert attachments[0].data == calibration.read_bytes()
    assert attachments[0].log_time_ns == T0 + 2
    assert records[0].values['calibration_sha256'] == \
        hashlib.sha256(calibration.read_bytes()).hexdigest()[:16]
    records, attachments = watch.observe(_diagnostics(str(tmp_path / 'gone.yaml')),
                                         T0 + 3) or ([], [])
    assert attachments == [] and records[0].values['calibration_attached'].startswith('no: ')
    # through the recorder: a /diagnostics message that names a new file stores it
    recorder = Recorder(RecorderSettings(output=str(tmp_path / 'bag')))
    for i, value in enumerate(('none', str(calibration), str(calibration))):
        recorder.record(names.DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray',
                        _diagnostics(value), T0 + i)
    recorder.close()
    described = bag_description(tmp_path / 'bag')
    assert [r.values['calibration_file'] for r in described.records] == \
        ['none', str(calibration)]
    assert [a.name for a in described.attachments] == ['calibration/calibration.yaml']


@pytest.mark.parametrize(('description', 'steps', 'kind'), [
    ({}, 0, INTERACTIVE_RUN),  # an old bag without steps: by hand
    ({}, 4, PROGRAM_RUN),  # an old bag with steps: a program's, as before
    ({'kind': 'interactive'}, 4, INTERACTIVE_RUN),
    ({'kind': 'program', 'program_moves': '4'}, 4, PROGRAM_RUN),
    ({'kind': 'program', 'program_moves': '4'}, 3, ABORTED_RUN),
    ({'kind': 'program', 'program_moves': '4'}, 0, ABORTED_RUN),
])
def test_run_kind(description: dict[str, str], steps: int, kind: str) -> None:
    marked = [ProgramStep('none', float(i), 1, 'P1') for i in range(steps)]
    assert run_kind(description, [*marked, ProgramStep.ended(9.0)]) == kind


def test_the_fleet_selects_by_key_and_lists_an_aborted_run_apart(tmp_path: Path) -> None:
    run = synthetic_run([[0.0, 0.0, 0.20], [0.002, 0.0, 0.20]], [[0.0, 0.0, 0.0, 1.0]] * 2,
                        modes=('none',), cycles=2, rate=10.0, dwell_time=1.5, start=1.77e9,
                        seed=4)
    write_run_bag(tmp_path / 'whole', run, description={'kind': 'program',
                                                        'program_moves': '4'})
    write_run_bag(tmp_path / 'cut', run, description={'kind': 'program',
                                                      'program_moves': '10'})
    write_run_bag(tmp_path / 'old', run)
    bags = [tmp_path / 'whole', tmp_path / 'cut', tmp_path / 'old']
    whole, cut = digest_bag(bags[0]), digest_bag(bags[1])
    assert isinstance(whole, RunDigest) and isinstance(cut, RunDigest)
    assert whole.kind == PROGRAM_RUN and whole.program
    assert cut.kind == ABORTED_RUN and not cut.program and cut.poses
    assert cut.description['program_moves'] == '10'
    assert select_bags(bags, {'program_moves': '10'}) == [bags[1]]
    assert select_bags(bags, {'kind': 'program'}) == bags[:2]
    assert select_bags(bags, {}) == bags
