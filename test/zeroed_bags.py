"""Copies of bags with a stretch of their MCAP file overwritten by zeros that readers skip."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
import shutil

from mcap.reader import make_reader

RECORD_HEADER = 9  # bytes: the opcode, then the uint64 length of the record's body
# A chunk record's body before its records: start and end time, uncompressed size, CRC, the
# compression string's length (its text follows) and the records' length.
CHUNK_FIELDS = 8 + 8 + 8 + 4 + 4 + 8


def zeroed_copy(bag: Path, target: Path) -> Counter[str]:
    """Copy ``bag`` to ``target``, zeroing consecutive message records of its middle chunk.

    Zeros read as MCAP records of opcode 0 and length 0, 9 bytes each, which readers skip: a
    stretch of zeros that starts at a record and is a multiple of 9 bytes long ends at one, and
    the messages it covered vanish without a parse error (rosbags writes no chunk CRC). The
    stretch zeroed is the longest such one in the chunk; the summary is left as it was.

    Args:
        bag: a bag of one uncompressed MCAP file, as rosbags writes it, with several chunks.
        target: the copy's directory.

    Returns:
        The messages zeroed, per topic.
    """
    shutil.copytree(bag, target)
    mcap_file = next(target.glob('*.mcap'))
    with mcap_file.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and len(summary.chunk_indexes) > 2, bag
    chunk = summary.chunk_indexes[len(summary.chunk_indexes) // 2]
    assert chunk.compression == '', bag
    data = bytearray(mcap_file.read_bytes())
    start = chunk.chunk_start_offset + RECORD_HEADER + CHUNK_FIELDS + len(chunk.compression)
    offsets = [start]
    while offsets[-1] < start + chunk.uncompressed_size:
        length = int.from_bytes(data[offsets[-1] + 1 : offsets[-1] + RECORD_HEADER], 'little')
        offsets.append(offsets[-1] + RECORD_HEADER + length)
    stretches = [
        (i, j)
        for i in range(len(offsets))
        for j in range(i + 1, len(offsets))
        if (offsets[j] - offsets[i]) % RECORD_HEADER == 0
    ]
    assert stretches, f'{bag}: no stretch of records is a multiple of {RECORD_HEADER} bytes'
    first, end = max(stretches, key=lambda stretch: stretch[1] - stretch[0])
    channel_ids = (
        int.from_bytes(data[at + RECORD_HEADER : at + RECORD_HEADER + 2], 'little')
        for at in offsets[first:end]
    )
    lost = Counter(summary.channels[channel_id].topic for channel_id in channel_ids)
    data[offsets[first] : offsets[end]] = bytes(offsets[end] - offsets[first])
    mcap_file.write_bytes(data)
    return lost
