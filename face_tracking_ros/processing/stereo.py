"""Message-in, message-out stereo tracking: the body of the stereo_tracker node and its replay.

Inputs: ``left/image_raw``, ``left/camera_info``, ``right/image_raw``, ``right/camera_info`` (raw
images, which it rectifies with their calibration unless ``rectify`` is false:
:mod:`~face_tracking_ros.imaging.rectification`; with ``compressed``, CompressedImage on
``left/image_raw/compressed`` and ``right/image_raw/compressed``) and, optionally, a latched
``face/model``. Left and right images are paired by exact stamp (or the nearest within
``pairing_tolerance_ms``) in a bounded queue; a stamp that never pairs is dropped and counted,
never paired with another. Outputs per pair, stamped with the left image's header:
``face/mesh_raw`` (FaceMesh, left camera frame), ``face/mesh`` (MarkerArray), ``face/state`` and,
with a model, the fitted ``face/pose``, ``face/action`` and ``face/shape``.

Offline, with ``retroactive_depths``, the outputs of a track are held until it ends (a reset or
the end of the bag, :meth:`StereoProcessor.finish`) and then emitted with the frame-1 depths
refined over the whole track applied to every pair
(:meth:`~face_tracking_ros.tracking.stereo.StereoTracker.with_final_depths`): the meshes
``face-tracking learn`` learns from. A live stream cannot be rewritten, so the live node refuses
it.

An image whose stamp repeats that of the last tracked pair is refused. A jump back of
:data:`~face_tracking_ros.processing.stereo_pairing.RESTART_JUMP_NS` or more (a looped bag,
restarted cameras) resets the tracker to the initialisation and clears the pairing queues, and
the new track starts with the pair of that image. An image a little older than the last pair
(e.g. the late partner of a dropped image) is put aside and counted as unpaired, unless the other
camera's images went back too and it pairs with one of them: a bag shorter than that jump,
looped, which restarts the track the same way. The pairing, its counts and these restarts are
:class:`~face_tracking_ros.processing.stereo_pairing.StereoPairing`'s; the processor restarts
the tracker when it is told to. The pair stamps also tell the tracker how many frame intervals
passed since the last pair (:class:`~face_tracking_ros.processing.frame_intervals.FrameIntervals`),
so its motion prediction spans dropped pairs.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from face_tracking_ros.errors import ConfigError, FaceTrackingError, InputError
from face_tracking_ros.geometry.camera import PinholeCamera, StereoRig
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import stamp_to_ns
from face_tracking_ros.io.messages import MessageFactory
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.processing.base import Output
from face_tracking_ros.processing.calibration import CameraCalibration
from face_tracking_ros.processing.detection import (
    DetectorFactory,
    landmark_detector,
    restart_points,
)
from face_tracking_ros.processing.face_outputs import MESH_PORTS, MODEL_PORTS, face_outputs
from face_tracking_ros.processing.frame_intervals import FrameIntervals
from face_tracking_ros.processing.held_input import HeldInput
from face_tracking_ros.processing.node_configs import (
    COMPRESSED,
    INFOS,
    LEFT_IMAGE,
    LEFT_INFO,
    MODEL,
    RIGHT_IMAGE,
    RIGHT_INFO,
    StereoNodeConfig,
    stereo_input_ports,
)
from face_tracking_ros.processing.parameters import ParameterSource
from face_tracking_ros.processing.stamp_guard import StampGuard
from face_tracking_ros.processing.stereo_pairing import StereoPairing
from face_tracking_ros.processing.track_counts import NO_REASON, TrackCounts
from face_tracking_ros.tracking.initialisation import (
    Initialisation,
    check_inside,
    load_init_file,
)
from face_tracking_ros.tracking.stereo import ExchangedPair, StereoTracker
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_result import StereoResult


class StereoProcessor:
    """Pairs left and right images by stamp and runs :class:`StereoTracker` on each pair.

    With ``retroactive_depths`` it holds every pair (its result until the track ends, then its
    messages) until :meth:`finish` (offline replay): about 20 kB per pair (peak RSS +8 MB for
    380 pairs at 640x480).

    The stamp order (:class:`~face_tracking_ros.processing.stamp_guard.StampGuard`), the pair
    held until the calibration comes (:class:`~face_tracking_ros.processing.held_input.HeldInput`)
    and each camera's calibration
    (:class:`~face_tracking_ros.processing.calibration.CameraCalibration`) follow the mono
    processor's rules. Its own: the pairing of left and right images
    (:class:`~face_tracking_ros.processing.stereo_pairing.StereoPairing`), where the last stamp
    is that of the last pair tracked, an image a little older than it is put aside, and a jump
    back restarts the track with a warning (see the module's docstring); a pair is held while
    there is no tracker (a calibration missing or refused); the two calibrations must form a
    rectified rig before either is kept: a new one that does not with the other camera's is set
    aside, and kept with the other camera's next new one if those two do (a rig switched to
    another resolution: each camera's new calibration fits only the other's new one).
    """

    def __init__(
        self,
        factory: MessageFactory,
        config: StereoNodeConfig,
        tracker_config: StereoTrackerConfig,
        model: FaceModel | None,
        initialisation: Initialisation | None,
        detector_for: DetectorFactory | None = None,
    ) -> None:
        """Wait for both camera_info messages before tracking.

        ``config.retroactive_depths`` turns the tracker's ``refine_depths`` on. ``detector_for``
        gives the landmark detector of the mesh's nodes (automatic initialisation, see
        :class:`StereoNodeConfig`); without it, tracking needs ``initialisation`` or the points
        of a reset.

        Raises:
            ConfigError: if the model's node count differs from the tracker's ``num_nodes``,
                or the initialisation names nodes that mesh does not have.
        """
        if model is not None:
            _check_nodes(model, tracker_config, ConfigError)
        _check_initialisation(initialisation, tracker_config, ConfigError)
        self._factory = factory
        self._config = config
        self._tracker_config = (
            replace(tracker_config, refine_depths=True)
            if config.retroactive_depths
            else tracker_config
        )
        self._model = model
        self._initialisation = initialisation
        self._detector_for = detector_for
        self._calibrations = {info: CameraCalibration(config.rectify) for info in INFOS}
        self._tracker: StereoTracker | None = None
        self._unfit = ''  # why the calibration gives no tracker, if it does not
        self._held: HeldInput[tuple[Any, Any]] = HeldInput(f'{LEFT_INFO} and {RIGHT_INFO}', 'pair')
        self._track_results: list[tuple[Any, StereoResult]] = []  # held: (header, result)
        self._ended_outputs: list[Output] = []  # held outputs of the tracks that ended
        self._stamps = StampGuard('pair')
        self._intervals = FrameIntervals()
        self._pairing: StereoPairing[Any] = StereoPairing(
            (LEFT_IMAGE, RIGHT_IMAGE),
            config.pairing_queue,
            config.pairing_tolerance_ms,
            self._stamps,
            self._restart_track,
        )
        self._tracked_nodes: np.ndarray | None = None  # (N, 3) of the last pair, if tracked
        self._counts = TrackCounts('pairs')
        self.inputs = stereo_input_ports(config.compressed)
        self.outputs = (*MESH_PORTS, *MODEL_PORTS)

    def reset(self, initialisation: Initialisation | None) -> str:
        """Restart tracking from 2-D left-image node positions; returns what it starts from.

        None: from a detection with auto_init (a detector), else from the last positions given
        (the init file's or an earlier reset's), as the mono tracker does.

        Raises:
            InputError: for None with neither a detector nor earlier positions, for nodes the
                mesh does not have, or positions outside the left image.
        """
        _check_initialisation(initialisation, self._tracker_config, InputError)
        left = self._calibrations[LEFT_INFO].camera
        if initialisation is not None and left is not None:
            size = (left.width, left.height)
            check_inside(initialisation.node_names, initialisation.points, size, 'left image')
        self._initialisation, source = restart_points(
            initialisation, self._initialisation, self._detector_for, 'stereo'
        )
        self._stamps.forget()  # the next pair starts the track, whatever its stamp
        if self._tracker is not None:
            self._end_track()
            self._reset_tracker()
        return source

    @property
    def unpaired(self) -> int:
        """Images that never paired so far (:attr:`StereoPairing.unpaired`)."""
        return self._pairing.unpaired

    def warning(self) -> str:
        """See :meth:`~face_tracking_ros.processing.track_counts.TrackCounts.warning`."""
        return self._counts.warning()

    def status(self) -> dict[str, str]:
        """The pairs tracked and lost so far, the images left unpaired and the rig's corrections.

        See :class:`~face_tracking_ros.processing.base.Reporting`: the pairs per status and the
        last reason (:class:`~face_tracking_ros.processing.track_counts.TrackCounts`; before
        any, why the calibration gives no tracker, e.g. a baseline in mm), ``restarts`` (tracks
        restarted by stamps that went back), ``model`` (the fingerprint of the face model in
        use), ``unpaired_images`` with, if any, ``unpaired_nearest_ms`` (how near the other
        camera's stamps came to one of them: more than ``pairing_tolerance_ms`` means
        unsynchronised cameras; :meth:`StereoPairing.report`), and once a tracker runs
        ``right_gain`` and ``right_row_offset_px`` (:class:`StereoTracker`'s).
        """
        report = {
            **self._counts.report(),
            'restarts': str(self._stamps.restarts),
            'model': self._model.fingerprint if self._model is not None else 'none (meshes only)',
            **self._pairing.report(),
        }
        never_paired = self._pairing.never_paired()
        if never_paired and report['last_reason'] == NO_REASON:  # (a short stream)
            report['last_reason'] = never_paired
        if self._unfit and report['last_reason'] == NO_REASON:  # pairs held: no tracker
            report['last_reason'] = self._unfit
        report['last_reason'] = self._held.reason(report['last_reason'])
        if self._tracker is not None:
            report['right_gain'] = f'{self._tracker.right_gain:.3f}'
            report['right_row_offset_px'] = f'{self._tracker.right_row_offset:.2f}'
        return report

    def run_deferred(self) -> None:
        """The templates the tracker samples for the next pair (``StereoTracker.prepare``).

        The node runs it once a pair's outputs are published, so they do not wait for it.
        """
        if self._tracker is not None:
            self._tracker.prepare()

    def finish(self) -> list[Output]:
        """The end of the input stream: the outputs held back (``retroactive_depths``), if any.

        Each track's pairs are emitted in order, with the frame-1 depths refined over the whole
        track applied (:meth:`StereoTracker.with_final_depths`); without the option there is
        nothing to emit. Images still waiting for a partner are counted as unpaired.
        """
        self._pairing.finish()
        self._end_track()
        outputs, self._ended_outputs = self._ended_outputs, []
        return outputs

    def handle(self, topic: str, msg: Any, wanted: frozenset[str]) -> list[Output]:
        """Process one message of an input port (see :class:`processing.base.Processor`)."""
        if topic in INFOS:
            self._set_camera(topic, msg)
            return self._track_held_pair()
        if topic == MODEL:
            model = conversions.model_from_msg(msg)
            _check_nodes(model, self._tracker_config, InputError)
            self._model = model
            self._rebuild()
            return []
        topic = COMPRESSED.get(topic, topic)  # pairs by side, whatever the transport
        pair = self._pairing.offer(topic, conversions.checked_stamp_ns(msg.header), msg)
        if pair is not None and self._tracker is None:  # held until the calibration comes
            dropped = self._held.hold(pair)
            if self._unfit:
                raise InputError(self._unfit)
            if dropped:
                raise InputError(dropped)
            return []
        return [] if pair is None else self._track(*pair)

    def _track_held_pair(self) -> list[Output]:
        """Track the pair that arrived before its calibration, once the calibration is there."""
        if self._tracker is None:
            return []
        return self._held.release(lambda pair: self._track(*pair))

    def _set_camera(self, topic: str, msg: Any) -> None:
        """Keep a new calibration if it forms a rectified rig with the other camera's.

        One that does not is set aside (:meth:`CameraCalibration.set_aside`), unless it forms one
        with the other camera's calibration set aside: then both are kept.

        Raises:
            InputError: for a bad camera_info, if the new calibration forms no rig (it is set
                aside), or one has a distortion model that cannot be rectified (the old ones
                are kept).
        """
        calibration = self._calibrations[topic]
        camera = calibration.read(msg)
        if camera is None:
            return
        other_topic = RIGHT_INFO if topic == LEFT_INFO else LEFT_INFO
        other = self._calibrations[other_topic]
        problem = '' if other.camera is None else _rig_problem(topic, camera, other.camera)
        if problem and (
            other.pending is None or _rig_problem(topic, camera, other.pending.camera)
        ):
            calibration.set_aside(camera)
            msg = f'{problem}; set aside until {other_topic} brings a calibration that fits it'
            raise InputError(msg)
        calibration.keep(camera)
        if problem:  # the other camera's new calibration, set aside, forms the rig with it
            other.keep_pending()
        self._rebuild()

    def _cameras(self) -> dict[str, PinholeCamera]:
        """The calibrations kept so far, by camera_info topic."""
        return {
            topic: calibration.camera
            for topic, calibration in self._calibrations.items()
            if calibration.camera is not None
        }

    def _rebuild(self) -> None:
        """A tracker for the rig and model, once both calibrations are there.

        A calibration or model that changes while a track runs restarts it from the nodes of its
        last tracked pair as the new left calibration sees them (those inside its image:
        :meth:`CameraCalibration.seen`), not from the initialisation's positions (made on the
        first pair, the head may have moved since).

        Raises:
            FaceTrackingError: why the tracker cannot work with them (also kept, and given for
                every pair until a calibration or model that fits arrives).
        """
        cameras = self._cameras()
        if len(cameras) < 2:
            return
        tracked_nodes = self._tracked_nodes  # (kept until a pair is tracked, as the mono's)
        self._end_track()
        rig = StereoRig(cameras[LEFT_INFO], cameras[RIGHT_INFO])
        names = mesh_topology(self._tracker_config.num_nodes).node_names
        detector = None if self._detector_for is None else self._detector_for(names)
        self._tracker, self._unfit = None, ''
        try:
            self._tracker = StereoTracker(rig, self._tracker_config, self._model, detector)
        except FaceTrackingError as error:
            self._unfit = f'cannot track with this calibration: {error}'
            raise
        pixels = (
            None if tracked_nodes is None else self._calibrations[LEFT_INFO].seen(tracked_nodes)
        )
        if (
            pixels is not None
            and np.isfinite(pixels[:, 0]).sum() >= self._tracker_config.init.min_given_nodes
        ):
            # A new calibration mid-track: go on from where the face was (NaN: not given).
            self._tracker.reset(pixels)
        elif self._can_initialise:  # (too few of those nodes left inside: as at the start)
            self._reset_tracker()

    def _reset_tracker(self) -> None:
        """Restart the tracker from the initialisation, its points moved to the rectified image."""
        assert self._tracker is not None
        self._tracked_nodes = None
        self._tracker.reset(self._calibrations[LEFT_INFO].rectified(self._initialisation))

    def _restart_track(self) -> None:
        """The cameras' stamps went back (the pairing restarted): start from the initialisation."""
        if self._tracker is not None and self._can_initialise:
            self._end_track()
            self._reset_tracker()

    @property
    def _can_initialise(self) -> bool:
        """Whether the tracker can start: it has node positions or a detector."""
        return self._initialisation is not None or self._detector_for is not None

    def _track(self, left_msg: Any, right_msg: Any) -> list[Output]:
        if not self._can_initialise:
            msg = (
                'not initialised: set init_file or auto_init, or call reset_tracking with node '
                'positions'
            )
            raise InputError(msg)
        left_raw = conversions.message_to_gray(left_msg)
        left = self._rectified_image(LEFT_INFO, left_raw)
        right_raw = conversions.message_to_gray(right_msg)
        right = self._rectified_image(RIGHT_INFO, right_raw)
        stamp_ns = stamp_to_ns(left_msg.header.stamp)
        previous = self._stamps.last
        self._stamps.take(stamp_ns)
        intervals = self._intervals.since(previous, stamp_ns)
        result = self._tracker.step(left, right, intervals, self._exchanged(left_raw, right_raw))
        self._tracked_nodes = result.nodes_cam if result.ok else None
        self._counts.add(result.status, result.reason)
        header = conversions.copy_header(self._factory, left_msg.header)
        if self._config.retroactive_depths:
            self._track_results.append((header, result))
            return []
        return self._outputs(header, result)

    def _rectified_image(self, info: str, gray: np.ndarray) -> np.ndarray:
        """A raw image of the camera of ``info``, rectified (see ``rectify``).

        Raises:
            InputError: if its size is not the one camera_info gives.
        """
        rectifier = self._calibrations[info].rectifier
        rectifier.check_size(gray, f'{info.split("/")[0]} image')
        return rectifier.image(gray)

    def _exchanged(self, left: np.ndarray, right: np.ndarray) -> ExchangedPair | None:
        """The raw pair exchanged, each rectified as its own camera's, made if the tracker asks.

        Raw images whose topics are remapped the wrong way round are rectified each with the
        other camera's rotation, which no stereo match survives from about 1.5 degrees on: this
        is the pair as the topics wired right would give it, for the tracker to name the swap
        (:func:`~face_tracking_ros.tracking.stereo_init.check_raw_not_swapped`). None when
        neither camera's images are rectified here.
        """
        left_rectifier, right_rectifier = (self._calibrations[info].rectifier for info in INFOS)
        if left_rectifier.identity and right_rectifier.identity:
            return None
        return lambda: (left_rectifier.image(right), right_rectifier.image(left))

    def _outputs(self, header: Any, result: StereoResult) -> list[Output]:
        """The messages of one pair's result, stamped with its left image's header."""
        assert self._tracker is not None
        return face_outputs(
            self._factory,
            header,
            self._config.face_id,
            result.as_track_result(),
            self._tracker.topology,
            self._model is not None,
        )

    def _end_track(self) -> None:
        """Before a reset or a new tracker: the held pairs, each track's with its final depths."""
        if not self._track_results:
            return
        assert self._tracker is not None
        headers, results = zip(*self._track_results, strict=True)
        final = self._tracker.with_final_depths(results)
        for header, result in zip(headers, final, strict=True):
            self._ended_outputs += self._outputs(header, result)
        self._track_results = []


def _check_nodes(
    model: FaceModel, tracker_config: StereoTrackerConfig, error: type[Exception]
) -> None:
    """Raise ``error`` if the model's node count differs from the tracker's."""
    if model.num_nodes != tracker_config.num_nodes:
        msg = (
            f'model has {model.num_nodes} nodes but the tracker is set to '
            f'{tracker_config.num_nodes} (tracker.num_nodes): model refused'
        )
        raise error(msg)


def _check_initialisation(
    initialisation: Initialisation | None,
    tracker_config: StereoTrackerConfig,
    error: type[Exception],
) -> None:
    """Raise ``error`` if the initialisation names nodes the tracker's mesh does not have."""
    names = mesh_topology(tracker_config.num_nodes).node_names
    owner = f'the {tracker_config.num_nodes}-node mesh (tracker.num_nodes)'
    unknown = initialisation.unknown_nodes(names, owner) if initialisation else ''
    if unknown:
        raise error(unknown)


def _rig_problem(topic: str, camera: PinholeCamera, other: PinholeCamera) -> str:
    """Why ``camera``, of the camera_info ``topic``, and ``other`` form no rig; '' if they do."""
    left, right = (camera, other) if topic == LEFT_INFO else (other, camera)
    try:
        StereoRig(left, right)
    except InputError as error:
        return str(error)
    return ''


def make_stereo_processor(params: ParameterSource, factory: MessageFactory) -> StereoProcessor:
    """The stereo_tracker processor configured from parameters (node or replay).

    Parameters: those of :class:`StereoNodeConfig`, ``tracker.*`` those of
    :class:`~face_tracking_ros.tracking.stereo_config.StereoTrackerConfig` and ``detector.*``
    those of :class:`~face_tracking_ros.tracking.detector.DetectorConfig`.

    Raises:
        ConfigError: for ``retroactive_depths`` in a live node, a bad parameter or init file,
            or ``auto_init`` without the detector installed.
        ModelFileError: for an unusable model file.
    """
    config = params.config(StereoNodeConfig)
    if config.retroactive_depths and params.live:
        msg = (
            'retroactive_depths is for offline replay (face-tracking track, learn): a live '
            'node publishes each pair as it comes and cannot rewrite it later'
        )
        raise ConfigError(msg)
    tracker_config = params.config(StereoTrackerConfig, prefix='tracker.')
    model = load_model(config.model_file) if config.model_file else None
    init = load_init_file(config.init_file) if config.init_file else None
    detector_for = landmark_detector(params, config.auto_init)
    return StereoProcessor(factory, config, tracker_config, model, init, detector_for)
