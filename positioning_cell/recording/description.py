"""The description a recorder stores in its bag (:mod:`positioning_cell.bag.description`): what
run it is, with what configuration, program and machine, and each calibration the positioner
takes while it records.

The command that starts a cell (``run_cell``, ``cell up``) writes the run's description file
(:func:`write_description_file`, ``<run>/description.yaml``: the metadata values and the files
to attach) and gives it to the recorder (parameter ``description_file``). The recorder reads it
when it starts (:func:`load_description`: the files as they are then) and stores it at the
start of every storage file. While it records, :class:`CalibrationWatch` follows the
positioner's ``calibration`` status value on ``/diagnostics`` and stores each calibration file
the positioner takes (a :data:`~positioning_cell.bag.description.CALIBRATION_RECORD` and the
file), so that a bag of ``make run`` carries the calibration it was judged with.
"""

from __future__ import annotations

import hashlib
import shlex
import time
from collections.abc import Mapping, Sequence
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import yaml

from positioning_cell import files, names
from positioning_cell.bag.description import (
    CALIBRATION_RECORD,
    MAX_ATTACHMENT_BYTES,
    RUN_RECORD,
    YAML_MEDIA_TYPE,
    Attachment,
    MetadataRecord,
)
from positioning_cell.bag.errors import BagError
from positioning_cell.bag.metadata import ROS_DISTRO
from positioning_cell.config import load_parameter_file, load_yaml_mapping, node_parameters
from positioning_cell.errors import ConfigError

#: The run's description file in its run folder.
DESCRIPTION_FILE = 'description.yaml'
#: What a run is: a program's (run_cell) or an operator's session (cell up).
KINDS = ('program', 'interactive')
#: The diagnostics type whose positioner status names the calibration in force.
_DIAGNOSTICS = 'diagnostic_msgs/msg/DiagnosticArray'


def _package_version() -> str:
    try:
        return version('positioning_cell')
    except PackageNotFoundError:
        return 'unknown'


def mechanism_fingerprint(config_files: Sequence[Path]) -> str:
    """The fingerprint (:func:`positioning_cell.calibration.file.fingerprint`) of the nominal
    mechanism the positioner gets from ``config_files`` (ROS 2 parameter files, later ones
    winning); ConfigError if a file or its mechanism block is unusable."""
    from positioning_cell.calibration.file import fingerprint  # not the recorder's imports
    from positioning_cell.core.mechanism import Mechanism

    block: dict[str, Any] = {}
    for path in config_files:
        mechanism = node_parameters(load_parameter_file(path), names.NODE_POSITIONER).get(
            'mechanism', {})
        if isinstance(mechanism, Mapping):
            block.update(mechanism)
    return fingerprint(Mechanism.from_params(block))


def write_description_file(run_dir: Path, kind: str, config_files: Sequence[Path],
                           program: Path | None = None, program_moves: int | None = None,
                           command: Sequence[str] = ()) -> Path:
    """Write ``run_dir/description.yaml``: the :data:`RUN_RECORD` values (``kind``, one of
    :data:`KINDS`; the mechanism fingerprint of ``config_files``; the program's file name and
    move count; the command line; when, and which package and ROS distribution) and the files
    to attach (``config/<name>`` for each config file, ``program/<name>``). ValueError for an
    unknown kind; ConfigError for an unusable config file."""
    if kind not in KINDS:
        raise ValueError(f'run kind {kind!r}: expected one of {", ".join(KINDS)}')
    attach = {f'config/{i}_{p.name}' if any(q.name == p.name for q in config_files[:i])
              else f'config/{p.name}': str(p.resolve()) for i, p in enumerate(config_files)}
    values = {'kind': kind, 'mechanism_fingerprint': mechanism_fingerprint(config_files),
              'config': ' '.join(attach), 'started_utc': time.strftime(
                  '%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
              'package_version': _package_version(), 'ros_distro': ROS_DISTRO,
              'command': shlex.join(command)}
    if program is not None:
        attach[f'program/{program.name}'] = str(program.resolve())
        values['program'] = program.name
    if program_moves is not None:
        values['program_moves'] = str(program_moves)
    path = run_dir / DESCRIPTION_FILE
    path.write_text(yaml.safe_dump({'metadata': values, 'attach': attach}, sort_keys=False),
                    encoding='utf-8')
    return path


def _attachment(name: str, path: Path, log_time_ns: int) -> Attachment:
    """The file at ``path`` as attachment ``name``; OSError or BagError (too large)."""
    if path.stat().st_size > MAX_ATTACHMENT_BYTES:
        raise BagError(path, f'larger than {MAX_ATTACHMENT_BYTES} bytes: not attached')
    return Attachment(name, YAML_MEDIA_TYPE, path.read_bytes(), log_time_ns)


def load_description(path: str | Path, log_time_ns: int
                     ) -> tuple[MetadataRecord, list[Attachment]]:
    """The :data:`RUN_RECORD` and the attachments a description file names (each file read
    now, stamped ``log_time_ns``). ConfigError naming the file and what is wrong: unreadable
    or malformed, a value that is not text, a file to attach that cannot be read."""
    data = load_yaml_mapping(path, files.PARAMETER_FILE, 'metadata: {...}, attach: {...}')
    metadata, attach = data.get('metadata', {}), data.get('attach', {})
    if not isinstance(metadata, Mapping) or not isinstance(attach, Mapping):
        raise ConfigError(f'{path}: metadata and attach must be mappings')
    try:
        record = MetadataRecord(RUN_RECORD, {str(k): str(v) for k, v in metadata.items()})
        attachments = [_attachment(str(name), Path(str(p)), log_time_ns)
                       for name, p in attach.items()]
    except (OSError, BagError) as err:
        raise ConfigError(f'{path}: cannot attach a file it names: {err}') from err
    return record, attachments


class CalibrationWatch:
    """Follows the positioner's ``calibration`` status value (a file path, or ``none``) in
    ``/diagnostics`` messages (serialized) and says when it changes: the record and the file
    to store (:meth:`observe`). A file that cannot be read is recorded as such, never
    raised."""

    def __init__(self) -> None:
        self.current: str | None = None  # not seen yet

    def observe(self, data: bytes, receive_time_ns: int
                ) -> tuple[list[MetadataRecord], list[Attachment]] | None:
        """A /diagnostics message received at ``receive_time_ns``: None, or what to store
        because the positioner's calibration changed (the first value seen included)."""
        if b'calibration' not in data:  # most diagnostics: not decoded at all
            return None
        from positioning_cell.bag.writer import jazzy_typestore

        try:
            array: Any = jazzy_typestore().deserialize_cdr(data, _DIAGNOSTICS)
        except Exception:  # a malformed message is the recorder's to keep, not to judge
            return None
        value = next((kv.value for s in array.status if s.name == names.STATUS_POSITIONER
                      for kv in s.values if kv.key == 'calibration'), None)
        if value is None or value == self.current:
            return None
        self.current = value
        stamp = time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime(receive_time_ns * 1e-9))
        values = {'calibration_file': value, 'calibration_since_utc': stamp}
        if value == names.NO_CALIBRATION:
            return [MetadataRecord(CALIBRATION_RECORD, values)], []
        name = f'calibration/{Path(value).name}'
        try:
            attachment = _attachment(name, Path(value), receive_time_ns)
        except (OSError, BagError) as err:
            values['calibration_attached'] = f'no: {err}'
            return [MetadataRecord(CALIBRATION_RECORD, values)], []
        values |= {'calibration_attached': name,
                   'calibration_sha256': hashlib.sha256(attachment.data).hexdigest()[:16]}
        return [MetadataRecord(CALIBRATION_RECORD, values)], [attachment]
