"""Simulated semi-automatic initialisation: the user's clicks on the first frame, from truth.

The seed initialises both trackers semi-automatically: a person clicks the mesh nodes on the
first image. For synthetic bags the clicks are simulated: the true nodes of the first frame,
projected into the (left) camera, with Gaussian pixel noise like a careful user's, and written as
an ordinary init file (see :mod:`face_tracking_ros.tracking.initialisation`), which the trackers
read exactly as they read a hand-made one.
"""

from __future__ import annotations

from collections.abc import Mapping
import json
from pathlib import Path
import zlib

import numpy as np

from face_tracking_ros.errors import BagError, ConfigError, InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.io import conversions
from face_tracking_ros.io.atomic import (
    check_output_path,
    check_replaceable,
    write_text_atomically,
)
from face_tracking_ros.io.bags import bag_topics, read_messages, recording_name, topic_has_word
from face_tracking_ros.io.series import read_converted
from face_tracking_ros.tracking.initialisation import (
    MIN_INIT_NODES,
    Initialisation,
    load_init_file,
)

DEFAULT_CLICK_NOISE_PX = 1.0


def simulated_clicks(
    node_names: tuple[str, ...],
    nodes_cam: np.ndarray,
    camera: PinholeCamera,
    noise_px: float = DEFAULT_CLICK_NOISE_PX,
    rng: np.random.Generator | None = None,
) -> Initialisation:
    """The clicked positions of the visible nodes of one frame.

    Args:
        node_names: names of the N nodes.
        nodes_cam: (N, 3) true nodes in the camera frame, m.
        camera: the camera the clicks are made in, on its raw image (as a user sees it; the
            rectified image of eq. 2 for a camera that needs no rectification).
        noise_px: standard deviation of the click error, px.
        rng: noise generator; None for no noise.

    Raises:
        ConfigError: if fewer than :data:`MIN_INIT_NODES` clicks fall inside the image (the
            face out of the frame, or a noise of the image's size), naming the noise.
    """
    points = camera.raw_pixels(nodes_cam)
    noise_px = noise_px if rng is not None else 0.0
    if rng is not None and noise_px > 0:
        points = points + rng.normal(0.0, noise_px, points.shape)
    inside = (
        (points[:, 0] >= 0)
        & (points[:, 0] <= camera.width - 1)
        & (points[:, 1] >= 0)
        & (points[:, 1] <= camera.height - 1)
    )
    if np.count_nonzero(inside) < MIN_INIT_NODES:
        msg = (
            f'simulated clicks: {np.count_nonzero(inside)} of the {len(points)} nodes fall inside '
            f'the {camera.width}x{camera.height} image with a click noise of {noise_px:g} px; the '
            f'initialisation needs at least {MIN_INIT_NODES}'
        )
        raise ConfigError(msg)
    names = tuple(name for name, keep in zip(node_names, inside, strict=True) if keep)
    return Initialisation(node_names=names, points=points[inside])


def write_init_file(init: Initialisation, path: Path) -> Path:
    """Write an init file (JSON) that :func:`load_init_file` reads back."""
    nodes = {
        name: [float(x), float(y)]
        for name, (x, y) in zip(init.node_names, init.points, strict=True)
    }
    data: dict[str, object] = {'nodes': nodes}
    if init.sigma is not None:
        data['sigma'] = [float(v) for v in init.sigma]
    write_text_atomically(path, json.dumps(data, indent=1))
    return path


def check_clicks_file(path: Path, option: str) -> None:
    """Refuse, before any work, an init file ``path`` the simulated clicks cannot go to.

    The directories above it must be directories or missing (they are made), ``path`` must not
    be a directory, and a file there must be an init file (an earlier run's clicks, replaced):
    never a user's notes or a model given by mistake.

    Args:
        path: where the clicks go.
        option: the option that asks for them, as the message names it ('--simulate-clicks:').

    Raises:
        ConfigError: naming the option and the file: it cannot be, or would not be, written.
    """
    check_output_path(path, option)
    check_replaceable(path, option, 'an init file', load_init_file)


def clicks_from_bag(
    bag: Path,
    noise_px: float = DEFAULT_CLICK_NOISE_PX,
    seed: int | None = None,
    camera_info: str | None = None,
    topics: Mapping[str, str] | None = None,
) -> Initialisation:
    """Simulated clicks on the first frame of a synthetic bag (left camera for stereo).

    The clicked camera is that of ``camera_info`` when given (the topic the tracker reads for
    the camera it is initialised in), else of the first camera_info topic, by name, with the
    word ``left`` in its name (:func:`~face_tracking_ros.io.bags.topic_has_word`: not
    ``/cleft_palate/...``), else of the first camera_info topic by name (a mono bag's only one).

    The noise is drawn from ``seed``; None (the default) seeds it from the bag's name, so that
    the clicks of different bags err independently, as a user's would, and those of one bag are
    the same in every run.

    ``topics`` are the bag's (name -> type) when the caller has read them; None: read here.

    Raises:
        BagError: if the bag has no truth or no camera_info of the clicked camera.
        InputError: if the first camera_info is not a calibration (NaN, an all-zero K),
            naming the bag and the topic.
    """
    topics = bag_topics(bag) if topics is None else topics
    infos = sorted(t for t, kind in topics.items() if kind == conversions.CAMERA_INFO_TYPE)
    if camera_info is not None and camera_info not in infos:
        has = ', '.join(infos) or 'none'
        msg = f'{bag}: no CameraInfo topic {camera_info} to click in (it has {has})'
        raise BagError(msg)
    info_topic = camera_info or next(
        (t for t in infos if topic_has_word(t, 'left')), infos[0] if infos else None
    )
    truth_topic = next((t for t, k in topics.items() if k == conversions.TRUTH_TYPE), None)
    if info_topic is None or truth_topic is None:
        msg = f'{bag}: simulated clicks need a CameraInfo and a FaceTruth topic'
        raise BagError(msg)
    info = next((message.msg for message in read_messages(bag, topics=[info_topic])), None)
    first = next(read_converted(bag, truth_topic, conversions.truth_from_msg), None)
    if info is None or first is None:
        empty = [topic for topic, msg in ((info_topic, info), (truth_topic, first)) if msg is None]
        msg = f'{bag}: simulated clicks need a message on {" and ".join(empty)}, which has none'
        raise BagError(msg)
    truth_msg, truth = first
    try:
        camera = conversions.camera_from_info(info)
    except InputError as error:
        msg = f'{bag}: {info_topic}: {error}'
        raise InputError(msg) from None
    names = tuple(truth_msg.node_names)
    draw = zlib.crc32(recording_name(bag).encode()) if seed is None else seed
    return simulated_clicks(names, truth.nodes, camera, noise_px, np.random.default_rng(draw))
