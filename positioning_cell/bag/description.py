"""What a bag says of itself: MCAP metadata records (named string maps) and attachment records
(named files), the MCAP format's own places for them, which Foxglove, ``mcap info`` and the
mcap library read.

The cell's recorder writes a run's description into every storage file it starts
(:mod:`positioning_cell.recording.description`): a :data:`RUN_RECORD` metadata record (kind of
run, program, mechanism fingerprint, configuration files ...) and the files themselves as
attachments, then, while it records, a :data:`CALIBRATION_RECORD` and the calibration file each
time the positioner takes a new one. :func:`read_description` reads them back from every file
of a bag; :meth:`BagDescription.keys` is the flat map that ``analyze_bags --where`` searches.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader

from positioning_cell.bag.errors import BagError

#: Name of the metadata record that describes the run (written when each file starts).
RUN_RECORD = 'positioning_cell.run'
#: Name of the metadata record written each time the positioner takes a calibration file.
CALIBRATION_RECORD = 'positioning_cell.calibration'
#: rosbag2's own metadata record (its metadata.yaml inside each file): not a description.
ROSBAG2_RECORD = 'rosbag2'
#: Media type of the YAML files attached (configuration, program, calibration).
YAML_MEDIA_TYPE = 'application/yaml'
#: The largest attachment written or read back, bytes: descriptions are configuration files.
MAX_ATTACHMENT_BYTES = 16 * 2**20


@dataclass(frozen=True)
class Attachment:
    """A file stored in the bag: its ``name`` (a relative path such as ``config/cell.yaml``),
    ``media_type``, ``data`` and ``log_time_ns`` (ns since the epoch: when it came into the
    recording)."""

    name: str
    media_type: str
    data: bytes
    log_time_ns: int = 0

    def __post_init__(self) -> None:
        if not self.name or not isinstance(self.name, str):
            raise BagError(Path(str(self.name)), 'an attachment needs a non-empty name')
        if len(self.data) > MAX_ATTACHMENT_BYTES:
            raise BagError(Path(self.name), f'attachment of {len(self.data)} bytes: at most '
                                            f'{MAX_ATTACHMENT_BYTES}')

    @property
    def text(self) -> str:
        """The data as UTF-8 text (undecodable bytes replaced)."""
        return self.data.decode('utf-8', 'replace')


@dataclass(frozen=True)
class MetadataRecord:
    """One MCAP metadata record: its ``name`` and string ``values``."""

    name: str
    values: Mapping[str, str]

    def __post_init__(self) -> None:
        if not self.name:
            raise BagError(Path('.'), 'a metadata record needs a non-empty name')
        bad = [k for k, v in self.values.items() if not isinstance(k, str) or not k
               or not isinstance(v, str)]
        if bad:
            raise BagError(Path(self.name), f'metadata keys and values must be strings, keys '
                                            f'non-empty: {bad!r}')
        object.__setattr__(self, 'values', MappingProxyType(dict(self.values)))


@dataclass(frozen=True)
class BagDescription:
    """The description records of a bag in file order (repeats from split files once) and its
    attachments."""

    records: tuple[MetadataRecord, ...] = ()
    attachments: tuple[Attachment, ...] = ()

    def keys(self) -> dict[str, str]:
        """Every value of the description records as one flat map, a later record's value
        winning (the calibration last taken, say): what ``--where KEY=VALUE`` searches."""
        flat: dict[str, str] = {}
        for record in self.records:
            flat.update(record.values)
        return flat

    def run(self) -> dict[str, str]:
        """The :data:`RUN_RECORD` values (empty: a bag without a description)."""
        return next((dict(r.values) for r in self.records if r.name == RUN_RECORD), {})

    def to_dict(self) -> dict[str, Any]:
        """For JSON: the records (name, values) and each attachment's name, media type, size
        (bytes) and log time (ns); the attachments' contents stay in the bag."""
        return {'records': [{'name': r.name, 'values': dict(r.values)} for r in self.records],
                'attachments': [{'name': a.name, 'media_type': a.media_type,
                                 'bytes': len(a.data), 'log_time_ns': a.log_time_ns}
                                for a in self.attachments]}

    def lines(self) -> list[str]:
        """For people: one line per record and one listing the attachments (Markdown)."""
        out = [f'- `{r.name}`: ' + ', '.join(f'{k} `{v}`' for k, v in r.values.items())
               for r in self.records]
        if self.attachments:
            out.append('- attached: ' + ', '.join(f'`{a.name}` ({len(a.data)} bytes)'
                                                  for a in self.attachments))
        return out

    def attachment(self, name: str) -> Attachment | None:
        """The last attachment called ``name`` (None: none)."""
        return next((a for a in reversed(self.attachments) if a.name == name), None)

    def matches(self, where: Mapping[str, str]) -> bool:
        """Whether every ``key: value`` of ``where`` is in :meth:`keys`."""
        keys = self.keys()
        return all(keys.get(k) == v for k, v in where.items())


def parse_where(terms: Sequence[str]) -> dict[str, str]:
    """``KEY=VALUE`` terms as a map; ValueError naming a term without ``=`` or key."""
    where: dict[str, str] = {}
    for term in terms:
        key, sep, value = term.partition('=')
        if not sep or not key.strip():
            raise ValueError(f'{term!r}: expected KEY=VALUE (a key of the bags\' description)')
        where[key.strip()] = value
    return where


def bag_description(path: Path) -> BagDescription:
    """:func:`read_description` of the bag at ``path`` (a bag folder or one ``.mcap``)."""
    from positioning_cell.bag.verify import storage_files

    return read_description(storage_files(path) if path.is_dir() else [path])


def read_description(files: Sequence[Path]) -> BagDescription:
    """The description records and attachments of a bag's storage ``files`` (in split order),
    read with the mcap library (its summary's indexes when the file has them, a scan
    otherwise); the same record or attachment repeated in several files is kept once.
    BagError naming a file the mcap library cannot read."""
    records: list[MetadataRecord] = []
    attachments: list[Attachment] = []
    for path in files:
        try:
            with path.open('rb') as stream:
                reader = make_reader(stream)
                file_records = [MetadataRecord(m.name, m.metadata)
                                for m in reader.iter_metadata() if m.name != ROSBAG2_RECORD]
                file_attachments = [Attachment(a.name, a.media_type, bytes(a.data), a.log_time)
                                    for a in reader.iter_attachments()]
        except (OSError, McapError, ValueError, KeyError) as err:
            raise BagError(path, f'cannot read its metadata and attachments: {err}') from err
        records += [r for r in file_records if r not in records]
        attachments += [a for a in file_attachments if a not in attachments]
    return BagDescription(tuple(records), tuple(attachments))
