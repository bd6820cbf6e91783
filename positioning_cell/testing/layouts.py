"""A recorded bag written again in another MCAP layout, as other recorders write them: the
same records (schemas, channels, and every message with its log time, publish time, sequence
and bytes, in the same file order) through the ``mcap`` library's writer, chunked or not,
with or without message and chunk indexes, statistics, summary offsets, repeated definitions
or any summary at all, with any chunk compression and size, with or without CRCs, and split
into several files with a ``metadata.yaml`` (as rosbag2 writes one for a split bag).

For the tests that every reader of the cell reads every valid layout alike (issue 21), and
for trying a layout by hand::

    .venv/bin/python -m positioning_cell.testing.layouts SOURCE_BAG TARGET_BAG fastwrite
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.writer import CompressionType, IndexType, Writer

from positioning_cell.bag.metadata import FileSummary, TopicMeta, topic_meta, write_metadata
from positioning_cell.bag.verify import storage_files

_COMPRESSION = {'none': CompressionType.NONE, 'zstd': CompressionType.ZSTD,
                'lz4': CompressionType.LZ4}
_INDEX = {'none': IndexType.NONE, 'chunk': IndexType.CHUNK, 'message': IndexType.MESSAGE,
          'all': IndexType.ALL}


@dataclass(frozen=True)
class Layout:
    """How a bag is laid out (the ``mcap.writer.Writer`` options): chunked or not, chunk
    size (bytes) and compression (none, zstd, lz4), the indexes written (none, chunk,
    message, all), schemas and channels repeated in the summary, statistics, summary offset
    records, chunk and summary CRCs, the data-section CRC, a summary section at all (False:
    none of the above in it, the footer's summary offset 0), and the number of files."""

    chunked: bool = True
    chunk_size: int = 1024 * 1024
    compression: str = 'zstd'
    index: str = 'all'
    repeat_definitions: bool = True
    statistics: bool = True
    summary_offsets: bool = True
    crcs: bool = True
    data_crc: bool = False
    summary: bool = True
    files: int = 1

    def writer(self, stream: BinaryIO) -> Writer:
        """An mcap writer with these options on ``stream``."""
        summary = self.summary
        return Writer(stream,
                      chunk_size=self.chunk_size, compression=_COMPRESSION[self.compression],
                      index_types=_INDEX[self.index] if summary else IndexType.NONE,
                      repeat_channels=self.repeat_definitions and summary,
                      repeat_schemas=self.repeat_definitions and summary,
                      use_chunking=self.chunked,
                      use_statistics=self.statistics and summary,
                      use_summary_offsets=self.summary_offsets and summary,
                      enable_crcs=self.crcs, enable_data_crcs=self.data_crc)


#: Layouts other tools write, by name.
LAYOUTS: dict[str, Layout] = {
    # rosbag2's fastwrite preset: no chunks, no message index, no CRC
    'fastwrite': Layout(chunked=False, index='none', crcs=False),
    'unchunked-with-crcs': Layout(chunked=False, data_crc=True),
    'chunks-without-any-index': Layout(index='none'),
    'chunk-index-only': Layout(index='chunk', compression='lz4'),
    'message-index-only': Layout(index='message', compression='none'),
    'lz4-small-chunks': Layout(compression='lz4', chunk_size=4096, data_crc=True),
    'uncompressed-tiny-chunks': Layout(compression='none', chunk_size=700),
    'zstd-large-chunks-no-crc': Layout(chunk_size=8 * 2**20, crcs=False),
    'definitions-only-in-chunks': Layout(repeat_definitions=False),
    'no-statistics-no-offsets': Layout(statistics=False, summary_offsets=False),
    'no-summary': Layout(summary=False, compression='lz4', chunk_size=64 * 1024),
    'no-summary-unchunked': Layout(summary=False, chunked=False),
    'split-in-3': Layout(chunk_size=64 * 1024, files=3),
    'fastwrite-split-in-2': Layout(chunked=False, index='none', crcs=False, files=2),
}


def _records(source: Path) -> tuple[list[Schema], list[Channel], list[Message]]:
    """The schemas, channels and messages of the MCAP bag at ``source`` (a folder or one
    file), in file order, read by the ``mcap`` library."""
    files = storage_files(source) if source.is_dir() else [source]
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: list[Message] = []
    for file in files:
        with file.open('rb') as stream:
            for schema, channel, message in make_reader(stream).iter_messages(
                    log_time_order=False):
                if schema is not None:
                    schemas.setdefault(schema.id, schema)
                channels.setdefault(channel.id, channel)
                messages.append(message)
    return list(schemas.values()), list(channels.values()), messages


def rewrite_bag(source: str | Path, target: str | Path, layout: Layout) -> Path:
    """The MCAP bag at ``source`` written again into the new rosbag2 folder ``target``
    (``<target>_<n>.mcap`` and ``metadata.yaml``) in ``layout``: every file holds every schema
    and channel, the messages are cut into ``layout.files`` consecutive parts. Returns
    ``target``."""
    source, target = Path(source), Path(target)
    schemas, channels, messages = _records(source)
    target.mkdir(parents=True)
    by_id = {s.id: s for s in schemas}
    topics = [topic_meta(c.topic, by_id[c.schema_id].name if c.schema_id in by_id else '',
                         c.message_encoding, c.metadata, source) for c in channels]
    topic_of = {c.id: c.topic for c in channels}
    cuts = [len(messages) * k // layout.files for k in range(layout.files + 1)]
    summaries: list[FileSummary] = []
    for n in range(layout.files):
        part = messages[cuts[n]:cuts[n + 1]]
        name = f'{target.name}_{n}.mcap'
        with (target / name).open('wb') as stream:
            writer = layout.writer(stream)
            writer.start(profile='ros2', library='positioning_cell.testing.layouts')
            schema_ids = {s.id: writer.register_schema(s.name, s.encoding, s.data)
                          for s in schemas}
            channel_ids = {c.id: writer.register_channel(c.topic, c.message_encoding,
                                                         schema_ids.get(c.schema_id, 0),
                                                         dict(c.metadata))
                           for c in channels}
            for m in part:
                writer.add_message(channel_ids[m.channel_id], m.log_time, m.data,
                                   m.publish_time, m.sequence)
            writer.finish()  # type: ignore[no-untyped-call]
        counts: dict[str, int] = {}
        for m in part:
            counts[topic_of[m.channel_id]] = counts.get(topic_of[m.channel_id], 0) + 1
        times = [m.log_time for m in part]
        summaries.append(FileSummary(name, min(times, default=0), max(times, default=0),
                                     len(part), counts))
    distinct: dict[str, TopicMeta] = {}
    for topic in topics:
        distinct.setdefault(topic.name, topic)
    write_metadata(target, list(distinct.values()), summaries)
    return target


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('source', type=Path)
    parser.add_argument('target', type=Path)
    parser.add_argument('layout', choices=sorted(LAYOUTS))
    args = parser.parse_args(argv)
    print(rewrite_bag(args.source, args.target, LAYOUTS[args.layout]))
    return 0


if __name__ == '__main__':
    sys.exit(main())
