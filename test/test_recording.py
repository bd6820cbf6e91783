"""positioning_cell.recording without ROS: the free-space margins and the falling rate, the
recorder's status, the rule every watcher applies to it ("the recorder failed, stopped, in
error or silent → recording stopped"), and the recorder's logic (recorder_node's library)."""

from __future__ import annotations

import errno
import math
import shutil
from pathlib import Path

import pytest

from positioning_cell.bag import RecorderSettings
from positioning_cell.bag.writer import BagWriteError, jazzy_typestore
from positioning_cell.errors import ConfigError
from positioning_cell.recording import (
    RATE_WINDOW_S,
    SILENT_AFTER_S,
    DiskReport,
    DiskSettings,
    FreeSpace,
    RecorderReport,
    RecorderState,
    free_bytes,
    human_bytes,
    recorder_status,
    recording,
)
from positioning_cell.recording.recorder import Recorder
from positioning_cell.testing.disks import FaultyDisk

MiB = 2**20
TS = jazzy_typestore()
T0 = 1_790_000_000_000_000_000


def test_free_bytes_is_what_an_unprivileged_writer_may_use(tmp_path: Path) -> None:
    free = free_bytes(tmp_path)
    usage = shutil.disk_usage(tmp_path)  # the same statvfs figure, taken a moment apart
    assert free > 0 and free == pytest.approx(usage.free, abs=256 * MiB)
    with pytest.raises(OSError):
        free_bytes(tmp_path / 'missing')


def test_human_bytes() -> None:
    assert [human_bytes(n) for n in (0, 1023, 1024, 1536, 812 * MiB, 100 * 2**30, 2**62)] == [
        '0 B', '1023 B', '1.0 KiB', '1.5 KiB', '812 MiB', '100 GiB', '4096 PiB']


def test_below_the_free_space_margin_warns() -> None:
    space = FreeSpace(DiskSettings(warn_free_bytes=100 * MiB, warn_time_to_full_s=0.0))
    assert space.update(0.0, 101 * MiB) == DiskReport(101 * MiB, None)
    low = space.update(1.0, 99 * MiB)
    assert low.warning == '99.0 MiB free, below the margin of 100 MiB'
    assert low.values() == {'free_bytes': str(99 * MiB), 'disk_falling_bytes_per_s': '',
                            'disk_full_in_s': ''}


def test_the_falling_rate_and_the_time_to_full() -> None:
    """Free space falling 1 MiB/s: measured once half the window is sampled; WARN when the
    disk fills within the margin; a rise or a steady disk is no rate; 0 turns the check off."""
    settings = DiskSettings(warn_free_bytes=0, warn_time_to_full_s=600.0)
    space = FreeSpace(settings)
    start = 1000 * MiB
    reports = [space.update(t, start - int(t) * MiB) for t in range(12)]
    assert all(r.falling_bytes_per_s is None for r in reports[:int(RATE_WINDOW_S / 2)])
    last = reports[-1]
    assert last.falling_bytes_per_s == pytest.approx(MiB)  # over the last 10 s
    assert last.time_to_full_s == pytest.approx(989.0)
    assert last.warning == '' and last.values()['disk_full_in_s'] == '989'
    # 500 MiB gone at once (another writer): about 50 MiB/s over the window, full in < 600 s
    fast = space.update(12.0, start - 512 * MiB)
    assert fast.falling_bytes_per_s == pytest.approx((start - 2 * MiB - (start - 512 * MiB))
                                                     / 10.0)
    assert fast.warning == 'disk full in about 10 s at 51.0 MiB/s (margin 10 min)'
    steady = FreeSpace(settings)
    for t in range(12):
        report = steady.update(t, start + t * MiB)  # space freed: not falling
    assert report.falling_bytes_per_s == 0.0 and math.isinf(report.time_to_full_s)
    assert report.values()['disk_full_in_s'] == 'inf'
    off = FreeSpace(DiskSettings(warn_free_bytes=0, warn_time_to_full_s=0.0))
    assert all(off.update(t, start - t * 100 * MiB).warning == '' for t in range(10))


def test_an_unreadable_disk_is_a_warning() -> None:
    report = FreeSpace(DiskSettings()).update(0.0, None, 'Input/output error')
    assert report.warning == 'free space unknown: Input/output error'
    assert report.values()['free_bytes'] == '' and math.isinf(report.time_to_full_s)


def test_disk_settings_are_validated() -> None:
    with pytest.raises(ConfigError, match='warn_free_bytes'):
        DiskSettings(warn_free_bytes=-1)
    with pytest.raises(ConfigError, match='warn_time_to_full_s'):
        DiskSettings(warn_time_to_full_s=-5.0)


def test_the_recorders_status() -> None:
    low = DiskReport(5 * MiB, None, '5.0 MiB free, below the margin of 1.0 GiB')
    s = recorder_status()
    assert (s.level, s.message, s.state) == (0, 'recording', RecorderState.RECORDING)
    s = recorder_status(disk=low)
    assert (s.level, s.message) == (1, 'recording; disk space low: 5.0 MiB free, below the '
                                       'margin of 1.0 GiB')
    s = recorder_status(paused=True)
    assert (s.level, s.message, s.state) == (1, 'paused', RecorderState.PAUSED)
    s = recorder_status(stopped='closed on request', disk=low)
    assert (s.level, s.message, s.state) == (0, 'recording stopped: closed on request',
                                             RecorderState.STOPPED)
    s = recorder_status(failure='ENOSPC (No space left on device) on write of /b/b_0.mcap; ...',
                        stopped='closed on request', paused=True)
    assert (s.level, s.state) == (2, RecorderState.FAILED)
    assert s.message == 'recording stopped: ENOSPC (No space left on device) on write of ' \
                        '/b/b_0.mcap; ...'


def _report(level: int, message: str, state: str = '', at: float = 100.0) -> RecorderReport:
    return RecorderReport(level, message, {'state': state} if state else {}, at)


def test_the_rule_recording_stopped() -> None:
    assert recording(None, 100.0) is None  # no recorder heard of: nothing to tell
    ok = recording(_report(0, 'recording', 'recording'), 101.0)
    assert ok is not None and (ok.level, ok.message, ok.stopped) == (0, 'recording', False)
    warn = recording(_report(1, 'recording; disk space low: x', 'recording'), 101.0)
    assert warn is not None and (warn.level, warn.stopped) == (1, False)
    failed = recording(_report(2, 'recording stopped: EFBIG (File too large) on ...',
                               'failed'), 100.5)
    assert failed is not None and failed.to_dict() == {
        'level': 2, 'message': 'recording stopped: EFBIG (File too large) on ...',
        'stopped': True}
    # Any ERROR from the recorder stops the recording, whatever it says.
    error = recording(_report(2, 'write errors'), 100.5)
    assert error is not None and (error.level, error.message, error.stopped) == (
        2, 'recording stopped: write errors', True)
    # Closed on request: stopped, a warning (nothing is recorded any more), never "silent".
    closed = recording(_report(0, 'recording stopped: closed on request', 'stopped'), 1e6)
    assert closed is not None and (closed.level, closed.stopped) == (1, True)
    assert closed.message == 'recording stopped: closed on request'


def test_a_silent_recorder_has_stopped() -> None:
    last = _report(0, 'recording', 'recording', at=100.0)
    live = recording(last, 100.0 + SILENT_AFTER_S)
    assert live is not None and not live.stopped
    silent = recording(last, 100.0 + SILENT_AFTER_S + 0.01)
    assert silent is not None and silent.stopped and silent.level == 2
    assert silent.message.startswith('recording stopped: recorder silent since ')
    assert silent.message.endswith(' (last: recording)')
    assert recording(last, 1e9) == silent  # the same words however long the silence


def test_the_recorder_without_ros(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """recorder_node's logic: messages written, dropped while paused; the free-space warning;
    after a failed write the bag closed, later messages counted, pause refused, the ERROR
    status with the failure's values; a clean close says so."""
    disk = FaultyDisk(monkeypatch)
    settings = RecorderSettings(output=str(tmp_path / 'bag'), chunk_bytes=4096,
                                disk=DiskSettings(warn_free_bytes=2**62))
    rec = Recorder(settings)
    data = bytes(TS.serialize_cdr(TS.types['std_msgs/msg/String']('x' * 100),
                                  'std_msgs/msg/String'))
    assert all(rec.record('/cell/program', 'std_msgs/msg/String', data, T0 + i) is None
               for i in range(50))
    assert rec.pause(True) == (True, f'paused (was recording); 50 messages in {rec.writer.path}')
    rec.record('/cell/program', 'std_msgs/msg/String', data, T0 + 50)
    assert rec.dropped_while_paused == 1 and rec.pause(False)[0]
    assert rec.check_disk(0.0).warning.endswith('below the margin of 4096 PiB')
    status, values = rec.status()
    assert (status.level, values['state'], values['messages']) == (1, 'recording', 50)
    assert values['/cell/program'] == 50 and int(values['reserve_bytes']) > 0

    disk.fail(errno.ENOSPC, after=10)
    errors = [rec.record('/cell/program', 'std_msgs/msg/String', data, T0 + 100 + i)
              for i in range(200)]
    failed = [e for e in errors if e is not None]
    assert len(failed) == 1 and isinstance(failed[0], BagWriteError)
    failure = rec.failure
    assert failure is not None and failure.closed and failure.lost == 0
    assert rec.not_recorded == 200 - 1 - errors.index(failed[0])
    status, values = rec.status()
    assert (status.level, status.message) == (2, f'recording stopped: {failure.line()}')
    assert {k: values[k] for k in ('state', 'error', 'failed_operation', 'lost', 'bag_closed')} \
        == {'state': 'failed', 'error': 'ENOSPC', 'failed_operation': 'write', 'lost': 0,
            'bag_closed': True}
    assert values['failed_file'] == str(tmp_path / 'bag' / 'bag_0.mcap')
    assert values['messages'] == failure.messages == 50 + errors.index(failed[0]) + 1
    assert rec.pause(True) == (False, f'not recording: {failure.line()}')
    assert rec.close() is None and rec.stopped == ''  # closed by the failure already

    clean = Recorder(RecorderSettings(output=str(tmp_path / 'clean')))
    clean.record('/cell/program', 'std_msgs/msg/String', data, T0)
    assert clean.close() is None
    status, values = clean.status()
    assert (status.level, status.message, values['state'], values['messages']) == (
        0, 'recording stopped: closed on request', 'stopped', 1)
