"""Write and read rosbag2 (MCAP) bags with the face_tracking typestore, without a ROS runtime.

Example:
    >>> with BagWriter(tmp / 'run1') as bag:
    ...     bag.write('face/state', 'face_tracking_msgs/msg/FaceState', state, stamp_ns)
    >>> for topic, msgtype, stamp_ns, msg in read_messages(tmp / 'run1', topics=['face/state']):
    ...     ...

Messages already serialised to CDR (what DDS carries) go in and out unchanged with
:meth:`BagWriter.write_raw` and :func:`read_raw`: the bag recorder and player never deserialise.

A damaged bag (cut off, or with a stretch that cannot be read) is read as far as it is
readable, then :class:`~face_tracking_ros.errors.DamagedBagError` says where it stopped;
:func:`read_usable` gives the commands that use a bag's messages (plots, enrolments, learning)
its readable messages with one warning instead.

Messages are read as the bag defines their types (:mod:`.bag_definitions`), so bags of earlier
versions of a message stay readable. Every failure of the underlying libraries (missing or
truncated bag, a type neither the package nor the bag defines, topic re-used with another type,
a topic whose type in ``metadata.yaml`` contradicts its MCAP file's schema) is raised as
:class:`~face_tracking_ros.errors.BagError` naming the bag.

:func:`topic_has_word` is how a topic's name tells the camera it comes from (``left``,
``right``): every choice of a stereo bag's left or right topic goes by it.
:func:`recording_name` is the name of the recording a bag holds, whether it is given as a
directory or as an MCAP file. :func:`is_bag_directory` is what makes a directory a bag (a
``metadata.yaml`` or MCAP files): the bags a directory of bags holds are named by it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator
import contextlib
from pathlib import Path, PurePath
import re
import struct
import sys
from types import TracebackType
from typing import Any, BinaryIO, NamedTuple, Protocol
import warnings

from mcap.exceptions import EndOfFile, InvalidMagic, McapError
from mcap.reader import make_reader
from mcap.records import Channel, McapRecord, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.summary import Summary
from rosbags.interfaces import CDRSer
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer, WriterError
from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.rosbag2.writer import Connection
from rosbags.serde import SerdeError
from rosbags.typesys.base import TypesysError
from rosbags.typesys.store import Typestore
import yaml

from face_tracking_ros import wording
from face_tracking_ros.errors import BagError, ConfigError, DamagedBagError, DamagedBagWarning
from face_tracking_ros.io.bag_definitions import BagDefinitions
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.io.yaml_text import parse_yaml
from face_tracking_ros.wording import counted

BAG_VERSION = 9  # rosbag2 metadata version written (Jazzy and later read it)
# An MCAP chunk is written to the file once it holds this many bytes. A run killed (SIGKILL) or
# a full disk loses the chunk still open: at rosbags' own 1 MiB (it has no setting), up to 97
# frames of a mono track's outputs (3.2 s at 30 fps), at 64 KiB 7. Measured 2026-12-07 on the
# 900-frame mono replay: the output 0.37 % larger, its writing 8 ms of CPU more (of 3.2 s);
# image bags hold one image a chunk (three before) and were decoded in 30 % less CPU time.
CHUNK_BYTES = 64 << 10
NS_PER_S = 1_000_000_000
CDR_HEADER_BYTES = 4  # the encapsulation header before a message's CDR
LITTLE_ENDIAN = sys.byteorder == 'little'  # messages are written in the host's byte order
# A serialising buffer's room beyond the largest message of its type so far (CdrSerialiser),
# and the largest message it is kept for: a larger one (an image) is cheap to size and dear to
# zero a buffer for (a 640x480 rgb8 Image: serialize_cdr 13 us, into a kept buffer 18 us).
SLACK_BYTES = 1024
BUFFERED_MAX_BYTES = 65536
# What rosbags' serialisers raise for an unknown type or a message not fitting it (SerdeError:
# a fixed-size array of another length)
_SERIALISE_ERRORS = (SerdeError, KeyError, AttributeError, TypeError, ValueError, struct.error)
MAX_NAMED_BAGS = 5  # bags named in the error for a directory of bags given as one
# (OverflowError: rosbags seeks past a record whose length, read from damaged bytes, is >= 2**63;
# MemoryError: it asks for a buffer of such a length, hundreds of gigabytes, to read the record)
_READ_ERRORS = (
    ReaderError,
    KeyError,
    ValueError,
    EOFError,
    OSError,
    OverflowError,
    MemoryError,
    struct.error,
)
DESERIALISE_ERRORS = (SerdeError, *_READ_ERRORS)  # what rosbags raises for bytes not of the type


class StampLike(Protocol):
    """A ``builtin_interfaces/msg/Time``: rosbags, rclpy or any object with these fields."""

    sec: int
    nanosec: int


class BagMessage(NamedTuple):
    """One message read from a bag."""

    topic: str
    msgtype: str  # e.g. 'sensor_msgs/msg/Image'
    stamp_ns: int  # bag receive time, ns since the epoch
    msg: Any  # rosbags message dataclass


class RawMessage(NamedTuple):
    """One message read from a bag, still serialised."""

    topic: str
    msgtype: str  # e.g. 'sensor_msgs/msg/Image'
    stamp_ns: int  # bag receive time, ns since the epoch
    data: bytes  # CDR, with its 4-byte encapsulation header, as DDS carries it
    msgdef: str = ''  # the bag's definition of msgtype (ros2msg text), '' if it has none


def stamp_to_ns(stamp: StampLike) -> int:
    """Convert a ``builtin_interfaces/msg/Time`` to integer nanoseconds since the epoch."""
    return stamp.sec * NS_PER_S + stamp.nanosec


class CdrSerialiser:
    """Serialises messages to CDR as rosbags' ``Typestore.serialize_cdr`` does, to the byte.

    ``serialize_cdr`` looks up the type's generated functions, walks the whole message to size
    its buffer (``getsize_cdr``), then walks it again to fill it: for a tracker's outputs, 300
    and more geometry_msgs/Point a frame, the sizing walk is a seventh of the time. Here each
    type's generated serialiser (``Msgdef.serialize_cdr_le``) is looked up once, and fills a
    zeroed buffer the size of the largest message of its type so far and some slack; the part
    written is the message. rosbags' functions never write past the buffer they are given
    (``struct.pack_into`` and memoryview slices refuse it): a larger message (or a bad one) goes
    to ``serialize_cdr`` after all, which sizes the next buffers, or raises its own error, as
    before (its sizing walk runs first: it may find another of a bad message's faults than the
    fill, or word the same one otherwise). Messages over :data:`BUFFERED_MAX_BYTES` (images)
    always go to ``serialize_cdr``: sizing them is cheap and zeroing a buffer is not, and a
    buffer kept for one would be zeroed for every later message of its type.
    """

    def __init__(self, store: Typestore) -> None:
        """Serialise the types of ``store``; no type's serialiser or buffer size known yet."""
        self._store = store
        self._sized: dict[str, tuple[CDRSer, int]] = {}  # per type: serialiser, buffer bytes

    def serialise(self, msg: Any, msgtype: str) -> memoryview:
        """The CDR of ``msg`` with its encapsulation header (``Typestore.serialize_cdr``'s).

        Raises:
            SerdeError, KeyError, AttributeError, TypeError, ValueError, struct.error: as
                ``Typestore.serialize_cdr`` does, for an unknown type or a message not fitting it.
        """
        sized = self._sized.get(msgtype)
        data = None if sized is None else self._into_buffer(msg, *sized)
        if data is None:
            data = self._store.serialize_cdr(msg, msgtype, little_endian=LITTLE_ENDIAN)
            self._keep_size(msgtype, len(data))
        return data

    def _keep_size(self, msgtype: str, size: int) -> None:
        """Make ``msgtype``'s next buffers hold ``size`` bytes and the slack, unless larger.

        Not for a message over :data:`BUFFERED_MAX_BYTES`: its type's buffers stay as they were.
        """
        if size > BUFFERED_MAX_BYTES:
            return
        msgdef = self._store.get_msgdef(msgtype)
        fill = msgdef.serialize_cdr_le if LITTLE_ENDIAN else msgdef.serialize_cdr_be
        capacity = self._sized.get(msgtype, (fill, 0))[1]
        self._sized[msgtype] = (fill, max(capacity, size + SLACK_BYTES))

    def _into_buffer(self, msg: Any, fill: CDRSer, capacity: int) -> memoryview | None:
        """``msg`` serialised by ``fill`` into a new ``capacity``-byte buffer; None if it is short.

        The header is serialize_cdr's: representation CDR (0), the byte order, two zero options.
        None too if ``msg`` does not fit the type (``serialize_cdr`` then says how).
        """
        buffer = memoryview(bytearray(capacity))
        buffer[1] = int(LITTLE_ENDIAN)
        try:
            end = CDR_HEADER_BYTES + fill(buffer[CDR_HEADER_BYTES:], 0, msg, self._store)
        except _SERIALISE_ERRORS:  # past the buffer's end, or a bad message
            return None
        return buffer[:end].toreadonly()


class BagWriter:
    """Context manager writing a rosbag2 bag with MCAP storage.

    Connections are created on first use of a topic. A topic keeps the type of its first message.
    """

    def __init__(
        self, path: Path | str, store: Typestore | None = None, chunk_bytes: int = CHUNK_BYTES
    ) -> None:
        """Prepare a writer; the bag directory is created on ``__enter__``.

        Args:
            path: Bag directory to create; must not exist.
            store: Typestore knowing every type written; default :func:`typestore`.
            chunk_bytes: an MCAP chunk is written out once it holds this many bytes
                (:data:`CHUNK_BYTES`; rosbags writes one out at 1 MiB whatever this is).
        """
        self.path = Path(path)
        self._chunk_bytes = chunk_bytes
        self._store = typestore() if store is None else store
        self._serialiser = CdrSerialiser(self._store)
        self._writer: Writer | None = None
        self._connections: dict[str, Connection] = {}
        self._failed = False  # a write failed: the bag is left as it is

    def __enter__(self) -> BagWriter:
        """Open the bag for writing.

        Raises:
            BagError: If the bag cannot be created (e.g. the path exists).
        """
        try:
            writer = Writer(self.path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
            writer.open()
        except WriterError as error:
            raise BagError(f'{self.path}: cannot create bag: {error}') from None
        self._writer = writer
        return self

    def set_custom_data(self, key: str, value: str) -> None:
        """Record ``key: value`` in the bag's metadata (rosbag2's ``custom_data``), at its close.

        Raises:
            BagError: outside the ``with`` block.
        """
        self._open_writer().set_custom_data(key, value)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Close the bag, writing its summary and metadata; after a failed write, only drop it.

        A bag whose write failed is left as it is (its file closed as the writer goes): a close
        would write its summary after the damage, and fail again on a full disk.

        Raises:
            BagError: if the close cannot write (:meth:`_write_failed`), unless an error is
                already on its way out of the block: that one is the error said.
        """
        writer = self._open_writer()
        self._writer = None
        if self._failed:
            return
        try:
            writer.close()
        except OSError as error:
            if exc is None:
                raise self._write_failed(error) from None

    def write(self, topic: str, msgtype: str, msg: Any, stamp_ns: int) -> None:
        """Serialise one message to CDR and write it.

        Args:
            topic: Topic name, e.g. ``'face/state'``.
            msgtype: Type name, e.g. ``'face_tracking_msgs/msg/FaceState'``.
            msg: A rosbags message of that type (``typestore().types[msgtype](...)``).
            stamp_ns: Record time, ns since the epoch.

        Raises:
            BagError: If the topic has another type, the type is unknown or ``msg`` does not
                fit it, or the bag cannot be written.
        """
        try:
            data = self._serialiser.serialise(msg, msgtype)
        except _SERIALISE_ERRORS as error:
            message = f'{self.path}: cannot serialise {msgtype} on {topic}: {error}'
            raise BagError(message) from None
        self.write_raw(topic, msgtype, data, stamp_ns)

    def write_raw(self, topic: str, msgtype: str, data: bytes, stamp_ns: int) -> None:
        """Write one message already serialised to CDR (e.g. as received from DDS), unchanged.

        Args:
            topic: Topic name, e.g. ``'/face/state'``.
            msgtype: Type name, e.g. ``'face_tracking_msgs/msg/FaceState'``; the typestore
                must know it (its definition goes into the bag).
            data: CDR bytes with their encapsulation header.
            stamp_ns: Record time, ns since the epoch.

        Raises:
            BagError: If the topic has another type or the type is unknown, or the bag cannot
                be written (:meth:`_write_failed`).
        """
        connection = self._connection(topic, msgtype)
        writer = self._open_writer()
        try:
            writer.write(connection, stamp_ns, data)
            self._close_full_chunk(writer)
        except OSError as error:
            self._failed = True
            raise self._write_failed(error) from None

    def _close_full_chunk(self, writer: Writer) -> None:
        """Write the open MCAP chunk out once it holds ``chunk_bytes`` (by rosbags' own close).

        Raises:
            OSError: if the chunk cannot be written.
        """
        storage = writer.storage
        if isinstance(storage, McapWriter) and storage.chunk.bio.tell() >= self._chunk_bytes:
            storage.close_chunk()

    def _write_failed(self, error: OSError) -> BagError:
        """The error of a write to the bag that failed (a full disk, a file size limit).

        The messages in the MCAP chunks written before stay readable, as in a bag cut off
        (:func:`read_raw`); the summary and ``metadata.yaml`` that a close writes are missing.
        """
        reason = error.strerror or str(error)
        msg = (
            f'{self.path}: cannot write the bag: {reason}; it ends where the write failed, '
            'without its summary and metadata.yaml (the messages before stay readable, as in a '
            'bag cut off)'
        )
        return BagError(msg)

    def _open_writer(self) -> Writer:
        """Return the rosbags writer, raising BagError outside the ``with`` block."""
        if self._writer is None:
            raise BagError(f'{self.path}: bag is not open (use BagWriter in a with statement)')
        return self._writer

    def _connection(self, topic: str, msgtype: str) -> Connection:
        """Return the connection of ``topic``, creating it on first use."""
        connection = self._connections.get(topic)
        if connection is None:
            writer = self._open_writer()
            try:
                connection = writer.add_connection(topic, msgtype, typestore=self._store)
            except TypesysError as error:
                message = f'{self.path}: cannot write {msgtype} on {topic}: {error}'
                raise BagError(message) from None
            self._connections[topic] = connection
        elif connection.msgtype != msgtype:
            raise BagError(
                f'{self.path}: topic {topic} has type {connection.msgtype}, cannot write {msgtype}'
            )
        return connection


def read_messages(path: Path | str, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """Read a rosbag2 bag (MCAP or SQLite 3) in record-time order.

    Messages are deserialised with :func:`typestore`; a type that the bag defines otherwise
    (another version of a message) is read with the bag's definition (:mod:`.bag_definitions`).

    Args:
        path: Bag directory (holding ``metadata.yaml``).
        topics: Topics to read; default all. Every one must be in the bag.

    Yields:
        One :class:`BagMessage` per message.

    Raises:
        DamagedBagError: where a damaged bag's readable messages end (:func:`read_raw`).
        BagError: If the bag is missing or corrupt, lacks a requested topic, or holds a type
            neither the typestore nor the bag defines (naming the topic and type, when its
            first message is reached).
    """
    definitions = BagDefinitions(typestore())
    for topic, msgtype, stamp_ns, data, msgdef in read_raw(path, topics):
        reading = definitions.store_for(msgtype, msgdef)
        if msgtype not in reading.types:
            message = (
                f'{path}: cannot read bag: {topic}: unknown message type {msgtype}; '
                'read the other topics with topics=[...]'
            )
            raise BagError(message)
        try:
            # A view: rosbags slices off the 4-byte header, which copies bytes (300 KB per image)
            msg = reading.deserialize_cdr(memoryview(data), msgtype)
        except DESERIALISE_ERRORS as error:
            message = f'{path}: cannot read bag: {topic}: {type(error).__name__}: {error}'
            raise BagError(message) from None
        yield BagMessage(topic, msgtype, stamp_ns, msg)


def read_usable(path: Path | str, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
    """The messages of a bag as :func:`read_messages` reads them; of a damaged bag, those readable.

    For the commands that use what a bag holds (plots, videos, enrolments, learning): a bag cut
    off (its MCAP file without its end, summary and metadata.yaml: a ``track`` or ``replay``
    killed, a full disk) or with a stretch that cannot be read gives the messages
    :func:`read_raw` reads of it, and a :class:`~face_tracking_ros.errors.DamagedBagWarning`
    names the bag, the damage and how many messages were read, where :func:`read_messages`
    raises: the outputs written before the damage stay usable. (A replay reads with
    :func:`read_messages`: it says the damage in its summary and ends with status 1.)

    Args:
        path: Bag directory (holding ``metadata.yaml``) or MCAP file.
        topics: Topics to read; default all. Every one must be in the bag.

    Yields:
        One :class:`BagMessage` per readable message.

    Raises:
        BagError: as :func:`read_messages` does, and for a damaged bag none of whose messages
            (on ``topics``) can be read: nothing to use.
    """
    wanted = None if topics is None else list(topics)
    read = 0
    try:
        for message in read_messages(path, wanted):
            read += 1
            yield message
    except DamagedBagError as error:
        on = '' if wanted is None else f' on {", ".join(wanted)}'
        if not read:
            msg = f'{path}: no message{on} could be read, nothing to use: {error}'
            raise BagError(msg) from None
        messages = f'{wording.counted(read, "message")}{on}'
        said = (
            f'{path} is cut off: using the {messages} read before the cut ({error})'
            if error.cut_off
            else f'{path} is damaged: using the {messages} that could be read ({error})'
        )
        warnings.warn(said, DamagedBagWarning, stacklevel=1)


def read_raw(path: Path | str, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
    """Read the serialised messages of a rosbag2 bag (MCAP or SQLite 3) in record-time order.

    A bag whose metadata or MCAP summary is damaged (e.g. cut off by a power loss) is streamed
    in file order up to the damage, then the BagError says where the damage is. A bag that
    yields fewer messages on a topic than its MCAP summary counts (e.g. zeros written over part
    of it) is read around the damage, then the BagError says how many were read.

    Args:
        path: Bag directory (holding ``metadata.yaml``).
        topics: Topics to read; default all. Every one must be in the bag.

    Yields:
        One :class:`RawMessage` per message; no type needs to be known.

    Raises:
        DamagedBagError: where a damaged bag's readable messages end (:func:`read_usable` uses
            them).
        BagError: If the bag is missing or corrupt, or lacks a requested topic.
    """
    path = Path(path)
    opened = _open_reader(path)
    if opened is None:
        yield from _stream_records(path, topics)
        return
    reader, counted = opened
    read: Counter[str] = Counter()
    try:
        wanted = _select(reader, path, topics)
        for connection, stamp_ns, data in reader.messages(connections=wanted):
            read[connection.topic] += 1
            yield RawMessage(
                connection.topic, connection.msgtype, stamp_ns, data, connection.msgdef.data
            )
    except _READ_ERRORS as error:
        raise BagError(f'{path}: cannot read bag: {type(error).__name__}: {error}') from None
    finally:
        reader.close()
    _check_all_read(path, read, {connection.topic for connection in wanted}, counted)


def _check_all_read(
    path: Path, read: Counter[str], topics: set[str], counted: Counter[str]
) -> None:
    """Raise if fewer messages were read on ``topics`` than the MCAP summaries count (``counted``).

    A stretch of an MCAP file overwritten with zeros (e.g. disk blocks lost) can read as
    records of opcode 0, which readers skip: the messages there vanish without an error.

    Raises:
        DamagedBagError: naming the bag and, per short topic, how many of how many messages
            were read.
    """
    short = [
        f'{read[topic]} of the {wording.counted(counted[topic], "message")} on {topic}'
        for topic in sorted(topics)
        if read[topic] < counted[topic]
    ]
    if short:
        message = (
            f'{path}: damaged MCAP file, read only {", ".join(short)} that its summary counts '
            '(the others are unreadable)'
        )
        raise DamagedBagError(message, cut_off=False)


def _summaries(path: Path) -> list[tuple[Path, Summary | None]]:
    """The MCAP files of a bag (:func:`_listed_files`) with their summaries, read once per open.

    They serve both the type check at the open and the message counts after a full read. A
    file whose summary the mcap library cannot read, or that has none, has None: the type check
    reads its records instead, the counts leave it out and the reading of the bag names its
    damage (rosbags, which read it, is laxer).
    """
    summaries = []
    for file in _listed_files(path):
        summary = None
        with contextlib.suppress(McapError, *_READ_ERRORS), file.open('rb') as stream:
            summary = make_reader(stream).get_summary()
        summaries.append((file, summary))
    return summaries


def _summary_counts(summaries: list[tuple[Path, Summary | None]]) -> Counter[str]:
    """Messages per topic that the summaries count (none where a file has no statistics)."""
    counts: Counter[str] = Counter()
    for _, summary in summaries:
        if summary is None or summary.statistics is None:
            continue
        for channel_id, count in summary.statistics.channel_message_counts.items():
            channel = summary.channels.get(channel_id)
            if channel is not None:
                counts[channel.topic] += count
    return counts


def _open_reader(path: Path) -> tuple[Reader, Counter[str]] | None:
    """An open rosbags Reader and the messages per topic its MCAP summaries count.

    The caller closes the reader. None for a damaged but streamable bag, or one whose summary
    disagrees with itself (:func:`_summary_agrees`).

    Raises:
        BagError: If the bag can be read neither way, or it is a directory of several MCAP
            files without the metadata.yaml that would say they are one bag.
    """
    try:
        reader = Reader(path)
        reader.open()
    except _READ_ERRORS as error:
        files = _mcap_files(path)
        unlisted = path.is_dir() and not (path / 'metadata.yaml').exists()
        if unlisted and len(files) > 1:
            msg = (
                f'{path}: {len(files)} MCAP files ({", ".join(file.name for file in files)}) and '
                'no metadata.yaml saying they are one bag: give one .mcap file, or a rosbag2 '
                'directory (with its metadata.yaml)'
            )
            raise BagError(msg) from None
        if files:
            return None
        if unlisted:
            raise BagError(_not_a_bag(path)) from None
        raise BagError(f'{path}: cannot read bag: {type(error).__name__}: {error}') from None
    try:
        summaries = _summaries(path)
        listed = set(_metadata_topics(path))
        if not all(_summary_agrees(summary, listed) for _, summary in summaries):
            reader.close()
            return None
        _check_types_agree(reader, path, summaries)
    except BaseException:
        reader.close()
        raise
    return reader, _summary_counts(summaries)


def _summary_agrees(summary: Summary | None, listed: set[str]) -> bool:
    """Whether an MCAP summary declares every channel its statistics count, on ``listed`` topics.

    rosbags takes the channels from the summary and pairs them with ``metadata.yaml``'s topics
    (``listed``; none to check without it): a summary's channel record damaged in its id or its
    topic name leaves the messages the chunks give that channel silently unread. The chunks
    declare their channels themselves, so such a file is streamed.
    """
    if summary is None:
        return True
    counted = (
        set() if summary.statistics is None else set(summary.statistics.channel_message_counts)
    )
    topics = {channel.topic for channel in summary.channels.values()}
    return counted <= set(summary.channels) and (not listed or topics <= listed)


def _not_a_bag(directory: Path) -> str:
    """Why ``directory`` (no metadata.yaml, no .mcap file) is not a bag; the bags it holds, if any.

    A directory of recordings (such as the repository's bags/stereo_train) is easily given where
    its bags are meant.
    """
    held = _bag_names_in(directory)
    msg = f'{directory}: not a rosbag2 bag (no metadata.yaml and no .mcap file in it)'
    if not held:
        return msg
    shown = ', '.join(held[:MAX_NAMED_BAGS]) + (', ...' if len(held) > MAX_NAMED_BAGS else '')
    return (
        f'{msg}; it holds {counted(len(held), "bag")} ({shown}): give the bags themselves (e.g. '
        f'{directory}/*), not the directory holding them'
    )


def _bag_names_in(directory: Path) -> list[str]:
    """The names of the bags (metadata.yaml or .mcap files) among a directory's subdirectories."""
    try:
        subdirectories = [sub for sub in directory.iterdir() if sub.is_dir()]
    except OSError:  # unreadable: no bags to name
        return []
    return sorted(sub.name for sub in subdirectories if is_bag_directory(sub))


def is_bag_directory(directory: Path) -> bool:
    """Whether ``directory`` holds a metadata.yaml or .mcap files; False if it cannot be entered.

    The rule by which a directory is a bag: the one that names the bags of a directory given as
    a bag (:func:`_bag_names_in`) and lists those of the learner node's ``bag_dir``. A user may
    list a directory but not look inside it (a drive's lost+found): Path.is_file raises
    PermissionError there, where the directory holding it was to be named as no bag.
    """
    try:
        return (directory / 'metadata.yaml').is_file() or bool(_mcap_files(directory))
    except OSError:
        return False


def _check_types_agree(
    reader: Reader, path: Path, summaries: list[tuple[Path, Summary | None]]
) -> None:
    """Refuse a bag whose ``metadata.yaml`` gives a topic another type than its MCAP file does.

    rosbags pairs the two by topic and type: the messages of such a topic were silently not read.
    The MCAP files' types are their summaries' channels and schemas (:func:`_summaries`), or,
    for a file without a readable summary, those its records declare (:func:`_scanned_types`).
    A single MCAP file (no ``metadata.yaml``) gives rosbags its types itself: nothing to check.

    Raises:
        BagError: naming the topic, the type ``metadata.yaml`` says and the file's own (schema).
    """
    if not path.is_dir():
        return
    listed: dict[str, set[str]] = {}
    for connection in reader.connections:
        listed.setdefault(connection.topic, set()).add(connection.msgtype)
    for file, summary in summaries:
        stored = _scanned_types(file) if summary is None else _stored_types(summary)
        for topic, msgtype in stored:
            if topic in listed and msgtype not in listed[topic]:
                said = ' or '.join(sorted(listed[topic]))
                msg = (
                    f'{path}: metadata.yaml says topic {topic} is {said}, but {file.name} stores '
                    f'it as {msgtype} (its schema): its messages cannot be read; correct the type '
                    'in metadata.yaml'
                )
                raise BagError(msg)


def _stored_types(summary: Summary) -> list[tuple[str, str]]:
    """(topic, type) of each channel of an MCAP file's summary, the type its schema's name."""
    schemas = summary.schemas
    return [
        (channel.topic, schemas[channel.schema_id].name)
        for channel in summary.channels.values()
        if channel.schema_id in schemas
    ]


def _scanned_types(file: Path) -> list[tuple[str, str]]:
    """(topic, type) of each channel an MCAP file's records declare, the type its schema's name.

    For a file without a readable summary. A channel is declared before its first message,
    which can come anywhere in the file (a topic first published late), so every record is
    read; past damage none is, and the reading of the bag names the damage.
    """
    schemas: dict[int, str] = {}
    types = []
    with contextlib.suppress(McapError, *_READ_ERRORS), file.open('rb') as stream:
        for record in StreamReader(stream).records:
            if isinstance(record, Schema):
                schemas[record.id] = record.name
            elif isinstance(record, Channel) and record.schema_id in schemas:
                types.append((record.topic, schemas[record.schema_id]))
    return types


def _listed_files(path: Path) -> list[Path]:
    """The MCAP files a bag's ``metadata.yaml`` lists, as rosbags finds them (by name, beside it).

    Without that list, the MCAP files of the directory (:func:`_mcap_files`). Another file in
    the directory (a copy, a backup) is not part of the bag.
    """
    names = _metadata(path).get('relative_file_paths') or []
    listed = [path / PurePath(str(name)).name for name in names]
    return [file for file in listed if file.suffix == '.mcap'] if listed else _mcap_files(path)


def _mcap_files(path: Path) -> list[Path]:
    """The MCAP files of a bag directory (or the file itself), sorted."""
    if path.is_file() and path.suffix == '.mcap':
        return [path]
    return sorted(path.glob('*.mcap')) if path.is_dir() else []


def _stream_records(path: Path, topics: Iterable[str] | None) -> Iterator[RawMessage]:
    """Stream the raw messages of a bag's MCAP files in file order, up to any damage.

    A truncated MCAP file (e.g. a recorder killed by a power loss) has no summary, so rosbags
    cannot open it; its records up to the damage are still valid. They are yielded, then a
    BagError says where the damage is. ``metadata.yaml`` is not needed.

    Yields:
        The raw messages, with their log time.

    Raises:
        DamagedBagError: At the damage, naming the file and the number of messages recovered.
        BagError: for an undamaged file, if a requested topic is not in it.
    """
    wanted = None if topics is None else set(topics)
    channels: dict[int, tuple[str, str, str]] = {}
    schemas: dict[int, tuple[str, str]] = {}
    count = 0
    files = _mcap_files(path)
    for file in files:
        try:
            with file.open('rb') as stream:
                for record in _file_records(stream, file.stat().st_size):
                    if isinstance(record, Schema):
                        schemas[record.id] = (record.name, _schema_text(record))
                    elif isinstance(record, Channel):
                        msgtype, msgdef = schemas.get(record.schema_id, ('', ''))
                        channels[record.id] = (record.topic, msgtype, msgdef)
                    elif isinstance(record, Message) and record.channel_id in channels:
                        topic, msgtype, msgdef = channels[record.channel_id]
                        if wanted is None or topic in wanted:
                            count += 1
                            yield RawMessage(topic, msgtype, record.log_time, record.data, msgdef)
        except (McapError, *_READ_ERRORS) as error:
            damage = _damage(error)
            recovered = wording.counted(count, 'message')
            message = f'{file}: damaged MCAP file, {recovered} recovered before: {damage}'
            raise DamagedBagError(message, cut_off=isinstance(error, EndOfFile)) from None
    missing = (wanted or set()) - {topic for topic, _, _ in channels.values()}
    if missing:
        raise BagError(f'{path}: no topic {", ".join(sorted(missing))} in bag')


def _damage(error: Exception) -> str:
    """What a damage the MCAP stream reader stopped at is, in the user's words.

    The reader's InvalidMagic quotes the 8 bytes it found, as numbers; a file that does not
    begin (or end) with the MCAP magic is no MCAP file, or one whose first or last bytes were
    lost.
    """
    if isinstance(error, EndOfFile):
        return 'the file ends part way (truncated)'
    if isinstance(error, InvalidMagic):
        return 'its first or last 8 bytes are not the MCAP magic (not an MCAP file?)'
    return f'{type(error).__name__}: {error}'


def _file_records(stream: BinaryIO, size: int) -> Iterator[McapRecord]:
    """The records of an MCAP file of ``size`` bytes, as StreamReader reads them.

    A file that ends inside a record's header (its opcode and length) or its closing magic made
    StreamReader unpack too few bytes: its struct.error is the EndOfFile of a truncated file.
    """
    try:
        yield from StreamReader(stream).records
    except struct.error:
        if stream.tell() < size:  # a short read inside the file: damage, not its end
            raise
        raise EndOfFile from None


def _schema_text(schema: Schema) -> str:
    """A ros2msg schema's definition text; '' for another encoding or undecodable bytes."""
    if schema.encoding != 'ros2msg':
        return ''
    try:
        return schema.data.decode()
    except UnicodeDecodeError:
        return ''


def _select(reader: Reader, path: Path, topics: Iterable[str] | None) -> list[Connection]:
    """Return the connections of ``topics`` (all if None), raising BagError for missing ones."""
    if topics is None:
        return list(reader.connections)
    wanted = set(topics)
    missing = wanted - {connection.topic for connection in reader.connections}
    if missing:
        raise BagError(f'{path}: no topic {", ".join(sorted(missing))} in bag')
    return [connection for connection in reader.connections if connection.topic in wanted]


def bag_topics(path: Path | str) -> dict[str, str]:
    """Topics of a bag and their message types.

    Raises:
        BagError: If the bag is missing or its metadata cannot be read.
    """
    return {connection.topic: connection.msgtype for connection in _connections(Path(path))}


def topic_has_word(topic: str, word: str) -> bool:
    """Whether ``word`` stands in ``topic``'s name between non-letters (or its ends).

    E.g. ``left`` in ``/stereo/left/image_raw``, ``cam_left`` and ``left_camera``; not in
    ``/cleft_palate/camera_info`` nor ``/leftover/camera_info``. Case is ignored.
    """
    return re.search(rf'(?<![a-z]){re.escape(word)}(?![a-z])', topic.lower()) is not None


def recording_name(path: Path | str) -> str:
    """The name of the recording a bag holds: its subject, init file and tracked meshes go by it.

    A rosbag2 directory's name; an MCAP file's name without ``.mcap`` (``anna_1.mcap``:
    ``anna_1``), or, for a file of a rosbag2 directory (beside its ``metadata.yaml``), the
    directory's (``anna_1/anna_1_0.mcap``: ``anna_1``).
    """
    path = Path(path)
    if path.suffix != '.mcap' or path.is_dir():
        return path.name
    directory = path.absolute().parent
    return directory.name if (directory / 'metadata.yaml').is_file() else path.stem


def check_distinct_bags(bags: Iterable[Path | str]) -> None:
    """Refuse a bag given twice to a command that pools its bags' frames.

    The same bag however written: a path through ``.``, a symbolic link, or a bag's only MCAP
    file beside its directory (:func:`_bag_identity`).

    Raises:
        ConfigError: naming the bag and its second spelling.
    """
    seen: dict[Path, Path] = {}
    for bag in map(Path, bags):
        first = seen.setdefault(_bag_identity(bag), bag)
        if first is not bag:
            msg = f'bag {first} given twice (also as {bag}): its frames would count twice'
            raise ConfigError(msg)


def _bag_identity(bag: Path) -> Path:
    """The resolved directory of a bag, or of the MCAP file that is its only one."""
    resolved = bag.resolve()
    if resolved.suffix == '.mcap' and _listed_files(resolved.parent) == [resolved]:
        return resolved.parent
    return resolved


def message_count(path: Path | str, topics: Iterable[str]) -> int:
    """Number of messages on ``topics`` in a bag, from its metadata.

    Raises:
        BagError: If the bag is missing or its metadata cannot be read.
    """
    wanted = set(topics)
    return sum(c.msgcount for c in _connections(Path(path)) if c.topic in wanted)


def _connections(path: Path) -> list[Connection]:
    """The connections of a bag, from its metadata (or salvaged from a damaged MCAP file)."""
    opened = _open_reader(path)
    if opened is None:
        return _salvaged_connections(path)
    reader = opened[0]
    try:
        return list(reader.connections)
    finally:
        reader.close()


def _salvaged_connections(path: Path) -> list[Connection]:
    """Connections (topic, type, readable message count) of a damaged bag, by streaming it.

    Topics that ``metadata.yaml`` lists but the damaged file does not reach have a count of 0.

    Raises:
        BagError: naming the damage, when neither the file nor ``metadata.yaml`` gives a topic
            (a file that is no MCAP file, or one cut before its first channel): a bag without
            topics would be refused for the topics it lacks, not for what it is.
    """
    counts: Counter[tuple[str, str]] = Counter(dict.fromkeys(_metadata_topics(path).items(), 0))
    try:
        for topic, msgtype, *_ in _stream_records(path, None):
            counts[topic, msgtype] += 1
    except BagError:
        if not counts:
            raise
    return [
        Connection(i, topic, msgtype, None, '', n, None, None)  # type: ignore[arg-type]
        for i, ((topic, msgtype), n) in enumerate(counts.items())
    ]


def custom_data(path: Path | str) -> dict[str, str]:
    """The ``custom_data`` of a bag's ``metadata.yaml`` ({} if it has none or is unreadable).

    rosbag2 keeps there what its writer was asked to record (:meth:`BagWriter.set_custom_data`);
    rosbags' reader does not expose it.
    """
    try:
        return {str(k): str(v) for k, v in (_metadata(Path(path))['custom_data'] or {}).items()}
    except (KeyError, TypeError, AttributeError):
        return {}


def _metadata_topics(path: Path) -> dict[str, str]:
    """Topics and types listed by a bag's ``metadata.yaml`` ({} if it is missing or unreadable)."""
    try:
        return {
            entry['topic_metadata']['name']: entry['topic_metadata']['type']
            for entry in _metadata(path)['topics_with_message_count']
        }
    except (KeyError, TypeError):
        return {}


def _metadata(path: Path) -> dict[str, Any]:
    """A bag's ``metadata.yaml`` information ({} if it is missing or unreadable).

    Unreadable includes bytes that are not UTF-8 text (a file overwritten by another's blocks):
    the bag is then read from its MCAP files, as without the file.
    """
    try:
        info = parse_yaml((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError):
        return {}
    return info if isinstance(info, dict) else {}
