"""Message-in, message-out monocular tracking: the body of the mono_tracker node and its replay.

Inputs: ``image`` (sensor_msgs/Image, or CompressedImage on ``image/compressed``), ``camera_info``
and, optionally, a latched ``face/model``; raw images are rectified with their calibration first
(``rectify``, :mod:`~face_tracking_ros.imaging.rectification`). Outputs, one each per image,
stamped with the image's header: ``face/state``, ``face/pose``, ``face/action``, ``face/shape``,
``face/mesh_raw`` (FaceMesh), ``face/mesh`` (MarkerArray), and ``face/overlay`` (the rectified
image) while someone subscribes to it. An image that arrives before the first camera_info is held
(the latest one) and tracked as soon as the calibration arrives. An image whose stamp repeats the
last tracked one is refused; an earlier stamp (a looped bag, a restarted camera) resets the
tracker, so the next image starts a new track from the initialisation. The published pose (and the
nodes, which move rigidly with it) is smoothed by the One Euro filter of
:mod:`~face_tracking_ros.tracking.pose_filter` (parameters ``smoothing.*``), timed by the image
stamps; the tracker itself continues from its raw estimate. The stamps also tell the tracker how
many frame intervals passed since the last image
(:class:`~face_tracking_ros.processing.frame_intervals.FrameIntervals`): images missing from a
bag, or dropped by the depth-1 queue while the tracker was busy, count as the time they took.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import ConfigError, FaceTrackingError, InputError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import stamp_to_ns
from face_tracking_ros.io.messages import MessageFactory
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.processing.base import Output, Port, QosClass
from face_tracking_ros.processing.calibration import CameraCalibration
from face_tracking_ros.processing.detection import (
    DetectorFactory,
    landmark_detector,
    restart_points,
)
from face_tracking_ros.processing.face_outputs import MESH_PORTS, MODEL_PORTS, face_outputs
from face_tracking_ros.processing.frame_intervals import FrameIntervals
from face_tracking_ros.processing.held_input import HeldInput
from face_tracking_ros.processing.model_agreement import MODEL_PORT
from face_tracking_ros.processing.node_configs import (
    CAMERA_INFO,
    COMPRESSED_IMAGE,
    IMAGE,
    MODEL,
    MonoNodeConfig,
)
from face_tracking_ros.processing.parameters import ParameterSource
from face_tracking_ros.processing.stamp_guard import StampGuard
from face_tracking_ros.processing.track_counts import TrackCounts
from face_tracking_ros.tracking.initialisation import (
    MIN_INIT_NODES,
    Initialisation,
    check_inside,
    load_init_file,
)
from face_tracking_ros.tracking.mono import MonoTracker
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.pose_filter import PoseFilter, PoseFilterConfig
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.visualization.overlay import draw_mesh


class MonoProcessor:
    """Runs :class:`~face_tracking_ros.tracking.mono.MonoTracker` on image messages.

    The stamp order (:class:`~face_tracking_ros.processing.stamp_guard.StampGuard`), the image
    held until camera_info comes (:class:`~face_tracking_ros.processing.held_input.HeldInput`)
    and the calibration (:class:`~face_tracking_ros.processing.calibration.CameraCalibration`)
    follow the stereo processor's rules. Its own: an image's stamp is taken as soon as it passes,
    and one that went back restarts the track at once, the status warning of it for a while
    after (:meth:`warning`); an image is held only while
    there is no camera_info (a camera and model that do not fit are an error for every image),
    and tracked once there is a tracker: at the camera_info, or at the model that follows it
    for a processor started without one.
    """

    def __init__(
        self,
        factory: MessageFactory,
        config: MonoNodeConfig,
        tracker_config: MonoTrackerConfig,
        model: FaceModel | None,
        initialisation: Initialisation | None = None,
        filter_config: PoseFilterConfig | None = None,
        detector_for: DetectorFactory | None = None,
    ) -> None:
        """Wait for camera_info (and a model, if none is given) before tracking.

        ``detector_for`` gives the landmark detector of a model's nodes (automatic
        initialisation, see :class:`MonoNodeConfig`); without it, the tracker starts from
        ``initialisation`` or the points of a reset.

        Raises:
            ConfigError: if the model has a singular prior covariance, lacks nodes the
                initialisation names, or has another p than the initialisation's sigma.
        """
        if model is not None:
            _check_model(model, initialisation, ConfigError)
        self._factory = factory
        self._config = config
        self._tracker_config = tracker_config
        self._filter_config = filter_config or PoseFilterConfig()
        self._model = model
        self._initialisation = initialisation
        self._detector_for = detector_for
        self._calibration = CameraCalibration(config.rectify)
        self._tracker: MonoTracker | None = None
        self._unfit = ''  # why the camera and model give no tracker, if they do not
        self._pose_filter: PoseFilter | None = None
        self._held: HeldInput[tuple[Any, np.ndarray]] = HeldInput(
            CAMERA_INFO, 'image', ' until it comes'
        )
        # The names and (N, 3) camera-frame nodes of the last image, if it was tracked.
        self._tracked: tuple[tuple[str, ...], np.ndarray] | None = None
        self._stamps = StampGuard('image')
        self._intervals = FrameIntervals()
        self._counts = TrackCounts('images')
        self.inputs = _input_ports(config)
        self.outputs = (
            *MESH_PORTS,
            *MODEL_PORTS,
            Port('face/overlay', conversions.IMAGE_TYPE, QosClass.SENSOR, on_demand=True),
        )

    def reset(self, initialisation: Initialisation | None) -> str:
        """Restart tracking from 2-D node positions; None: a detection, or the last ones given.

        None detects the face with auto_init (a detector), else re-uses the last positions (the
        init file's or an earlier reset's). Returns what the restart starts from.

        Raises:
            InputError: for None with neither a detector nor earlier positions, for nodes the
                face model does not have, or positions outside the image (the track goes on as
                it was).
        """
        unknown = '' if self._model is None else _unknown_nodes(self._model, initialisation)
        if unknown:
            raise InputError(unknown)
        camera = self._calibration.camera
        if initialisation is not None and camera is not None:
            size = (camera.width, camera.height)
            check_inside(initialisation.node_names, initialisation.points, size)
        self._initialisation, source = restart_points(
            initialisation, self._initialisation, self._detector_for, 'mono'
        )
        self._restart()
        return source

    def handle(self, topic: str, msg: Any, wanted: frozenset[str]) -> list[Output]:
        """Process one message of an input port (see :class:`processing.base.Processor`)."""
        if topic == CAMERA_INFO:
            self._set_camera(msg)
            return self._track_held_image(wanted)
        if topic == MODEL:
            model = conversions.model_from_msg(msg)
            _check_model(model, self._initialisation, InputError)
            self._model = model
            self._rebuild()
            return self._track_held_image(wanted)  # (held for the camera_info and this model)
        conversions.checked_stamp_ns(msg.header)  # before the image is held
        gray = conversions.message_to_gray(msg)
        if self._calibration.camera is None:  # held until the calibration comes
            dropped = self._held.hold((msg.header, gray))
            if dropped:
                raise InputError(dropped)
            return []
        return self._track(msg.header, gray, wanted)

    def status(self) -> dict[str, str]:
        """The images per tracking status, the last reason, the restarts and the model.

        ``restarts`` counts the tracks restarted by a stamp that went back; ``model`` is the
        fingerprint of the face model in use (it changes with one taken from face/model).
        See :class:`~face_tracking_ros.processing.base.Reporting` and
        :class:`~face_tracking_ros.processing.track_counts.TrackCounts`.
        """
        model = self._model.fingerprint if self._model is not None else 'none'
        report = {**self._counts.report(), 'restarts': str(self._stamps.restarts), 'model': model}
        report['last_reason'] = self._held.reason(report['last_reason'])
        return report

    def warning(self) -> str:
        """Images not tracked in a row, else stamps that went back a moment ago.

        See :meth:`~face_tracking_ros.processing.track_counts.TrackCounts.warning` and
        :meth:`~face_tracking_ros.processing.stamp_guard.StampGuard.warning` (the stereo
        processor warns of each jump back as it comes).
        """
        return self._counts.warning() or self._stamps.warning()

    def run_deferred(self) -> None:
        """The last tracked image's share of the bundle adjustment (``MonoTracker.adjust``).

        The node runs it once that image's outputs are published, so they do not wait for it.
        """
        if self._tracker is not None:
            self._tracker.adjust()

    def _track_held_image(self, wanted: frozenset[str]) -> list[Output]:
        """Track the image that arrived before the first camera_info, once there is a tracker.

        That is when the camera_info arrives, or the model after it for a processor started
        without one.
        """
        if self._tracker is None:
            return []
        return self._held.release(lambda held: self._track(*held, wanted))

    def _set_camera(self, msg: Any) -> None:
        """Keep the camera of a camera_info; rebuild the tracker only when the calibration changed.

        Raises:
            InputError: for a bad camera_info or a distortion model that cannot be rectified
                (the old camera is kept).
        """
        camera = self._calibration.read(msg)
        if camera is not None:
            self._calibration.keep(camera)
            self._rebuild()

    def _rebuild(self) -> None:
        """A tracker for the camera and model; none while either is missing or they do not fit.

        Raises:
            FaceTrackingError: why the tracker cannot work with them (also kept, and given for
                every image until a camera or model that fits arrives).
        """
        camera = self._calibration.camera
        if camera is not None and self._model is not None:
            detector = (
                None if self._detector_for is None else self._detector_for(self._model.node_names)
            )
            carried = self._carried_over()
            self._tracker, self._unfit = None, ''
            try:
                self._tracker = MonoTracker(
                    self._model, camera, self._tracker_config, detector=detector
                )
            except FaceTrackingError as error:
                self._unfit = f'cannot track with this camera and model: {error}'
                raise
            self._pose_filter = PoseFilter(camera, self._filter_config)
            self._restart(carried)

    def _carried_over(self) -> Initialisation | None:
        """The nodes of the last image, if it was tracked, to go on from with a new tracker.

        A calibration or model that changes while a track runs restarts it from there, not from
        the initialisation's points (made on the first image, the head may have moved since):
        the nodes as the new calibration sees them (:meth:`CameraCalibration.seen`), those
        outside its image left out. They stay the last tracked nodes until another image is
        tracked or the track starts from the initialisation: a camera_info wrong for a moment
        (its images refused) and then right again goes on from them too.
        """
        tracked = self._tracked
        if (
            tracked is None
            or self._calibration.camera is None
            or tracked[0] != self._model.node_names
        ):
            return None
        names, nodes_cam = tracked
        pixels = self._calibration.seen(nodes_cam)
        inside = np.isfinite(pixels[:, 0])
        if inside.sum() < MIN_INIT_NODES:
            return None
        kept = tuple(name for name, keep in zip(names, inside, strict=True) if keep)
        return Initialisation(node_names=kept, points=pixels[inside])

    def _restart(self, carried: Initialisation | None = None) -> None:
        """Restart the tracker and the pose filter from its next result.

        The tracker starts from ``carried`` (node positions in the rectified image) if given,
        else from the initialisation (and the last tracked nodes are forgotten).
        """
        if self._tracker is not None and self._pose_filter is not None:
            if carried is None:
                self._tracked = None
            initialisation = self._calibration.rectified(self._initialisation)
            self._tracker.reset(carried or initialisation)
            self._pose_filter.reset()

    def _track(self, header: Any, gray: np.ndarray, wanted: frozenset[str]) -> list[Output]:
        if self._tracker is None:
            msg = (
                self._unfit
                or f'no face model yet: set the model_file parameter or publish one on {MODEL}'
            )
            raise InputError(msg)
        rectifier = self._calibration.rectifier
        rectifier.check_size(gray)
        stamp_ns = stamp_to_ns(header.stamp)
        intervals = self._check_stamp(stamp_ns)
        gray = rectifier.image(gray)
        tracked = self._tracker.track(gray, intervals)
        ok = tracked.status == TrackStatus.TRACKING
        self._tracked = (self._model.node_names, tracked.nodes_cam) if ok else None
        self._counts.add(tracked.status, tracked.reason)
        result = self._pose_filter.filter(tracked, stamp_ns * 1e-9)
        out_header = conversions.copy_header(self._factory, header)
        topology = self._model.topology
        outputs = face_outputs(self._factory, out_header, self._config.face_id, result, topology)
        if 'face/overlay' in wanted:
            canvas = draw_mesh(
                gray, result.nodes_px, topology.edges, result.status, occluded=result.occluded
            )
            overlay = conversions.array_to_image(self._factory, out_header, canvas)
            outputs.append(Output('face/overlay', overlay))
        return outputs

    def _check_stamp(self, stamp_ns: int) -> int:
        """Accept a later stamp; refuse a repeated one; restart the track on an earlier one.

        An earlier stamp (a looped bag, a restarted camera) resets the tracker, and the track
        starts again with this image (counted in the status's ``restarts``).

        Returns:
            The frame intervals since the last image taken (:class:`FrameIntervals`): more than
            1 when images were dropped (missing from a bag, or left in the queue while the
            tracker was busy).

        Raises:
            InputError: for a repeated stamp.
        """
        if not self._stamps.later(stamp_ns, 'image'):
            self._restart()
            self._stamps.restart()
        previous = self._stamps.last
        self._stamps.take(stamp_ns)
        return self._intervals.since(previous, stamp_ns)


def _input_ports(config: MonoNodeConfig) -> tuple[Port, ...]:
    """The image (raw or compressed, as ``config`` says), camera_info and face model ports."""
    image = (
        Port(COMPRESSED_IMAGE, conversions.COMPRESSED_IMAGE_TYPE, QosClass.SENSOR)
        if (config.compressed)
        else Port(IMAGE, conversions.IMAGE_TYPE, QosClass.SENSOR)
    )
    return (image, Port(CAMERA_INFO, conversions.CAMERA_INFO_TYPE, QosClass.SENSOR), MODEL_PORT)


def _check_model(
    model: FaceModel, initialisation: Initialisation | None, error: type[Exception]
) -> None:
    """Raise ``error`` if the tracker cannot use the model.

    The tracker inverts the §4.1 prior covariances, so they must be positive definite, and the
    initialisation's nodes must be nodes of the model.
    """
    for name in ('sigma_prior_covariance', 'alpha_prior_covariance'):
        if np.linalg.eigvalsh(getattr(model, name)).min(initial=1.0) <= 0.0:
            msg = f"the face model's {name} is singular (the tracker inverts it): model refused"
            raise error(msg)
    unknown = _unknown_nodes(model, initialisation)
    if unknown:
        raise error(unknown)
    sigma = initialisation.sigma if initialisation else None
    if sigma is not None and len(sigma) != model.p:
        source = initialisation.source  # e.g. 'init file clicks.yaml'
        msg = f'{source} holds {len(sigma)} sigma values, the face model p = {model.p}'
        raise error(msg)


def _unknown_nodes(model: FaceModel, initialisation: Initialisation | None) -> str:
    """What names the initialisation's nodes that the model lacks; '' if there are none."""
    owner = f'the {model.num_nodes}-node face model'
    return initialisation.unknown_nodes(model.node_names, owner) if initialisation else ''


def make_mono_processor(params: ParameterSource, factory: MessageFactory) -> MonoProcessor:
    """The mono_tracker processor configured from parameters (node or replay).

    Parameters: those of :class:`MonoNodeConfig`, ``tracker.*`` those of
    :class:`~face_tracking_ros.tracking.mono_config.MonoTrackerConfig`, ``smoothing.*`` those of
    :class:`~face_tracking_ros.tracking.pose_filter.PoseFilterConfig` and ``detector.*`` those
    of :class:`~face_tracking_ros.tracking.detector.DetectorConfig`.

    Raises:
        ConfigError: for a bad parameter or init file, auto_init without the detector
            installed, or a model the tracker cannot use (see :class:`MonoProcessor`).
        ModelFileError: for an unusable model file.
    """
    config = params.config(MonoNodeConfig)
    tracker_config = params.config(MonoTrackerConfig, prefix='tracker.')
    filter_config = params.config(PoseFilterConfig, prefix='smoothing.')
    model = load_model(config.model_file or default_model_path())
    init = load_init_file(config.init_file) if config.init_file else None
    detector_for = landmark_detector(params, config.auto_init)
    return MonoProcessor(factory, config, tracker_config, model, init, filter_config, detector_for)
