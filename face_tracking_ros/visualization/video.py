"""Overlay videos: a bag's frames with the tracked mesh, as MP4 (OpenCV) or GIF (imageio).

The trackers' node positions are in the rectified image (eq. 2), so the frames are rectified
with the camera_info beside their topic first, as the trackers rectify them
(:mod:`~face_tracking_ros.imaging.rectification`), unless ``rectify`` is false.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np

from face_tracking_ros.errors import BagError, ConfigError, InputError
from face_tracking_ros.imaging.rectification import Rectifier
from face_tracking_ros.io import conversions
from face_tracking_ros.io.atomic import check_output_path
from face_tracking_ros.io.bags import bag_topics, read_usable, stamp_to_ns, topic_has_word
from face_tracking_ros.io.series import StateSeries
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.visualization.overlay import draw_mesh


def image_topic(bag: Path, requested: str | None = None) -> str:
    """The image topic to draw on: ``requested``, else the only one, else the left camera's.

    The left camera's is the only image topic with the word ``left`` in its name
    (:func:`~face_tracking_ros.io.bags.topic_has_word`: not ``/cleft_palate/image``).

    Raises:
        BagError: if there is no image topic (naming the bag's topics), ``requested`` is not
            one, or the choice is ambiguous.
    """
    every = bag_topics(bag)
    topics = [
        t
        for t, kind in every.items()
        if kind in (conversions.IMAGE_TYPE, conversions.COMPRESSED_IMAGE_TYPE)
    ]
    if not topics:
        msg = (
            f'{bag}: no sensor_msgs/msg/Image or CompressedImage topic to draw on (its topics: '
            f'{", ".join(every) or "none"})'
        )
        raise BagError(msg)
    if requested:
        if requested not in topics:
            msg = f'{bag}: no image topic {requested}; its image topics: {", ".join(topics)}'
            raise BagError(msg)
        return requested
    left = [t for t in topics if topic_has_word(t, 'left')]
    if len(topics) == 1 or len(left) == 1:
        return topics[0] if len(topics) == 1 else left[0]
    msg = f'{bag}: choose the image topic (--image-topic) among {", ".join(topics)}'
    raise BagError(msg)


def camera_info_topic(bag: Path, image: str) -> str | None:
    """The CameraInfo topic beside an image topic, if the bag has it.

    'left/image_raw' and 'left/image_raw/compressed' -> 'left/camera_info'.
    """
    namespace = image.removesuffix('/compressed').rpartition('/')[0]
    candidate = f'{namespace}/camera_info' if namespace else 'camera_info'
    return candidate if bag_topics(bag).get(candidate) == conversions.CAMERA_INFO_TYPE else None


def overlay_frames(
    bag: Path, states: StateSeries, topic: str | None = None, every: int = 1, rectify: bool = True
) -> Iterator[np.ndarray]:
    """(H, W, 3) rgb frames of ``bag`` with the mesh of the state of the same stamp drawn.

    With ``rectify``, each frame is rectified with the latest CameraInfo beside its topic (the
    first one until then; none in the bag: drawn as it is). A damaged bag gives the frames it
    can be read to, with a warning (:func:`~face_tracking_ros.io.bags.read_usable`).

    Raises:
        InputError: for an image of another size than its camera_info says, or than the frames
            before it (one video holds one size); the frames before it have been yielded.
    """
    if every < 1:
        msg = f'every must be >= 1, got {every}'
        raise ConfigError(msg)
    by_stamp = {int(stamp): i for i, stamp in enumerate(states.stamps)}
    edges = mesh_topology(states.image_points.shape[1]).edges
    chosen = image_topic(bag, topic)
    info = camera_info_topic(bag, chosen) if rectify else None
    cameras = conversions.CameraInfoReader()
    rectifier = None
    first_info = next(read_usable(bag, topics=[info]), None) if info is not None else None
    if first_info is not None:  # from the first frame on, even if its camera_info comes after it
        rectifier = Rectifier(cameras.read(first_info.msg))
    count, size = -1, None
    for message in read_usable(bag, topics=[chosen, *([info] if info else [])]):
        if message.topic == info:
            camera = cameras.read(message.msg)
            if rectifier is None or rectifier.camera is not camera:
                rectifier = Rectifier(camera)
            continue
        count += 1
        index = by_stamp.get(stamp_to_ns(message.msg.header.stamp))
        if index is None or count % every:
            continue
        gray = conversions.message_to_gray(message.msg)
        name = f'{chosen} image {count}'
        if rectifier is not None:
            rectifier.check_size(gray, name)
            gray = rectifier.image(gray)
        size = _one_size(gray.shape, size, name)
        status = TrackStatus(states.status[index])
        label = f'{status.name.lower()}  frame {count}'
        points, occluded = states.image_points[index], states.occluded[index]
        yield draw_mesh(gray, points, edges, status, label, occluded)


def _one_size(shape: tuple[int, ...], first: tuple[int, ...] | None, name: str) -> tuple[int, ...]:
    """The video's frame size: ``first``, or ``shape`` for the first frame.

    Raises:
        InputError: for a frame ``name`` of another size than the frames before it.
    """
    if first is not None and shape != first:
        msg = f'{name} is {shape[1]}x{shape[0]}, the frames before it {first[1]}x{first[0]}'
        raise InputError(msg)
    return first or shape


def write_overlay_video(
    bag: Path,
    states: StateSeries,
    video: Path,
    topic: str | None = None,
    every: int = 1,
    fps: float = 30.0,
    rectify: bool = True,
) -> int:
    """Write the overlay frames as ``.mp4`` (mp4v) or ``.gif``; returns the number of frames.

    ``rectify``: see :func:`overlay_frames`. The video is written beside ``video`` as
    ``<stem>.partial<suffix>`` and renamed to ``video`` once complete, so an earlier video of
    that name survives a bag that fails part way; the frames before the failure stay in the
    partial file, which the error names.

    Raises:
        ConfigError: for another file suffix or a directory that does not exist.
        BagError: if no frame of the bag has a state, or no image of a damaged bag can be
            read (one damaged part way is drawn as far as it is readable, with a warning).
        InputError: for a frame that cannot be drawn (see :func:`overlay_frames`).
        OSError: if the video cannot be written.
    """
    if not video.parent.is_dir():
        msg = f'video file {video}: no directory {video.parent} to write it in'
        raise ConfigError(msg)
    writers = {'.gif': _write_gif, '.mp4': _write_mp4}
    if video.suffix not in writers:
        msg = f'video file must end in .mp4 or .gif: {video}'
        raise ConfigError(msg)
    check_output_path(video, 'video file')  # the partial file is renamed over it
    partial = video.with_name(f'{video.stem}.partial{video.suffix}')
    frames = overlay_frames(bag, states, topic, every, rectify)
    try:
        count = writers[video.suffix](frames, partial, fps / every)
    except (BagError, InputError) as error:
        kept = f' (the frames before it are in {partial})' if partial.exists() else ''
        raise type(error)(f'{error}{kept}') from None
    if not count:
        msg = f'{bag}: no image has a tracking state of the same stamp'
        raise BagError(msg)
    partial.replace(video)
    return count


def _write_gif(frames: Iterator[np.ndarray], video: Path, fps: float) -> int:
    """Collect rgb frames and write them as a looping GIF, also the ones before a failure."""
    images: list[np.ndarray] = []
    try:
        images.extend(frames)
    finally:
        if images:
            iio.imwrite(video, images, duration=1000 / fps, loop=0)
    return len(images)


def _write_mp4(frames: Iterator[np.ndarray], video: Path, fps: float) -> int:
    """Stream rgb frames into an MP4 file (closed, and readable, also after a failure)."""
    writer = None
    count = 0
    try:
        for frame in frames:
            if writer is None:
                size = (frame.shape[1], frame.shape[0])
                writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*'mp4v'), fps, size)
                if not writer.isOpened():
                    msg = f'OpenCV cannot write {video} (mp4v)'
                    raise OSError(msg)
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
            count += 1
    finally:
        if writer is not None:
            writer.release()
    return count
