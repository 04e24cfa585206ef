"""Message <-> array conversions, built through both factories (rclpy and rosbags)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from rclpy.serialization import deserialize_message

from face_tracking_ros.errors import ConfigError, InputError, ModelFileError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.io import conversions
from face_tracking_ros.io.messages import RclpyMessages, RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.result import TrackResult, TrackStatus

MODEL = 'face_tracking_msgs/msg/FaceModel'

STAMP_NS = 1_700_000_000_123_456_789


def _result(num_nodes: int = 34, p: int = 2, q: int = 5) -> TrackResult:
    rng = np.random.default_rng(3)
    return TrackResult(
        status=TrackStatus.TRACKING,
        omega=np.array([0.1, -0.2, 0.05]),
        t=np.array([0.01, -0.02, 0.65]),
        alpha=rng.normal(size=q),
        sigma=rng.normal(size=p),
        nodes_cam=rng.normal(size=(num_nodes, 3)),
        nodes_px=rng.uniform(0, 640, size=(num_nodes, 2)),
        node_residuals=rng.uniform(0, 9, size=num_nodes),
        mean_residual=4.5,
        iterations=7,
    )


def _model(num_nodes: int = 19, p: int = 2, q: int = 3) -> FaceModel:
    rng = np.random.default_rng(5)
    basis, _ = np.linalg.qr(rng.normal(size=(3 * num_nodes, p + q)))
    return FaceModel(
        node_names=mesh_topology(num_nodes).node_names,
        mean_shape=mesh_topology(num_nodes).reference_shape.ravel().copy(),
        shape_basis=basis[:, :p],
        action_basis=basis[:, p:],
        shape_eigenvalues=np.array([4e-5, 1e-5]),
        action_eigenvalues=np.array([9e-5, 3e-5, 1e-5]),
        sigma_prior_covariance=np.diag([4e-5, 1e-5]),
        alpha_prior_covariance=np.diag([9e-5, 3e-5, 1e-5]),
        method='seed',
        metadata={'subjects': 11},
    )


def _face_messages(factory):
    header = conversions.make_header(factory, STAMP_NS, 'camera_optical')
    return conversions.face_messages(factory, header, 'face_0', _result(), mesh_topology(34))


@pytest.mark.parametrize('field', ['state', 'pose', 'action', 'shape', 'mesh', 'markers'])
def test_both_factories_build_equal_messages(field):
    store = typestore()
    built_rosbags = getattr(_face_messages(RosbagsMessages(store)), field)
    built_rclpy = getattr(_face_messages(RclpyMessages()), field)
    msgtype = built_rosbags.__msgtype__
    rosbags_bytes = bytes(store.serialize_cdr(built_rosbags, msgtype))
    assert deserialize_message(rosbags_bytes, type(built_rclpy)) == built_rclpy


def test_face_state_carries_result_and_header():
    state = _face_messages(RosbagsMessages(typestore())).state
    result = _result()
    assert conversions.stamp_to_ns(state.header.stamp) == STAMP_NS
    assert state.header.frame_id == 'camera_optical'
    assert state.status == TrackStatus.TRACKING
    np.testing.assert_allclose(state.omega, result.omega)
    np.testing.assert_allclose(conversions.points_to_array(state.nodes, 'nodes'), result.nodes_cam)
    assert list(state.node_names) == list(mesh_topology(34).node_names)
    assert state.iterations == 7
    position, orientation = state.pose.position, state.pose.orientation
    assert (position.x, position.y, position.z) == (0.01, -0.02, 0.65)  # t, m
    # The quaternion of omega: axis omega / |omega|, half the angle |omega| (x, y, z, w).
    angle = np.linalg.norm(result.omega)
    expected = [*np.sin(angle / 2) * result.omega / angle, np.cos(angle / 2)]
    quaternion = [orientation.x, orientation.y, orientation.z, orientation.w]
    np.testing.assert_allclose(quaternion, expected, rtol=0, atol=1e-15)


def test_mesh_and_markers_hold_the_result_s_nodes_and_the_topology_s_edges():
    """FaceMesh and the RViz markers: nodes as spheres, each edge as its two end nodes."""
    messages = _face_messages(RosbagsMessages(typestore()))
    nodes, topology = _result().nodes_cam, mesh_topology(34)
    mesh = messages.mesh
    np.testing.assert_array_equal(conversions.points_to_array(mesh.points, 'points'), nodes)
    np.testing.assert_array_equal(np.reshape(mesh.edges, (-1, 2)), topology.edges)
    assert list(mesh.node_names) == list(topology.node_names) and mesh.face_id == 'face_0'
    spheres, lines = messages.markers.markers
    assert (spheres.type, lines.type) == (7, 5)  # Marker.SPHERE_LIST, Marker.LINE_LIST
    assert spheres.ns == lines.ns == 'face_0' and (spheres.id, lines.id) == (0, 1)
    assert (spheres.action, lines.action) == (0, 0)  # Marker.ADD
    assert (spheres.scale.x, lines.scale.x) == (0.004, 0.001)  # sphere diameter, line width, m
    assert spheres.color.a == lines.color.a == 1.0  # a tracked face: opaque
    np.testing.assert_array_equal(conversions.points_to_array(spheres.points, 'spheres'), nodes)
    segments = conversions.points_to_array(lines.points, 'lines').reshape(-1, 2, 3)
    np.testing.assert_array_equal(segments, nodes[topology.edges])


@pytest.mark.parametrize('factory', [RosbagsMessages(typestore()), RclpyMessages()])
def test_an_initializing_result_is_published_with_zeros_for_its_nan(factory):
    header = conversions.make_header(factory, STAMP_NS, 'camera_optical')
    empty = TrackResult.empty(34, 2, 5, 'no face yet')
    state = conversions.face_messages(factory, header, 'face_0', empty, mesh_topology(34)).state
    assert state.status == TrackStatus.INITIALIZING
    assert list(state.omega) == [0.0, 0.0, 0.0]
    assert (state.pose.position.x, state.pose.position.z) == (0.0, 0.0)
    assert conversions.points_to_array(state.nodes, 'nodes').tolist() == [[0.0] * 3] * 34
    assert state.mean_residual == 0.0
    markers = conversions.face_messages(
        factory, header, 'face_0', empty, mesh_topology(34)
    ).markers
    for marker in markers.markers:  # not tracked: grey, half transparent
        colour = marker.color
        assert (colour.r, colour.g, colour.b, colour.a) == (0.5, 0.5, 0.5, 0.5)


def test_model_round_trips_through_its_message():
    model = _model()
    factory = RosbagsMessages(typestore())
    msg = conversions.model_to_msg(factory, conversions.make_header(factory, 0, 'face'), model)
    back = conversions.model_from_msg(msg)
    np.testing.assert_array_equal(back.shape_basis, model.shape_basis)
    np.testing.assert_array_equal(back.alpha_prior_covariance, model.alpha_prior_covariance)
    assert back.metadata == {'subjects': 11}
    assert back.node_names == model.node_names


def test_a_model_read_from_a_bag_has_writable_arrays():
    """Read back from CDR its arrays are read-only views, which the compiled kernels refuse."""
    store = typestore()
    factory = RosbagsMessages(store)
    msg = conversions.model_to_msg(factory, conversions.make_header(factory, 0, 'face'), _model())
    read = store.deserialize_cdr(store.serialize_cdr(msg, MODEL), MODEL)
    assert not read.shape_basis.flags.writeable  # as a bag gives it
    model = conversions.model_from_msg(read)
    assert model.shape_basis.flags.writeable and model.action_basis_nodes().flags.writeable


def test_model_message_with_wrong_length_names_the_field():
    factory = RosbagsMessages(typestore())
    msg = conversions.model_to_msg(factory, conversions.make_header(factory, 0, 'face'), _model())
    msg.action_basis = msg.action_basis[:-1]
    with pytest.raises(InputError, match='FaceModel.action_basis has 170 values, expected 171'):
        conversions.model_from_msg(msg)


def test_model_message_with_nan_is_rejected():
    factory = RosbagsMessages(typestore())
    msg = conversions.model_to_msg(factory, conversions.make_header(factory, 0, 'face'), _model())
    msg.mean_shape[4] = np.nan
    with pytest.raises(ModelFileError, match='mean_shape holds NaN'):
        conversions.model_from_msg(msg)


@pytest.mark.parametrize('encoding', ['mono8', 'rgb8', 'bgr8'])
def test_image_round_trip_gives_the_grey_image(encoding):
    rng = np.random.default_rng(1)
    gray = rng.integers(0, 256, size=(48, 64), dtype=np.uint8)
    pixels = gray if encoding == 'mono8' else np.repeat(gray[:, :, None], 3, axis=2)
    factory = RosbagsMessages(typestore())
    msg = conversions.array_to_image(
        factory, conversions.make_header(factory, 0, 'c'), pixels, encoding
    )
    np.testing.assert_array_equal(conversions.image_to_gray(msg), gray)


def test_image_with_row_padding_is_cropped_to_width():
    data = np.arange(4 * 8, dtype=np.uint8)  # 4 rows of 6 pixels, step 8
    msg = SimpleNamespace(encoding='mono8', height=4, width=6, step=8, data=data)
    np.testing.assert_array_equal(conversions.image_to_gray(msg), data.reshape(4, 8)[:, :6])


@pytest.mark.parametrize(('width', 'height'), [(4, 0), (0, 3)])
def test_an_image_without_rows_or_columns_is_refused_as_empty(width, height):
    msg = SimpleNamespace(encoding='mono8', height=height, width=width, step=4, data=b'')
    with pytest.raises(InputError, match=rf'^image of {width}x{height} mono8 is empty$'):
        conversions.image_to_gray(msg)


def test_unsupported_encoding_is_named():
    msg = SimpleNamespace(encoding='16UC1', height=2, width=2, step=4, data=np.zeros(8, np.uint8))
    with pytest.raises(InputError, match="unsupported image encoding '16UC1'"):
        conversions.image_to_gray(msg)


def test_truncated_image_data_is_reported():
    msg = SimpleNamespace(
        encoding='rgb8', height=10, width=10, step=30, data=np.zeros(200, np.uint8)
    )
    with pytest.raises(InputError, match='needs step >= 30 and step x height = 300 bytes'):
        conversions.image_to_gray(msg)


def test_uncalibrated_camera_info_is_rejected():
    info = SimpleNamespace(
        width=640,
        height=480,
        k=np.zeros(9),
        d=np.zeros(5),
        p=np.zeros(12),
        r=np.zeros(9),
        distortion_model='plumb_bob',
    )
    with pytest.raises(InputError, match='all-zero K'):
        conversions.camera_from_info(info)


def test_camera_info_round_trip():
    camera = PinholeCamera.ideal(320, 240, 300.0, tx=-33.0)
    factory = RosbagsMessages(typestore())
    msg = conversions.camera_to_info(factory, conversions.make_header(factory, 0, 'c'), camera)
    back = conversions.camera_from_info(msg)
    np.testing.assert_array_equal(back.p, camera.p)
    assert (back.width, back.height) == (320, 240)


def test_a_repeated_camera_info_gives_the_camera_read_before_unconverted():
    factory = RosbagsMessages(typestore())
    header = conversions.make_header(factory, 0, 'c')
    reader = conversions.CameraInfoReader()
    first = reader.read(conversions.camera_to_info(factory, header, PinholeCamera.ideal()))
    # A driver's repeat: another message, the same calibration.
    assert reader.read(conversions.camera_to_info(factory, header, PinholeCamera.ideal())) is first
    changed = reader.read(
        conversions.camera_to_info(factory, header, PinholeCamera.ideal(focal=610.0))
    )
    assert changed is not first and changed.focal == 610.0


def test_nan_in_a_vector_field_is_named():
    with pytest.raises(InputError, match='ActionParams.alpha holds NaN'):
        conversions.finite_vector([0.0, np.nan], 'ActionParams.alpha')


def test_nan_among_many_values_is_located_not_dumped():
    """The error printed every value: 102 of them for a 34-node mesh."""
    nodes = np.linspace(0.1, 0.9, 34 * 3).reshape(34, 3)
    nodes[3, 0] = nodes[20, 2] = np.nan
    with pytest.raises(InputError) as error:
        conversions.finite_vector(nodes, 'FaceTruth.nodes')
    expected = 'FaceTruth.nodes holds NaN or Inf: 2 of 102 values, the first (nan) at [3, 0]'
    assert str(error.value) == expected


def test_a_reset_request_becomes_an_initialisation_and_a_repeated_node_is_refused():
    """A request naming a node twice (a later click meant to correct one) is refused.

    The second point replaced the first without a word, and the fit failed on it.
    """
    names = ['right_eye', 'left_eye', 'nose_tip', 'mouth_right', 'mouth_left', 'chin']
    clicks = [(300, 210), (345, 211), (322, 250), (304, 282), (341, 282), (323, 318)]
    points = [SimpleNamespace(x=float(x), y=float(y), z=0.0) for x, y in clicks]
    init = conversions.initialisation_from_reset(SimpleNamespace(node_names=names, points=points))
    assert init.node_names == tuple(names)
    np.testing.assert_array_equal(init.points, clicks)
    assert conversions.initialisation_from_reset(SimpleNamespace(node_names=[], points=[])) is None
    again = SimpleNamespace(node_names=[*names, 'nose_tip', 'chin'], points=points + points[:2])
    with pytest.raises(
        ConfigError,
        match='reset_tracking request: initialisation repeats node names: chin, nose_tip$',
    ):
        conversions.initialisation_from_reset(again)
