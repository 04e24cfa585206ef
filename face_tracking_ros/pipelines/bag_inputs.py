"""What a tracker replayed over a bag reads, and with which parameters.

A bag's image topics and their transport (Image or CompressedImage), whether it is a stereo
bag, the tracker inputs remapped to its topics, the ``compressed`` parameter, and, for its
initialisation, the nodes the chosen tracker tracks and the camera it is initialised in: what
``face-tracking track`` and the learning pipeline's tracking of raw stereo bags
(:mod:`.stereo_meshes`) give :func:`face_tracking_ros.replay.replay_bag`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Protocol

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.bags import topic_has_word
from face_tracking_ros.io.conversions import CAMERA_INFO_TYPE, COMPRESSED_IMAGE_TYPE, IMAGE_TYPE
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.pipelines.option_flags import option_flag
from face_tracking_ros.processing.node_configs import (
    CAMERA_INFO,
    COMPRESSED_IMAGE,
    IMAGE,
    LEFT_IMAGE,
    LEFT_INFO,
    MODEL,
    RIGHT_IMAGE,
    RIGHT_INFO,
    stereo_input_ports,
)
from face_tracking_ros.processing.node_configs import COMPRESSED as STEREO_COMPRESSED
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.replay import bag_spelling, fed_topic, resolve_inputs
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig


def image_topics(topics: Mapping[str, str]) -> tuple[list[str], bool]:
    """A bag's image topics (name -> type given) and whether they are compressed.

    Its Image topics if it has any, else its CompressedImage ones (a bag recorded through
    image_transport's compressed plugin).
    """
    raw = [topic for topic, kind in topics.items() if kind == IMAGE_TYPE]
    if raw:
        return raw, False
    return [topic for topic, kind in topics.items() if kind == COMPRESSED_IMAGE_TYPE], True


def is_stereo_bag(topics: Mapping[str, str]) -> bool:
    """True if a bag's topics (name -> type) hold a left and a right image stream."""
    images, _ = image_topics(topics)
    return all(any(topic_has_word(t, side) for t in images) for side in ('left', 'right'))


def check_one_transport(bag: Path, topics: Mapping[str, str]) -> None:
    """Refuse a bag whose left and right images come one as Image, one as CompressedImage.

    Raises:
        ConfigError: naming the two topics: the stereo tracker takes one transport for both.
    """
    images = {t: kind for t, kind in topics.items() if kind in (IMAGE_TYPE, COMPRESSED_IMAGE_TYPE)}
    left = {kind for t, kind in images.items() if topic_has_word(t, 'left')}
    right = {kind for t, kind in images.items() if topic_has_word(t, 'right')}
    if left and right and not left & right:
        named = ', '.join(f'{t} ({kind.rpartition("/")[2]})' for t, kind in images.items())
        msg = (
            f'{bag}: its left and right images come by different transports ({named}): the '
            'stereo tracker takes both as Image or both as CompressedImage'
        )
        raise ConfigError(msg)


def compressed_parameters(
    topics: Mapping[str, str], given: Iterable[str | None] = ()
) -> list[str]:
    """``['compressed=true']`` when the images to track are CompressedImage, else ``[]``.

    Args:
        topics: the bag's topics (name -> type).
        given: the image topics given (``--image-topic``, ``--left-topic``; None: not given);
            their type decides, else the bag's (compressed if it has CompressedImage topics
            only).
    """
    chosen = [topics.get(bag_spelling(topic, topics)) for topic in given if topic]
    if chosen:
        compressed = chosen[0] == COMPRESSED_IMAGE_TYPE
    else:
        images, only_compressed = image_topics(topics)
        compressed = only_compressed and bool(images)
    return ['compressed=true'] if compressed else []


def input_remaps(topics: Mapping[str, str | None], compressed: bool) -> dict[str, str]:
    """Processor input -> bag topic, of the topics given (input name -> bag topic, or None).

    With ``compressed`` (the tracker's ``compressed`` parameter), an image topic given for a raw
    image input goes to its ``/compressed`` input, the one the tracker then reads.
    """
    transport = {raw: port for port, raw in STEREO_COMPRESSED.items()} | {IMAGE: COMPRESSED_IMAGE}
    return {
        transport.get(port, port) if compressed else port: topic
        for port, topic in topics.items()
        if topic
    }


class StereoTopicOptions(Protocol):
    """Options naming the stereo topics: ``track``'s arguments, or ``learn``'s LearnOptions."""

    left_topic: str | None
    right_topic: str | None
    left_info_topic: str | None
    right_info_topic: str | None


def stereo_topics(args: StereoTopicOptions) -> dict[str, str | None]:
    """The stereo_tracker inputs given as ``left_topic``, ``right_topic`` and their camera_info's.

    On the command line: --left-topic, --right-topic, --left-info-topic, --right-info-topic.
    """
    return {
        LEFT_IMAGE: args.left_topic,
        RIGHT_IMAGE: args.right_topic,
        LEFT_INFO: args.left_info_topic,
        RIGHT_INFO: args.right_info_topic,
    }


def stereo_remaps(
    topics: Mapping[str, str],
    options: StereoTopicOptions,
    compressed: bool,
    remaps: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """The stereo tracker's input -> bag topic: found by side, then ``remaps``, then ``options``.

    Each over the one before: an input no topic's name ends in is found by its side
    (:func:`_by_side`); ``remaps`` (``--remap INPUT=TOPIC``) and the topics ``options`` give
    (``--left-topic``, ...) take precedence, in that order.

    Args:
        topics: the bag's topics (name -> type).
        options: the topics given.
        compressed: whether the tracker reads CompressedImage (the type of the images).
        remaps: processor input -> bag topic, from the command line.
    """
    found = {port: _by_side(port, topics, compressed) for port in STEREO_PORTS}
    given = input_remaps(stereo_topics(options), compressed)
    return {**input_remaps(found, compressed), **(remaps or {}), **given}


def _by_side(port: str, topics: Mapping[str, str], compressed: bool) -> str | None:
    """The one topic of ``port``'s type with its side, and not the other, in its name.

    E.g. stereo_image_proc's ``/stereo/left/image_rect`` for ``left/image_raw``; the side is a
    word of the name (``left``, ``cam_left``, ``left_camera``; not ``bright``). None where a
    topic of the type has a name ending in the port's (``.../left/image_raw[/compressed]``: the
    tracker finds it so), or where none or several topics qualify.
    """
    image_type = COMPRESSED_IMAGE_TYPE if compressed else IMAGE_TYPE
    msgtype = CAMERA_INFO_TYPE if port in (LEFT_INFO, RIGHT_INFO) else image_type
    of_type = [topic for topic, kind in topics.items() if kind == msgtype]
    if any(topic.strip('/').endswith((port, f'{port}/compressed')) for topic in of_type):
        return None
    side, other = ('left', 'right') if port.startswith('left') else ('right', 'left')
    found = [t for t in of_type if topic_has_word(t, side) and not topic_has_word(t, other)]
    return found[0] if len(found) == 1 else None


STEREO_FIELDS = {  # the option field giving each input's topic (StereoTopicOptions)
    LEFT_IMAGE: 'left_topic',
    RIGHT_IMAGE: 'right_topic',
    LEFT_INFO: 'left_info_topic',
    RIGHT_INFO: 'right_info_topic',
}
STEREO_PORTS = tuple(STEREO_FIELDS)  # the stereo tracker's raw image and camera_info inputs


def check_stereo_topics(
    bag: Path,
    topics: Mapping[str, str],
    options: StereoTopicOptions,
    compressed: bool,
    remaps: Mapping[str, str] | None = None,
    named: Callable[[str], str] = option_flag,
) -> None:
    """Refuse stereo topics the tracker cannot pair: one topic for both sides, or a side missing.

    Args:
        bag: the bag, for the messages.
        topics: its topics (name -> type).
        options: the topics given (--left-topic, ...).
        compressed: whether the tracker reads CompressedImage.
        remaps: processor input -> bag topic, from the command line (--remap).
        named: how the messages name the option of a field of ``options`` (the learner node:
            as its parameter).

    Raises:
        ConfigError: naming the two options given one topic, or the inputs no topic of the
            bag feeds (with the bag's image and camera_info topics).
    """
    given = {
        port: bag_spelling(topic, topics) if topic else None
        for port, topic in stereo_topics(options).items()
    }
    for left, right in ((LEFT_IMAGE, RIGHT_IMAGE), (LEFT_INFO, RIGHT_INFO)):
        if given[left] and given[left] == given[right]:
            msg = (
                f'{named(STEREO_FIELDS[left])} and {named(STEREO_FIELDS[right])} are both '
                f'{given[left]}: the stereo tracker needs a topic of each camera'
            )
            raise ConfigError(msg)
    ports = [port for port in stereo_input_ports(compressed) if port.topic != MODEL]
    mapping = stereo_remaps(topics, options, compressed, remaps)
    fed = set(resolve_inputs(ports, topics, mapping).values())
    missing = [port for port in ports if port.topic not in fed]
    if missing:
        names = [port.topic for port in missing]
        flags = [named(STEREO_FIELDS[name.removesuffix('/compressed')]) for name in names]
        found = '; '.join(
            f'{kind}: {", ".join(t for t, k in topics.items() if k == kind) or "none"}'
            for kind in sorted({port.msgtype for port in ports})
        )
        msg = (
            f"{bag}: no topic for the stereo tracker's {', '.join(names)} (matched by a name "
            f'ending in it, else give {", ".join(flags)}); the bag has {found}'
        )
        raise ConfigError(msg)


def tracked_nodes(node: str, params: list[str], model_file: Path | None) -> tuple[str, ...]:
    """The nodes the chosen tracker tracks: its mesh's (stereo), its model's (mono).

    Args:
        node: 'stereo_tracker' or 'mono_tracker'.
        params: its parameters (``tracker.num_nodes`` for stereo), NAME=VALUE.
        model_file: the mono tracker's model file; None: the packaged one.
    """
    if node == 'stereo_tracker':
        config = OverrideParameters.parse(params).config(StereoTrackerConfig, prefix='tracker.')
        return mesh_topology(config.num_nodes).node_names
    return load_model(model_file or default_model_path()).node_names


def clicked_camera_topic(topic_map: Mapping[str, str], node: str) -> str | None:
    """The camera_info topic of the camera a tracker is initialised in; None: none fed.

    The camera its init file's pixel positions (clicked, or simulated from the truth) are in:
    the mono tracker's only camera, the stereo tracker's left one. The stereo tracker takes
    the left camera as its reference: its meshes are in the left camera frame, and it reads the
    init file (and ``auto_init`` finds the landmarks) in the left image, then finds each node
    in the right image along its epipolar line
    (:mod:`face_tracking_ros.tracking.stereo_init`).

    Args:
        topic_map: the tracker's replay's bag topic -> input
            (:func:`~face_tracking_ros.replay.wire_replay`).
        node: 'stereo_tracker' or 'mono_tracker'.
    """
    return fed_topic(topic_map, LEFT_INFO if node == 'stereo_tracker' else CAMERA_INFO)
