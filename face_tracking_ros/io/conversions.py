"""Conversions between ROS messages and the arrays and dataclasses of the algorithm layer.

The one place where message fields meet numpy. Readers accept rclpy and rosbags messages alike
(same field names); writers build messages through a
:class:`~face_tracking_ros.io.messages.MessageFactory`, so the live nodes and offline replay
share this code. Every reader validates what it reads and raises
:class:`~face_tracking_ros.errors.InputError` naming the message field at fault.
"""

from __future__ import annotations

from dataclasses import dataclass
import json
from typing import Any

import cv2
import numpy as np

from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import omega_to_quaternion
from face_tracking_ros.imaging.gray import encoding_channels, to_gray
from face_tracking_ros.io.bags import NS_PER_S, stamp_to_ns
from face_tracking_ros.io.messages import MessageFactory
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import MeshTopology
from face_tracking_ros.tracking.initialisation import Initialisation
from face_tracking_ros.tracking.result import TrackResult
from face_tracking_ros.wording import counted

IMAGE_TYPE = 'sensor_msgs/msg/Image'
COMPRESSED_IMAGE_TYPE = 'sensor_msgs/msg/CompressedImage'
CAMERA_INFO_TYPE = 'sensor_msgs/msg/CameraInfo'
STATE_TYPE = 'face_tracking_msgs/msg/FaceState'
TRUTH_TYPE = 'face_tracking_msgs/msg/FaceTruth'


def make_header(factory: MessageFactory, stamp_ns: int, frame_id: str) -> Any:
    """A std_msgs/Header with the given stamp (ns) and frame."""
    stamp = factory.make(
        'builtin_interfaces/msg/Time',
        sec=stamp_ns // 1_000_000_000,
        nanosec=stamp_ns % 1_000_000_000,
    )
    return factory.make('std_msgs/msg/Header', stamp=stamp, frame_id=frame_id)


def checked_stamp_ns(header: Any) -> int:
    """The stamp of an input's ``header``, ns since the epoch, refusing an invalid one.

    builtin_interfaces/Time's ``nanosec`` is below 10^9; a larger one (a driver that adds
    nanoseconds without carrying them into ``sec``) reads as a stamp up to 4.3 s late, and the
    next image's, which went back from it, restarted the track.

    Raises:
        InputError: naming the field and its value.
    """
    nanosec = int(header.stamp.nanosec)
    if not 0 <= nanosec < NS_PER_S:
        msg = (
            f'header.stamp.nanosec = {nanosec} is not below 10^9 (1 s): an invalid stamp, '
            'message skipped'
        )
        raise InputError(msg)
    return stamp_to_ns(header.stamp)


def copy_header(factory: MessageFactory, header: Any) -> Any:
    """A copy of ``header`` built by ``factory``: carries stamp and frame_id to the outputs."""
    return make_header(factory, stamp_to_ns(header.stamp), str(header.frame_id))


# --- images and cameras -------------------------------------------------------------------------


def image_to_gray(msg: Any) -> np.ndarray:
    """Grey (H, W) uint8 image of a sensor_msgs/Image in a supported 8-bit encoding.

    mono8, rgb8, bgr8, rgba8, bgra8, the four bayer_*8 patterns, yuv422 (UYVY), yuv422_yuy2 and
    cv_bridge's passthrough 8UC1, 8UC3 (BGR) and 8UC4 (BGRA)
    (:data:`~face_tracking_ros.imaging.gray.SUPPORTED_ENCODINGS`).

    Raises:
        InputError: for another encoding, or when height, width, step and data disagree.
    """
    encoding = str(msg.encoding)
    channels = encoding_channels(encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if height <= 0 or width <= 0:
        msg_text = f'image of {width}x{height} {encoding} is empty'
        raise InputError(msg_text)
    row_bytes = width * channels
    if step < row_bytes or data.size < step * height:
        msg_text = (
            f'image of {width}x{height} {encoding} has step {step} and {data.size} data bytes; '
            f'needs step >= {row_bytes} and step x height = {max(step, row_bytes) * height} '
            'bytes'
        )
        raise InputError(msg_text)
    rows = data[: step * height].reshape(height, step)[:, : width * channels]
    return to_gray(rows.reshape(height, width, channels), encoding)


def compressed_to_gray(msg: Any) -> np.ndarray:
    """Grey (H, W) uint8 image decoded from a sensor_msgs/CompressedImage (JPEG or PNG).

    An 8-bit image only, as of a raw Image (:func:`image_to_gray`): image_transport's PNG of a
    mono16 camera or a depth image is refused, as their raw Image is, where OpenCV would hand
    over its top byte.

    Raises:
        InputError: if the data does not decode, or decodes to a 16-bit image.
    """
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if not len(data):
        msg_text = f'compressed image in format {msg.format!r} has no data'
        raise InputError(msg_text)
    gray = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
    if gray is None:
        msg_text = f'compressed image in format {msg.format!r} does not decode'
        raise InputError(msg_text)
    if gray.dtype != np.uint8:
        msg_text = (
            f'compressed image in format {msg.format!r} is {8 * gray.itemsize}-bit: the trackers '
            'take 8-bit images'
        )
        raise InputError(msg_text)
    return gray


def message_to_gray(msg: Any) -> np.ndarray:
    """Grey (H, W) uint8 image of a sensor_msgs/Image or CompressedImage.

    The two are told apart by their fields (an Image has an ``encoding``): see
    :func:`image_to_gray` and :func:`compressed_to_gray`.

    Raises:
        InputError: as those do.
    """
    return image_to_gray(msg) if hasattr(msg, 'encoding') else compressed_to_gray(msg)


def array_to_image(
    factory: MessageFactory, header: Any, pixels: np.ndarray, encoding: str = ''
) -> Any:
    """A sensor_msgs/Image of an (H, W) mono8 or (H, W, 3) rgb8 uint8 array.

    Args:
        factory: message factory.
        header: header of the image.
        pixels: the image; its shape chooses mono8 or rgb8 unless ``encoding`` is given.
        encoding: 'mono8', 'rgb8' or 'bgr8'; empty to choose from the shape.
    """
    pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    encoding = encoding or ('mono8' if channels == 1 else 'rgb8')
    if encoding_channels(encoding) != channels:
        msg_text = f'array of shape {pixels.shape} cannot be encoded as {encoding!r}'
        raise InputError(msg_text)
    height, width = pixels.shape[:2]
    return factory.make(
        IMAGE_TYPE,
        header=header,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * channels,
        data=pixels.reshape(-1),
    )


def camera_from_info(msg: Any) -> PinholeCamera:
    """A PinholeCamera from a sensor_msgs/CameraInfo.

    Raises:
        InputError: for an uncalibrated (all-zero K) or malformed CameraInfo.
    """
    for name, length in (('k', 9), ('r', 9), ('p', 12)):
        size = np.size(getattr(msg, name))
        if size != length:
            msg_text = f'camera_info {name.upper()} has {size} values, expected {length}'
            raise InputError(msg_text)
    if not np.any(np.asarray(msg.k, dtype=float)):
        msg_text = 'camera_info has an all-zero K: the camera is not calibrated'
        raise InputError(msg_text)
    return PinholeCamera.from_camera_info(msg)


def calibration_key(msg: Any) -> tuple:
    """What of a sensor_msgs/CameraInfo :func:`camera_from_info` reads, comparable and hashable.

    Equal keys give equal cameras (:class:`CameraInfoReader`).
    """
    arrays = (np.asarray(getattr(msg, name), dtype=float).tobytes() for name in 'dkrp')
    roi = msg.roi
    cropping = (msg.binning_x, msg.binning_y, roi.x_offset, roi.y_offset, roi.width, roi.height)
    return (int(msg.width), int(msg.height), str(msg.distortion_model), *cropping, *arrays)


class CameraInfoReader:
    """:func:`camera_from_info` of a stream of CameraInfo, converted only when it changes.

    A camera driver repeats the same CameraInfo with every image; its :func:`calibration_key`
    tells a repeat from a change, so only a new calibration is converted and validated.
    """

    def __init__(self) -> None:
        """Start with no calibration."""
        self._key: tuple | None = None
        self._camera: PinholeCamera | None = None

    def read(self, msg: Any) -> PinholeCamera:
        """The camera of ``msg``; the previous one when its calibration is unchanged.

        Raises:
            InputError: as :func:`camera_from_info` (the previous calibration is kept).
        """
        key = calibration_key(msg)
        if key != self._key:  # None before the first calibration converted
            self._camera = camera_from_info(msg)
            self._key = key
        return self._camera


def camera_to_info(factory: MessageFactory, header: Any, camera: PinholeCamera) -> Any:
    """A sensor_msgs/CameraInfo describing ``camera``."""
    fields = camera.camera_info_fields()
    return factory.make(
        CAMERA_INFO_TYPE,
        header=header,
        height=fields['height'],
        width=fields['width'],
        distortion_model=fields['distortion_model'],
        d=np.asarray(fields['d'], dtype=float),
        k=np.asarray(fields['k'], dtype=float),
        r=np.asarray(fields['r'], dtype=float),
        p=np.asarray(fields['p'], dtype=float),
    )


# --- points and poses ---------------------------------------------------------------------------


def finite_vector(values: Any, field: str, length: int | None = None) -> np.ndarray:
    """A finite float vector from a message field (an array of any shape, flattened).

    Raises:
        InputError: naming ``field`` if a value is NaN or Inf (how many, and the first one's
            index in ``values``' shape, not the values) or the length is not ``length``.
    """
    array = np.asarray(values, dtype=float)
    vector = array.ravel()
    if length is not None and vector.size != length:
        msg_text = f'{field} has {vector.size} values, expected {length}'
        raise InputError(msg_text)
    finite = np.isfinite(vector)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        index = ', '.join(str(int(i)) for i in np.unravel_index(bad[0], array.shape))
        msg_text = (
            f'{field} holds NaN or Inf: {len(bad)} of {vector.size} values, the first '
            f'({vector[bad[0]]}){f" at [{index}]" if index else ""}'
        )
        raise InputError(msg_text)
    return vector


def points_to_array(points: Any, field: str) -> np.ndarray:
    """(N, 3) array of a geometry_msgs/Point list, validated finite."""
    array = np.array([(p.x, p.y, p.z) for p in points], dtype=float).reshape(-1, 3)
    return finite_vector(array, field).reshape(-1, 3)


def array_to_points(factory: MessageFactory, array: np.ndarray) -> list[Any]:
    """geometry_msgs/Point list of an (N, 2) or (N, 3) array (z = 0 for 2-D points)."""
    array = np.asarray(array, dtype=float)
    if array.shape[1] == 2:
        planar, array = array, np.zeros((len(array), 3))
        array[:, :2] = planar
    return factory.points(array)


def pose_msg(factory: MessageFactory, omega: np.ndarray, t: np.ndarray) -> Any:
    """geometry_msgs/Pose of cam_T_face from rotation vector omega (rad) and translation t (m)."""
    qx, qy, qz, qw = omega_to_quaternion(omega).tolist()
    return factory.make(
        'geometry_msgs/msg/Pose',
        position=factory.make('geometry_msgs/msg/Point', x=t[0], y=t[1], z=t[2]),
        orientation=factory.make('geometry_msgs/msg/Quaternion', x=qx, y=qy, z=qz, w=qw),
    )


# --- the face model -----------------------------------------------------------------------------


def model_to_msg(factory: MessageFactory, header: Any, model: FaceModel) -> Any:
    """face_tracking_msgs/FaceModel of a model (matrices flattened row-major)."""
    return factory.make(
        'face_tracking_msgs/msg/FaceModel',
        header=header,
        node_names=list(model.node_names),
        mean_shape=model.mean_shape.astype(float),
        shape_basis=model.shape_basis.ravel().astype(float),
        action_basis=model.action_basis.ravel().astype(float),
        shape_eigenvalues=model.shape_eigenvalues.astype(float),
        action_eigenvalues=model.action_eigenvalues.astype(float),
        sigma_prior_covariance=model.sigma_prior_covariance.ravel().astype(float),
        alpha_prior_covariance=model.alpha_prior_covariance.ravel().astype(float),
        p=model.p,
        q=model.q,
        method=model.method,
        metadata_json=json.dumps(model.metadata, sort_keys=True),
    )


def model_from_msg(msg: Any) -> FaceModel:
    """FaceModel from a face_tracking_msgs/FaceModel, validated.

    Raises:
        InputError: if array lengths disagree with N, p and q or metadata is not JSON.
        ModelFileError: if the arrays do not form a valid model (NaN, non-orthonormal basis).
    """
    n3, p, q = 3 * len(msg.node_names), int(msg.p), int(msg.q)
    try:
        metadata = json.loads(msg.metadata_json) if msg.metadata_json else {}
    except json.JSONDecodeError as error:
        msg_text = f'FaceModel.metadata_json is not JSON: {error}'
        raise InputError(msg_text) from None
    return FaceModel(
        node_names=tuple(msg.node_names),
        mean_shape=_sized(msg.mean_shape, 'FaceModel.mean_shape', n3),
        shape_basis=_sized(msg.shape_basis, 'FaceModel.shape_basis', n3 * p).reshape(n3, p),
        action_basis=_sized(msg.action_basis, 'FaceModel.action_basis', n3 * q).reshape(n3, q),
        shape_eigenvalues=_sized(msg.shape_eigenvalues, 'FaceModel.shape_eigenvalues', p),
        action_eigenvalues=_sized(msg.action_eigenvalues, 'FaceModel.action_eigenvalues', q),
        sigma_prior_covariance=_sized(
            msg.sigma_prior_covariance, 'FaceModel.sigma_prior_covariance', p * p
        ).reshape(p, p),
        alpha_prior_covariance=_sized(
            msg.alpha_prior_covariance, 'FaceModel.alpha_prior_covariance', q * q
        ).reshape(q, q),
        method=str(msg.method),
        metadata=metadata,
    )


def _sized(values: Any, field: str, length: int) -> np.ndarray:
    """Float array of exactly ``length`` values (NaN is left to model validation).

    A copy: a message read from a bag holds read-only views of its buffer, and the trackers'
    compiled kernels are compiled for writable arrays.
    """
    array = np.array(values, dtype=float).ravel()
    if array.size != length:
        msg_text = f'{field} has {array.size} values, expected {length}'
        raise InputError(msg_text)
    return array


# --- ground truth -------------------------------------------------------------------------------


@dataclass(frozen=True)
class TruthSample:
    """One frame of synthetic ground truth (a face_tracking_msgs/FaceTruth).

    Attributes:
        stamp_ns: image time, ns.
        subject_id: synthetic subject.
        omega: (3,) rotation vector of cam_T_face, rad.
        t: (3,) translation of cam_T_face, m.
        alpha: true expression coefficients.
        sigma: true identity coefficients.
        nodes: (N, 3) true nodes in the camera frame, m.
        label: expression label ('neutral' if none).
        intensity: expression intensity in [0, 1].
    """

    stamp_ns: int
    subject_id: str
    omega: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    sigma: np.ndarray
    nodes: np.ndarray
    label: str
    intensity: float


def truth_from_msg(msg: Any) -> TruthSample:
    """TruthSample of a face_tracking_msgs/FaceTruth."""
    position = msg.pose.position
    return TruthSample(
        stamp_ns=stamp_to_ns(msg.header.stamp),
        subject_id=str(msg.subject_id),
        omega=finite_vector(msg.omega, 'FaceTruth.omega', 3),
        t=finite_vector([position.x, position.y, position.z], 'FaceTruth.pose.position', 3),
        alpha=finite_vector(msg.alpha, 'FaceTruth.alpha'),
        sigma=finite_vector(msg.sigma, 'FaceTruth.sigma'),
        nodes=points_to_array(msg.nodes, 'FaceTruth.nodes'),
        label=str(msg.expression_label),
        intensity=float(msg.expression_intensity),
    )


# --- tracker outputs ----------------------------------------------------------------------------


@dataclass(frozen=True)
class FaceMessages:
    """Every per-frame output message of a tracker for one face."""

    state: Any
    pose: Any
    action: Any
    shape: Any
    mesh: Any
    markers: Any


def face_messages(
    factory: MessageFactory,
    header: Any,
    face_id: str,
    result: TrackResult,
    topology: MeshTopology,
) -> FaceMessages:
    """The FaceState, PoseStamped, ActionParams, ShapeParams, FaceMesh and MarkerArray of a result.

    Args:
        factory: message factory.
        header: header of the source image (stamp and frame_id are carried to every output).
        face_id: tracker-assigned face identifier.
        result: the tracker's estimate for this image.
        topology: the mesh topology (node names and edges).
    """
    omega = _nan_as_zero(result.omega)
    pose = pose_msg(factory, omega, _nan_as_zero(result.t))
    nodes = array_to_points(factory, _nan_as_zero(result.nodes_cam))
    state = factory.make(
        'face_tracking_msgs/msg/FaceState',
        header=header,
        face_id=face_id,
        status=int(result.status),
        pose=pose,
        omega=omega,
        alpha=np.asarray(result.alpha, dtype=float),
        sigma=np.asarray(result.sigma, dtype=float),
        node_names=list(topology.node_names),
        nodes=nodes,
        image_points=array_to_points(factory, _nan_as_zero(result.nodes_px)),
        node_residuals=_nan_as_zero(result.node_residuals),
        right_node_residuals=_nan_as_zero(
            np.zeros(0) if result.right_node_residuals is None else result.right_node_residuals
        ),
        occluded=np.zeros(0, dtype=bool) if result.occluded is None else result.occluded,
        mean_residual=float(_nan_as_zero(result.mean_residual)),
        iterations=int(result.iterations),
    )
    return FaceMessages(
        state=state,
        pose=factory.make('geometry_msgs/msg/PoseStamped', header=header, pose=pose),
        action=factory.make(
            'face_tracking_msgs/msg/ActionParams',
            header=header,
            face_id=face_id,
            alpha=np.asarray(result.alpha, dtype=float),
        ),
        shape=factory.make(
            'face_tracking_msgs/msg/ShapeParams',
            header=header,
            face_id=face_id,
            sigma=np.asarray(result.sigma, dtype=float),
        ),
        mesh=factory.make(
            'face_tracking_msgs/msg/FaceMesh',
            header=header,
            face_id=face_id,
            node_names=list(topology.node_names),
            points=nodes,
            edges=topology.edges.ravel().astype(np.uint32),
        ),
        markers=mesh_markers(factory, header, face_id, nodes, topology, result.ok),
    )


_UNTRACKED_COLOUR = (0.5, 0.5, 0.5, 0.5)  # RGBA of the mesh of a face that is not tracked


def occluded_nodes(state: Any) -> np.ndarray:
    """A FaceState's ``occluded`` flags as a bool array: (N,), or empty where none were judged.

    A FaceState written before the field existed (read with its bag's own definition,
    :mod:`.bag_definitions`) has none: empty too.
    """
    return np.asarray(getattr(state, 'occluded', ()), dtype=bool)


def _nan_as_zero(values: Any) -> np.ndarray:
    """Float array of ``values`` with NaN (no estimate yet, INITIALIZING) as 0."""
    values = np.array(values, dtype=float)
    values[np.isnan(values)] = 0.0
    return values


MESH_MARKER_IDS = (0, 1)  # the mesh's markers in its face's namespace: nodes, edges


def mesh_markers(
    factory: MessageFactory,
    header: Any,
    face_id: str,
    points: list[Any],
    topology: MeshTopology,
    tracked: bool = True,
) -> Any:
    """visualization_msgs/MarkerArray drawing the mesh: nodes as spheres, edges as lines (m).

    Args:
        factory: message factory.
        header: header of the markers.
        face_id: the marker namespace.
        points: the N nodes as geometry_msgs/Point (camera frame, m), shared with the FaceMesh.
        topology: the mesh topology (its edges).
        tracked: False for a face that is not tracked (LOST, with its last valid mesh, or not
            yet initialised): the mesh is drawn grey and half transparent.
    """
    edge_points = [points[i] for i in topology.edges.ravel().tolist()]
    identity = factory.make(
        'geometry_msgs/msg/Pose', orientation=factory.make('geometry_msgs/msg/Quaternion', w=1.0)
    )

    def marker(marker_id: int, kind: int, size: float, color: tuple, pts: list) -> Any:
        r, g, b, a = color if tracked else _UNTRACKED_COLOUR
        return factory.make(
            'visualization_msgs/msg/Marker',
            header=header,
            ns=face_id,
            id=marker_id,
            type=kind,
            action=0,
            pose=identity,
            scale=factory.make('geometry_msgs/msg/Vector3', x=size, y=size, z=size),
            color=factory.make('std_msgs/msg/ColorRGBA', r=r, g=g, b=b, a=a),
            points=pts,
        )

    sphere_list, line_list = 7, 5  # visualization_msgs/Marker.SPHERE_LIST, LINE_LIST
    nodes_id, edges_id = MESH_MARKER_IDS
    # Colours are exact in float32 (ColorRGBA), so rclpy and rosbags messages compare equal.
    return factory.make(
        'visualization_msgs/msg/MarkerArray',
        markers=[
            marker(nodes_id, sphere_list, 0.004, (1.0, 0.375, 0.125, 1.0), points),
            marker(edges_id, line_list, 0.001, (0.125, 0.75, 1.0, 1.0), edge_points),
        ],
    )


def deleted_mesh_markers(factory: MessageFactory, header: Any, face_id: str) -> Any:
    """visualization_msgs/MarkerArray deleting the markers :func:`mesh_markers` draws.

    For a face without an estimate (INITIALIZING): a marker stays on a viewer's screen until
    it is deleted, so the last tracked mesh would stay drawn, in the tracked colour.
    """
    delete = 2  # visualization_msgs/Marker.DELETE
    return factory.make(
        'visualization_msgs/msg/MarkerArray',
        markers=[
            factory.make(
                'visualization_msgs/msg/Marker', header=header, ns=face_id, id=i, action=delete
            )
            for i in MESH_MARKER_IDS
        ],
    )


def initialisation_from_reset(request: Any) -> Initialisation | None:
    """The Initialisation of a ResetTracking request; None (automatic) when it is empty.

    Raises:
        ConfigError: if names and points disagree in number, are too few, or a name repeats.
    """
    if not request.node_names and not request.points:
        return None
    if len(request.node_names) != len(request.points):
        names = counted(len(request.node_names), 'node name')
        msg = f'{names} but {counted(len(request.points), "point")}'
        raise ConfigError(msg)
    points = np.array([[point.x, point.y] for point in request.points], dtype=float)
    try:
        return Initialisation(
            tuple(request.node_names), points, source='the reset_tracking request'
        )
    except ConfigError as error:
        raise ConfigError(f'reset_tracking request: {error}') from None
