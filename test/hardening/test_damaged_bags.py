"""Damaged bags: cut at random offsets, no metadata.yaml, unknown types, missing topics.

The readers yield what is readable, in order and unchanged, and say where and why they stopped;
offline replay processes the readable part, says so and exits with status 1.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
import shutil
import subprocess
import sys

from cut_bags import cut_copy, read_until_damage
from fault_scenes import CAMERA, image_msg, info_msg, stamp
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from summaryless_bags import summaryless_copy
from zeroed_bags import zeroed_copy

from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import BagError
from face_tracking_ros.io import bags
from face_tracking_ros.io.bags import (
    BagWriter,
    bag_topics,
    message_count,
    read_messages,
    read_raw,
    stamp_to_ns,
)
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore

from repo_root import REPO

FRAMES = 40
CUTS = 24
IMAGE, INFO = 'sensor_msgs/msg/Image', 'sensor_msgs/msg/CameraInfo'
CHANNEL_OPCODE = 0x04
MONO = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'


@pytest.fixture(scope='module')
def bag(tmp_path_factory) -> Path:
    """40 frames of camera_info and a 320x240 noise image (~3 MB: several MCAP chunks).

    In chunks of 1 MiB (13 frames, both topics), as a recorder writing them so leaves them: the
    zeroed stretch of its middle chunk hides messages of both topics.
    """
    path = tmp_path_factory.mktemp('bags') / 'camera'
    rng = np.random.default_rng(0)
    with BagWriter(path, chunk_bytes=1 << 20) as writer:
        for f in range(FRAMES):
            writer.write('/cam/camera_info', INFO, info_msg(CAMERA, stamp(f)), stamp(f))
            pixels = rng.integers(0, 256, (CAMERA.height, CAMERA.width), dtype=np.uint8)
            writer.write('/cam/image', IMAGE, image_msg(pixels, stamp(f)), stamp(f) + 1)
    return path


def _refusals(path: Path) -> list[str]:
    """The BagError of bag_topics, read_raw and read_messages on ``path`` (each must raise)."""
    refusals = []
    for read in (bag_topics, read_raw, read_messages):
        with pytest.raises(BagError) as error:
            list(read(path))
        refusals.append(str(error.value))
    return refusals


@pytest.fixture
def mcap_opens(monkeypatch) -> Counter[str]:
    """How often each MCAP file is opened (Path.open, by file name) from here on."""
    opened: Counter[str] = Counter()
    path_open = Path.open

    def counting_open(self: Path, *args, **kwargs):
        opened[self.name] += self.suffix == '.mcap'
        return path_open(self, *args, **kwargs)

    monkeypatch.setattr(Path, 'open', counting_open)
    return opened


def test_a_bag_cut_anywhere_yields_an_unchanged_prefix_and_says_where_it_stopped(bag, tmp_path):
    original = list(read_raw(bag))
    assert len(original) == 2 * FRAMES
    fractions = np.sort(np.random.default_rng(1).uniform(0.0, 1.0, CUTS))
    recovered = []
    for n, fraction in enumerate(fractions):
        cut = cut_copy(bag, tmp_path / f'cut{n}', fraction, keep_metadata=n % 2 == 0)
        messages, error = read_until_damage(cut)
        assert messages == original[: len(messages)], f'cut at {fraction:.3f}: not a prefix'
        assert f'damaged MCAP file, {len(messages)} messages recovered before' in error
        assert str(next(cut.glob('*.mcap'))) in error
        assert not error.endswith(': ')  # the damage is described (a bare 'EndOfFile: ' was not)
        # The salvaged bag's topics and counts describe exactly what is readable.
        if messages:
            readable = {m.topic: m.msgtype for m in messages}
            assert bag_topics(cut) == readable
            assert message_count(cut, readable) == len(messages)
        recovered.append(len(messages))
        shutil.rmtree(cut)
    assert recovered == sorted(recovered), 'a longer file must not recover fewer messages'
    assert recovered[-1] >= FRAMES, f'the last chunks should survive a late cut: {recovered}'


def test_a_bag_zeroed_in_its_middle_is_read_around_the_damage_then_says_what_is_missing(
    bag, tmp_path
):
    """Zeros that read as skippable records: the summary still counts the messages they hid."""
    zeroed = tmp_path / 'zeroed'
    lost = zeroed_copy(bag, zeroed)
    assert lost['/cam/image'] > 0 and lost['/cam/camera_info'] > 0
    messages, error = read_until_damage(zeroed)
    original, read = list(read_raw(bag)), set(messages)
    assert messages == [m for m in original if m in read]  # the others, in order and unchanged
    assert len(messages) == len(original) - lost.total()
    short = ', '.join(
        f'{FRAMES - n} of the {FRAMES} messages on {topic}' for topic, n in sorted(lost.items())
    )
    assert error == (
        f'{zeroed}: damaged MCAP file, read only {short} that its summary counts '
        '(the others are unreadable)'
    )
    info = f'{FRAMES - lost["/cam/camera_info"]} of the {FRAMES} messages on /cam/camera_info'
    with pytest.raises(BagError, match=f'read only {info} that its summary'):  # topics read only
        list(read_raw(zeroed, topics=['/cam/camera_info']))


def test_a_read_opens_its_mcap_file_for_rosbags_and_once_for_the_summary(bag, mcap_opens):
    """The summary read at the open serves the type check and the counts of a full read.

    The type check opened the file a second time (a rosbags Reader of the file alone), and the
    counts after a full read a third (its summary again).
    """
    assert len(list(read_raw(bag))) == 2 * FRAMES
    assert mcap_opens['camera.mcap'] == 2
    mcap_opens.clear()
    assert bag_topics(bag) == {'/cam/camera_info': INFO, '/cam/image': IMAGE}
    assert mcap_opens['camera.mcap'] == 2


def test_a_stray_mcap_file_beside_a_bag_is_not_counted_as_its_messages(bag, tmp_path):
    """Only the files metadata.yaml lists are the bag: a copy beside them is not damage."""
    copied = shutil.copytree(bag, tmp_path / 'with_backup')
    listed = next(copied.glob('*.mcap'))
    shutil.copy(listed, copied / f'backup_of_{listed.name}')
    assert len(list(read_raw(copied))) == len(list(read_raw(bag)))  # and no BagError


@pytest.mark.parametrize(
    'metadata', [b'\x89PNG\r\n\x1a\n\xff\xfe', b'rosbag2_bagfile_information: [', b'']
)
def test_a_metadata_file_that_is_not_yaml_text_is_read_around(bag, tmp_path, metadata):
    """A metadata.yaml of binary bytes, broken YAML or nothing: the MCAP file is the bag."""
    damaged = shutil.copytree(bag, tmp_path / 'damaged')
    (damaged / 'metadata.yaml').write_bytes(metadata)
    assert bag_topics(damaged) == bag_topics(bag)
    assert [(m.topic, m.stamp_ns) for m in read_raw(damaged)] == [
        (m.topic, m.stamp_ns) for m in read_raw(bag)
    ]


@pytest.mark.parametrize('directory', [False, True])
def test_a_file_that_is_no_mcap_file_is_named_as_such_not_as_a_bag_without_topics(
    tmp_path, directory
):
    """Notes saved as .mcap, alone or in a directory without metadata.yaml: no topic to name."""
    folder = tmp_path / 'notes' if directory else tmp_path
    folder.mkdir(exist_ok=True)
    (folder / 'notes.mcap').write_text('these are my notes, not a recording\n')
    given = folder if directory else folder / 'notes.mcap'
    for read in (bag_topics, read_raw):
        with pytest.raises(BagError) as raised:
            list(read(given))
        assert str(raised.value) == (
            f'{folder / "notes.mcap"}: damaged MCAP file, 0 messages recovered before: its first '
            'or last 8 bytes are not the MCAP magic (not an MCAP file?)'
        )


def test_a_bag_zeroed_anywhere_yields_messages_of_its_own_or_a_bag_error(bag, tmp_path):
    """Short stretches of zeros at random: a record length read from them can pass 2**63."""
    data = next(bag.glob('*.mcap')).read_bytes()
    original = {(m.topic, m.stamp_ns) for m in read_raw(bag)}
    rng = np.random.default_rng(2)
    for n in range(CUTS):
        start = round(rng.uniform(0.05, 0.9) * len(data))
        end = start + round(rng.uniform(0.001, 0.05) * len(data))
        zeroed = shutil.copytree(bag, tmp_path / f'zeroed{n}')
        next(zeroed.glob('*.mcap')).write_bytes(data[:start] + bytes(end - start) + data[end:])
        messages, error = read_until_damage(zeroed)  # no other exception
        assert {(m.topic, m.stamp_ns) for m in messages} <= original
        assert error.startswith(f'{zeroed}: ') or not error and len(messages) == len(original)
        shutil.rmtree(zeroed)


def test_a_bag_cut_inside_its_header_reports_nothing_recovered(bag, tmp_path):
    cut = cut_copy(bag, tmp_path / 'cut', 4 / next(bag.glob('*.mcap')).stat().st_size)
    messages, error = read_until_damage(cut)
    assert messages == []
    assert 'damaged MCAP file, 0 messages recovered before' in error


def test_an_empty_bag_directory_is_a_bag_error(tmp_path):
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagError, match=r'empty: not a rosbag2 bag \(no metadata.yaml and no '):
        list(read_messages(tmp_path / 'empty'))


def test_a_directory_of_bags_given_as_a_bag_names_the_bags_it_holds(bag, tmp_path):
    recordings = tmp_path / 'recordings'
    shutil.copytree(bag, recordings / 'anna_1')
    cut_copy(bag, recordings / 'ben_1', 1.0, keep_metadata=False)  # a directory with its .mcap
    (recordings / 'notes').mkdir()
    with pytest.raises(BagError) as raised:
        list(read_messages(recordings))
    assert str(raised.value) == (
        f'{recordings}: not a rosbag2 bag (no metadata.yaml and no .mcap file in it); it holds 2 '
        f'bags (anna_1, ben_1): give the bags themselves (e.g. {recordings}/*), not the '
        'directory holding them'
    )


def test_a_directory_of_many_bags_names_the_first_few(tmp_path):
    for name in ('f', 'e', 'd', 'c', 'b', 'a'):  # a metadata.yaml is enough to be named
        (tmp_path / 'many' / name).mkdir(parents=True)
        (tmp_path / 'many' / name / 'metadata.yaml').touch()
    with pytest.raises(BagError, match=r'it holds 6 bags \(a, b, c, d, e, \.\.\.\): give'):
        list(read_messages(tmp_path / 'many'))


def test_a_subdirectory_that_cannot_be_entered_is_not_among_the_bags_named(
    bag, tmp_path, monkeypatch
):
    """A drive's lost+found, say: listed in the directory, but a user may not look inside it."""
    drive = tmp_path / 'drive'
    shutil.copytree(bag, drive / 'anna_1')
    locked = drive / 'lost+found'
    locked.mkdir()
    stat = Path.stat

    def refused(path: Path, **kwargs: bool):  # os.stat of a path inside it, without root
        if path.parent == locked:
            raise PermissionError(13, 'Permission denied', str(path))
        return stat(path, **kwargs)

    monkeypatch.setattr(Path, 'stat', refused)
    with pytest.raises(BagError, match=r'drive: not a rosbag2 bag .* it holds 1 bag \(anna_1\)'):
        list(read_messages(drive))


def test_without_metadata_a_requested_topic_the_bag_lacks_is_named(bag, tmp_path):
    copy = cut_copy(bag, tmp_path / 'copy', 1.0, keep_metadata=False)
    assert len(list(read_messages(copy, topics=['/cam/image']))) == FRAMES
    with pytest.raises(BagError, match='no topic /cam/depth in bag'):
        list(read_messages(copy, topics=['/cam/image', '/cam/depth']))


def _retype(bag: Path, stored: str, said: str) -> None:
    """Make a bag's metadata.yaml say ``said`` for its one topic of type ``stored``."""
    metadata = bag / 'metadata.yaml'
    text = metadata.read_text()
    assert text.count(f'type: {stored}') == 1
    metadata.write_text(text.replace(f'type: {stored}', f'type: {said}'))


def test_a_type_in_metadata_that_contradicts_the_mcap_schema_names_both(bag, tmp_path, capsys):
    """The reader pairs metadata and MCAP channels by topic and type: the image went unread."""
    copy = cut_copy(bag, tmp_path / 'copy', 1.0)
    _retype(copy, IMAGE, INFO)
    expected = (
        f'{copy}: metadata.yaml says topic /cam/image is {INFO}, but camera.mcap stores it as '
        f'{IMAGE} (its schema): its messages cannot be read; correct the type in metadata.yaml'
    )
    assert _refusals(copy) == [expected] * 3
    assert main(['replay', 'mono_tracker', str(copy), '--out', str(tmp_path / 'out')]) == 2
    assert capsys.readouterr().err == f'error: {expected}\n'


LATE = 30  # the first frame of late_topic_bag with a camera_info


@pytest.fixture(scope='module')
def late_topic_bag(bag, tmp_path_factory) -> Path:
    """``bag`` with camera_info from frame LATE on: its channel is declared in a late chunk."""
    path = tmp_path_factory.mktemp('late') / 'late'
    with BagWriter(path) as writer:
        for message in read_raw(bag):
            if message.topic == '/cam/image' or message.stamp_ns >= stamp(LATE):
                writer.write_raw(message.topic, message.msgtype, message.data, message.stamp_ns)
    return path


def _messages_before_channel(mcap_file: Path, topic: str) -> int:
    """How many messages an MCAP file holds before the channel record of ``topic``."""
    with mcap_file.open('rb') as stream:
        before = 0
        for record in StreamReader(stream).records:
            if isinstance(record, Channel) and record.topic == topic:
                return before
            before += isinstance(record, Message)
    raise AssertionError(f'{mcap_file}: no channel {topic}')


def test_a_bag_without_summary_whose_metadata_contradicts_a_late_schema_names_both(
    late_topic_bag, tmp_path
):
    """Its records say the file's types; rosbags read the image as camera_info, silently none."""
    copy = tmp_path / 'copy'
    mcap_file = summaryless_copy(late_topic_bag, copy)
    assert _messages_before_channel(mcap_file, '/cam/camera_info') == LATE  # after ~2 MB
    _retype(copy, INFO, IMAGE)
    expected = (
        f'{copy}: metadata.yaml says topic /cam/camera_info is {IMAGE}, but late.mcap stores it '
        f'as {INFO} (its schema): its messages cannot be read; correct the type in metadata.yaml'
    )
    assert _refusals(copy) == [expected] * 3


def test_a_bag_without_summary_reads_every_message_and_streams_what_a_cut_leaves(
    late_topic_bag, tmp_path, mcap_opens
):
    """Its file is read once more, for its types; alone (no metadata.yaml) it types itself."""
    copy = tmp_path / 'copy'
    mcap_file = summaryless_copy(late_topic_bag, copy)
    original = list(read_raw(late_topic_bag))
    assert len(original) == FRAMES + FRAMES - LATE
    mcap_opens.clear()
    assert list(read_raw(copy)) == original
    assert mcap_opens['late.mcap'] == 3  # rosbags, its summary (none), its records
    assert bag_topics(copy) == {'/cam/camera_info': INFO, '/cam/image': IMAGE}
    assert [(m.topic, m.stamp_ns) for m in read_messages(copy)] == [
        (m.topic, m.stamp_ns) for m in original
    ]
    mcap_opens.clear()
    assert list(read_raw(mcap_file)) == original
    assert mcap_opens['late.mcap'] == 2
    cut = cut_copy(copy, tmp_path / 'cut', 0.5)
    messages, error = read_until_damage(cut)
    assert 0 < len(messages) < len(original)
    assert messages == original[: len(messages)]
    assert error.startswith(f'{cut / "late.mcap"}: damaged MCAP file, {len(messages)} messages ')


def test_a_directory_of_two_mcap_files_without_metadata_is_refused(bag, tmp_path):
    """They were read as one bag, their messages interleaved file after file."""
    two = tmp_path / 'two'
    two.mkdir()
    for name in ('a.mcap', 'b.mcap'):
        shutil.copy(next(bag.glob('*.mcap')), two / name)
    expected = (
        f'{two}: 2 MCAP files (a.mcap, b.mcap) and no metadata.yaml saying they are one bag: '
        'give one .mcap file, or a rosbag2 directory (with its metadata.yaml)'
    )
    assert _refusals(two) == [expected] * 3
    assert len(list(read_raw(two / 'a.mcap'))) == 2 * FRAMES  # one of them, as the error says


@pytest.fixture(scope='module')
def bag_with_unknown_type(tmp_path_factory) -> Path:
    """Five Float64 on /n and five robot_msgs/msg/Battery (unknown to the project) on /battery."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg('float64 level\nstring note', 'robot_msgs/msg/Battery'))
    factory = RosbagsMessages(store)
    path = tmp_path_factory.mktemp('unknown') / 'bag'
    with BagWriter(path, store=store) as writer:
        for i in range(5):
            battery = factory.make('robot_msgs/msg/Battery', level=0.9 - 0.1 * i, note='ok')
            writer.write('/battery', 'robot_msgs/msg/Battery', battery, 10 * i)
            number = factory.make('std_msgs/msg/Float64', data=float(i))
            writer.write('/n', 'std_msgs/msg/Float64', number, 10 * i + 1)
    return path


def test_a_type_the_project_does_not_know_is_read_as_the_bag_defines_it(bag_with_unknown_type):
    path = bag_with_unknown_type
    assert bag_topics(path) == {'/battery': 'robot_msgs/msg/Battery', '/n': 'std_msgs/msg/Float64'}
    assert [m.msg.data for m in read_messages(path, topics=['/n'])] == [0, 1, 2, 3, 4]
    assert len(list(read_raw(path, topics=['/battery']))) == 5  # raw copies need no type
    batteries = [m.msg for m in read_messages(path, topics=['/battery'])]
    assert [b.level for b in batteries] == pytest.approx([0.9, 0.8, 0.7, 0.6, 0.5])
    assert {b.note for b in batteries} == {'ok'}


def test_a_type_unknown_to_the_project_and_undefined_in_the_bag_is_named(
    bag_with_unknown_type, monkeypatch
):
    undefined = [raw._replace(msgdef='') for raw in read_raw(bag_with_unknown_type)]
    monkeypatch.setattr(bags, 'read_raw', lambda path, topics=None: iter(undefined))
    with pytest.raises(BagError, match='/battery: unknown message type robot_msgs/msg/Battery'):
        list(read_messages(bag_with_unknown_type))


def test_a_bag_of_another_version_of_a_message_is_read_as_it_defines_it(tmp_path):
    """face/state written before FaceState had right_node_residuals or occluded stays readable."""
    state = 'face_tracking_msgs/msg/FaceState'
    text, _ = typestore().generate_msgdef(state)
    assert 'float64[] right_node_residuals\n' in text  # this version's FaceState has it
    other = get_typestore(Stores.EMPTY)
    earlier = text.replace('float64[] right_node_residuals\n', '').replace('bool[] occluded\n', '')
    other.register(get_types_from_msg(earlier, state))
    header = other.types['std_msgs/msg/Header'](
        stamp=other.types['builtin_interfaces/msg/Time'](sec=1, nanosec=2), frame_id='cam'
    )
    pose = other.types['geometry_msgs/msg/Pose'](
        position=other.types['geometry_msgs/msg/Point'](x=0.0, y=0.0, z=0.6),
        orientation=other.types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    message = other.types[state](
        header=header, face_id='face_0', status=1, pose=pose, omega=np.zeros(3),
        alpha=np.array([0.5]), sigma=np.array([0.25]), node_names=['a'], nodes=[],
        image_points=[], node_residuals=np.array([3.0]), mean_residual=3.5, iterations=7,
    )  # fmt: skip
    path = tmp_path / 'old'
    with BagWriter(path, store=other) as writer:
        writer.write('face/state', state, message, 10)
    read = next(read_messages(path)).msg
    assert (read.face_id, read.status, read.iterations) == ('face_0', 1, 7)
    assert (read.mean_residual, list(read.node_residuals), list(read.alpha)) == (3.5, [3.0], [0.5])
    assert not hasattr(read, 'right_node_residuals') and not hasattr(read, 'occluded')


# --- offline replay -----------------------------------------------------------------------------


def _replay(bag: Path, out: Path, capsys) -> tuple[int, str]:
    status = main(['replay', 'mono_tracker', str(bag), '--out', str(out), '--quiet'])
    return status, capsys.readouterr().out


def test_replay_of_a_cut_bag_processes_the_readable_part_and_exits_1(bag, tmp_path, capsys):
    tracked = []
    for n, fraction in enumerate((0.3, 0.7, 0.95)):
        cut = cut_copy(bag, tmp_path / f'cut{n}', fraction)
        readable = read_until_damage(cut)[0]
        images = [m.stamp_ns - 1 for m in readable if m.topic == '/cam/image']
        infos = len(readable) - len(images)
        status, output = _replay(cut, tmp_path / f'out{n}', capsys)
        assert status == 1, output
        read_line = f'read: {infos} camera_info, {len(images)} image' if readable else 'read: none'
        assert read_line in output
        assert 'input bag damaged, replayed its readable part: ' in output
        assert f'damaged MCAP file, {len(readable)} messages recovered before' in output
        out = tmp_path / f'out{n}'
        states = list(read_messages(out, topics=['face/state'])) if images else []
        assert [stamp_to_ns(m.msg.header.stamp) for m in states] == images
        tracked.append(len(states))
    assert tracked[-1] > 0, tracked


def test_replay_of_a_bag_without_calibration_says_why_nothing_was_tracked(bag, tmp_path, capsys):
    images_only = tmp_path / 'images'
    with BagWriter(images_only) as writer:
        for message in read_raw(bag, topics=['/cam/image']):
            writer.write_raw(message.topic, message.msgtype, message.data, message.stamp_ns)
    status, output = _replay(images_only, tmp_path / 'out', capsys)
    assert status == 0
    assert f'read: {FRAMES} image' in output
    assert f'  {FRAMES - 1}x image: no calibration on camera_info yet' in output  # 1st held
    assert list(read_messages(tmp_path / 'out')) == []


def test_replay_of_a_bag_without_any_input_topic_names_what_it_needs(
    bag_with_unknown_type, tmp_path, capsys
):
    status = main(['replay', 'mono_tracker', str(bag_with_unknown_type), '--out', 'x'])
    assert status == 2
    error = capsys.readouterr().err
    assert 'no topic matches the inputs of mono_tracker' in error
    assert 'image (sensor_msgs/msg/Image)' in error
    assert 'the bag has /battery (robot_msgs/msg/Battery), /n (std_msgs/msg/Float64)' in error


def test_a_cut_bag_is_decoded_up_to_the_damage(bag, tmp_path):
    """read_messages on a cut bag deserialises exactly the raw messages read_raw yields."""
    cut = cut_copy(bag, tmp_path / 'cut', 0.5, keep_metadata=False)
    raw, _ = read_until_damage(cut)
    decoded = []
    with pytest.raises(BagError, match='damaged MCAP file'):
        decoded.extend(read_messages(cut))
    assert [(m.topic, m.stamp_ns) for m in decoded] == [(m.topic, m.stamp_ns) for m in raw]
    assert all(m.msg.header.stamp.sec > 0 for m in decoded)


def _damaged_copy(bag: Path, target: Path, offset: int, xor: int) -> Path:
    """A copy of ``bag`` whose MCAP file has the byte at ``offset`` XORed with ``xor``."""
    shutil.copytree(bag, target)
    mcap_file = next(target.glob('*.mcap'))
    data = bytearray(mcap_file.read_bytes())
    data[offset] ^= xor
    mcap_file.write_bytes(bytes(data))
    return target


def test_a_header_whose_length_reads_as_hundreds_of_gigabytes_is_a_bag_error(bag, tmp_path):
    """A byte of the header record's length (after the magic and the opcode) flipped.

    rosbags asked for a buffer of that length, and its MemoryError came out of every reader.
    """
    damaged = _damaged_copy(bag, tmp_path / 'long_header', 8 + 1 + 4, 0x5A)
    for read in (read_raw, read_messages):
        with pytest.raises(BagError, match='damaged MCAP file, 0 messages recovered before') as e:
            list(read(damaged))
        assert str(e.value).startswith(str(damaged))
    assert message_count(damaged, ['/cam/image']) == 0


@pytest.mark.parametrize(('field', 'at'), [('id', 0), ('topic', 2 + 2 + 4)])
def test_a_bag_whose_summary_misnames_a_channel_is_read_whole(bag, tmp_path, field, at):
    """The summary's copy of the image channel's record, a byte of its id or topic flipped.

    rosbags took the channels from the summary: the image messages were of no channel (of
    another id) or of a topic metadata.yaml does not list (/cam/3mage), and the bag read as its
    camera_info alone, without an error.
    """
    data = next(bag.glob('*.mcap')).read_bytes()
    offset, summary_channel = 8, None  # after the magic
    while offset < len(data) - 8:  # the records outside chunks: in the summary for a channel
        length = int.from_bytes(data[offset + 1 : offset + 9], 'little')
        if data[offset] == CHANNEL_OPCODE and b'/cam/image' in data[offset : offset + 9 + length]:
            summary_channel = offset
        offset += 9 + length
    assert summary_channel is not None
    damaged = _damaged_copy(bag, tmp_path / field, summary_channel + 9 + at, 0x5A)
    messages, error = read_until_damage(damaged)
    assert messages == list(read_raw(bag))
    assert error == ''


@pytest.mark.parametrize('cut_from_end', [False, True])
def test_a_bag_cut_inside_a_record_header_says_it_is_truncated(bag, tmp_path, cut_from_end):
    """Cut 3 bytes into the header record's length, or 1 byte short of the closing magic.

    It said 'error: unpack requires a buffer of 8 bytes' (struct's words for a short read).
    """
    size = next(bag.glob('*.mcap')).stat().st_size
    cut = cut_copy(bag, tmp_path / 'cut', (size - 1 if cut_from_end else 8 + 1 + 3) / size)
    messages, error = read_until_damage(cut)
    assert len(messages) == (2 * FRAMES if cut_from_end else 0)
    assert error.endswith(' recovered before: the file ends part way (truncated)'), error


def test_a_bag_whose_writer_is_killed_keeps_all_but_its_last_chunk(tmp_path):
    """What a writer killed (SIGKILL) or stopped by a full disk leaves: the file written so far.

    Its messages stay readable but for those of the chunk still open in memory, 64 KiB of them
    at most (bags.CHUNK_BYTES). In rosbags' own chunks of 1 MiB, these 300 messages of 1.1 kB
    (330 kB) were all in it: none was readable; a mono track's outputs lost up to 97 frames so.
    """
    path, copy = tmp_path / 'open', tmp_path / 'killed'
    rng = np.random.default_rng(0)
    images = [
        image_msg(rng.integers(0, 256, (32, 32), dtype=np.uint8), stamp(f)) for f in range(300)
    ]
    with BagWriter(path) as writer:
        for f, image in enumerate(images):
            writer.write('/cam/image', IMAGE, image, stamp(f))
        shutil.copytree(path, copy)  # as the file is now: what is still buffered is not in it
    messages, error = read_until_damage(copy)
    assert error.endswith('recovered before: the file ends part way (truncated)'), error
    written = list(read_raw(path))
    assert messages == written[: len(messages)]
    open_chunk = (64 << 10) // len(written[0].data) + 1  # messages of 64 KiB, at most
    assert len(messages) >= len(written) - open_chunk, len(messages)


def test_a_track_whose_output_cannot_be_written_names_the_bag_and_keeps_what_was_written(
    tmp_path,
):
    """A full disk part way, as a file size limit: its errno text alone named no file.

    The track records its inputs, so that the 2.5 MB limit comes after MCAP chunks of several
    frames were written: their frames, images with their tracked states, stay readable.
    """
    out, limit = tmp_path / 'tracked', 2_500_000
    # The limit is set in the child itself: a preexec_fn may deadlock a parent with threads
    # (a test process that has started DDS has some). A write past it fails with EFBIG.
    limited = (
        'import resource, signal, sys; '
        'signal.signal(signal.SIGXFSZ, signal.SIG_IGN); '
        f'resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit})); '
        'from face_tracking_ros.cli.main import main; '
        'sys.exit(main(sys.argv[1:]))'
    )
    track = ['track', str(MONO), '--simulate-clicks', '1', '--record-inputs', '--out', str(out)]
    finished = subprocess.run(
        [sys.executable, '-c', limited, *track, '--quiet'],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert finished.returncode == 2
    assert finished.stderr == (
        f'error: {out}: cannot write the bag: File too large; it ends where the write failed, '
        'without its summary and metadata.yaml (the messages before stay readable, as in a bag '
        'cut off)\n'
    )
    messages, error = read_until_damage(out)
    assert error.endswith('recovered before: the file ends part way (truncated)')
    read = Counter(message.topic for message in messages)
    assert read['image'] >= 3 and read['face/state'] >= 3
    images = list(read_raw(MONO, ['image']))[: read['image']]
    assert [m.data for m in messages if m.topic == 'image'] == [m.data for m in images]
