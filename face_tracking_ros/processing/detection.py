"""The tracker nodes' automatic initialisation: the optional landmark detector, from parameters.

Semi-automatic initialisation (an init file, the reset_tracking service) needs nothing more.
With ``auto_init`` a tracker node finds the face itself, with dlib's 68-point landmarks
(:mod:`face_tracking_ros.tracking.detector`, an optional extra). Its models load once, when the
node is made, so a node asked for it on a machine without dlib stops at start with the
command that installs it, not at the first image.
"""

from __future__ import annotations

from collections.abc import Callable

from face_tracking_ros.errors import InputError
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.processing.parameters import ParameterSource
from face_tracking_ros.tracking.detector import Detector, DetectorConfig, DlibLandmarkDetector
from face_tracking_ros.tracking.initialisation import Initialisation

DetectorFactory = Callable[[tuple[str, ...]], Detector]
"""A mesh's node names -> the landmark detector of those nodes."""

LARGEST_MESH = 34  # the detector is loaded for its nodes, then narrowed to a model's


def landmark_detector(params: ParameterSource, enabled: bool) -> DetectorFactory | None:
    """The detector of a tracker node with ``auto_init`` (``enabled``), per mesh; else None.

    The ``detector.*`` parameters (:class:`~face_tracking_ros.tracking.detector.DetectorConfig`)
    are read either way, so a node declares them all.

    Raises:
        ConfigError: if enabled and dlib or its predictor is missing (the message says how to
            install them), or for a bad ``detector.*`` value.
    """
    config = params.config(DetectorConfig, prefix='detector.')
    if not enabled:
        return None
    return DlibLandmarkDetector(mesh_topology(LARGEST_MESH).node_names, config).for_nodes


def restart_points(
    given: Initialisation | None,
    last: Initialisation | None,
    detector_for: DetectorFactory | None,
    tracker: str,
) -> tuple[Initialisation | None, str]:
    """The 2-D node positions a tracker restarts from on a reset (the reset_tracking service).

    The positions given, else (None) a detection with auto_init (``detector_for``; returns
    None), else the last positions given: the init file's or an earlier reset's.

    Returns:
        The positions, and what the restart starts from, for the service's reply.

    Raises:
        InputError: for None with neither a detector nor earlier positions: nothing would start
            the track (``tracker`` names it in the message).
    """
    if given is not None:
        return given, f'initialising from the {len(given.node_names)} node positions given'
    if detector_for is not None:
        return None, 'initialising from a detection of the face (auto_init)'
    if last is None:
        msg = (
            f'the {tracker} tracker needs 2-D node positions to (re)initialise, or auto_init to '
            'detect the face'
        )
        raise InputError(msg)
    return last, "initialising from the last node positions given (the init file's or a reset's)"
