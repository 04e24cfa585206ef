"""Copies of bags whose MCAP file has no summary, as another tool may write it."""

from __future__ import annotations

from pathlib import Path
import shutil

from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import IndexType, Writer


def summaryless_copy(bag: Path, target: Path) -> Path:
    """Copy ``bag`` to ``target``, its MCAP file rewritten with the mcap Writer without summary.

    The records of the data section are written again in their order (schemas and channels
    where they first appear), in chunks, with a footer whose summary offset is 0 and no index.

    Args:
        bag: a bag of one MCAP file, as rosbags writes it.
        target: the copy's directory.

    Returns:
        The copy's MCAP file.
    """
    shutil.copytree(bag, target)
    mcap_file = next(target.glob('*.mcap'))
    with mcap_file.open('rb') as stream:
        records = list(StreamReader(stream).records)
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    with mcap_file.open('wb') as stream:
        writer = Writer(
            stream,
            index_types=IndexType.NONE,
            repeat_channels=False,
            repeat_schemas=False,
            use_statistics=False,
            use_summary_offsets=False,
        )
        writer.start(profile='ros2', library='summaryless_copy')
        for record in records:  # the summary's copies of schemas and channels are skipped
            if isinstance(record, Schema) and record.id not in schema_ids:
                schema_ids[record.id] = writer.register_schema(
                    record.name, record.encoding, record.data
                )
            elif isinstance(record, Channel) and record.id not in channel_ids:
                channel_ids[record.id] = writer.register_channel(
                    record.topic,
                    record.message_encoding,
                    schema_ids[record.schema_id],
                    record.metadata,
                )
            elif isinstance(record, Message):
                writer.add_message(
                    channel_ids[record.channel_id],
                    record.log_time,
                    record.data,
                    record.publish_time,
                    record.sequence,
                )
        writer.finish()
    with mcap_file.open('rb') as stream:
        assert make_reader(stream).get_summary() is None, mcap_file
    return mcap_file
