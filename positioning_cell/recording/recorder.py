"""The recorder's logic without ROS: a :class:`~positioning_cell.bag.BagWriter` with pause and
resume, what happens after writing failed, the counts, the free-space checks, the run's
description and calibrations stored in the bag (:mod:`positioning_cell.recording.description`),
and the status it publishes (:mod:`positioning_cell.recording.status`). ``recorder_node``
feeds it the messages and the timers' ticks and publishes what it says."""

from __future__ import annotations

import os
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from positioning_cell import names
from positioning_cell.bag.errors import BagError
from positioning_cell.bag.settings import RecorderSettings
from positioning_cell.bag.writer import BagWriteError, BagWriter, WriteFailure
from positioning_cell.recording.description import CalibrationWatch, load_description
from positioning_cell.recording.disk import DiskReport, FreeSpace, free_bytes
from positioning_cell.recording.status import RecorderStatus, recorder_status


def default_output(now: datetime | None = None) -> Path:
    """``runs/<UTC timestamp>/bag`` relative to the working directory."""
    stamp = (now or datetime.now(timezone.utc)).strftime('%Y%m%dT%H%M%SZ')
    return Path('runs') / stamp / 'bag'


class Recorder:
    """The bag of a recording (``settings.output``, or :func:`default_output`; BagError if it
    cannot be created) and its state. Once writing failed (``failure``), the bag is closed and
    nothing more is written: messages are counted as ``not_recorded``. The run's description
    (``settings.description_file``; ConfigError if it cannot be used, before any bag is made)
    goes in first; the calibrations the positioner takes are stored as they come."""

    def __init__(self, settings: RecorderSettings) -> None:
        description = (load_description(settings.description_file, time.time_ns())
                       if settings.description_file else None)
        self.writer = BagWriter(
            settings.output or default_output(), compression=settings.compression,
            chunk_bytes=settings.chunk_bytes, split_max_bytes=settings.split.max_bytes,
            split_max_duration_s=settings.split.max_duration_s)
        self.failure: WriteFailure | None = None
        self.stopped = ''
        self.paused = False
        self.dropped_while_paused = 0
        self.not_recorded = 0
        self.write_errors = 0
        self.disk: DiskReport | None = None
        self._free_space = FreeSpace(settings.disk)
        self._calibration = CalibrationWatch()
        if description is not None:
            self.writer.describe([description[0]], description[1])

    def record(self, topic: str, msgtype: str, data: bytes, receive_time_ns: int
               ) -> BagError | None:
        """One message received (serialized, at ``receive_time_ns`` since the epoch): written,
        or dropped while paused, or counted once writing failed. The writer's error if it
        refused it: a BagWriteError (writing failed, the bag is closed: ``failure``) or
        another BagError (this message only; counted in ``write_errors``)."""
        if self.failure is not None:
            self.not_recorded += 1
            return None
        if self.paused:
            self.dropped_while_paused += 1
            return None
        try:
            self.writer.write(topic, msgtype, data, receive_time_ns)
            if topic == names.DIAGNOSTICS:
                taken = self._calibration.observe(data, receive_time_ns)
                if taken is not None:
                    self.writer.describe(*taken)
        except BagWriteError as err:
            self.failure = err.failure
            return err
        except BagError as err:
            self.write_errors += 1
            return err
        return None

    def flush(self) -> BagWriteError | None:
        """Chunks to the disk (what a kill can lose); the error if writing failed."""
        try:
            self.writer.flush()
        except BagWriteError as err:
            self.failure = err.failure
            return err
        return None

    def pause(self, paused: bool) -> tuple[bool, str]:
        """Pause (flushing first) or resume: whether it did, and what to answer."""
        if self.writer.closed:
            return False, (f'not recording: {self.failure.line()}' if self.failure else
                           f'not recording: {self.writer.path} is closed')
        was, self.paused = self.paused, paused
        if paused:
            self.flush()
        state = 'paused' if paused else 'recording'
        return self.failure is None, (f'{state} (was {"paused" if was else "recording"}); '
                                      f'{self.writer.message_count} messages in '
                                      f'{self.writer.path}')

    def close(self) -> BagWriteError | None:
        """Finish the bag (idempotent); the error if writing failed on the way."""
        if self.writer.closed:
            return None
        try:
            self.writer.close()
        except BagWriteError as err:
            self.failure = err.failure
            return err
        self.stopped = 'closed on request'
        return None

    def check_disk(self, now: float) -> DiskReport:
        """Free space of the bag's filesystem at ``now`` (s, monotonic) against the margins."""
        try:
            free, error = free_bytes(self.writer.path), ''
        except OSError as err:
            free, error = None, err.strerror or str(err)
        self.disk = self._free_space.update(now, free, error)
        return self.disk

    def status(self) -> tuple[RecorderStatus, dict[str, Any]]:
        """The status to publish (level, message, state) and its key-values
        (docs/howto/record-analyse.md, "The recorder")."""
        writer, failure = self.writer, self.failure
        status = recorder_status(paused=self.paused, failure=failure.line() if failure else '',
                                 stopped=self.stopped, disk=self.disk)
        values: dict[str, Any] = {
            'state': status.state.value, 'bag': writer.path, 'messages': writer.message_count,
            'files': len(writer.files), 'dropped_while_paused': self.dropped_while_paused,
            'write_errors': self.write_errors, 'not_recorded': self.not_recorded,
            'reserve_bytes': writer.reserve_bytes,
            **(self.disk.values() if self.disk is not None else {})}
        if failure is not None:
            values.update({'error': failure.error, 'failed_file': os.fspath(failure.file),
                           'failed_operation': failure.operation, 'lost': failure.lost,
                           'bag_closed': failure.closed})
        return status, {**values, **writer.topic_counts}
