"""Property-based tests (hypothesis) of the message conversions and the numerical core.

Random valid inputs never raise and give the right answer; random invalid inputs raise the
package's own error types with a message naming the problem.
"""

from __future__ import annotations

from dataclasses import replace
import re
from types import SimpleNamespace

import cv2
from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from face_tracking_ros.errors import FaceTrackingError, InputError, ModelFileError
from face_tracking_ros.geometry.procrustes import rigid_align
from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging.gray import SUPPORTED_ENCODINGS
from face_tracking_ros.io import conversions
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.model_file import ARRAY_FIELDS
from face_tracking_ros.model.topology import mesh_topology

FACTORY = RosbagsMessages(typestore())
HEADER = conversions.make_header(FACTORY, 1_700_000_000_000_000_000, 'camera_optical')
CHANNELS = {'mono8': 1, 'rgb8': 3, 'bgr8': 3, 'rgba8': 4, 'bgra8': 4, 'yuv422': 2}
CHANNELS |= {'yuv422_yuy2': 2} | {f'bayer_{p}8': 1 for p in ('rggb', 'bggr', 'gbrg', 'grbg')}
CHANNELS |= {'8UC1': 1, '8UC3': 3, '8UC4': 4}
TO_GRAY = {
    '8UC3': cv2.COLOR_BGR2GRAY,
    '8UC4': cv2.COLOR_BGRA2GRAY,
    'rgb8': cv2.COLOR_RGB2GRAY,
    'bgr8': cv2.COLOR_BGR2GRAY,
    'rgba8': cv2.COLOR_RGBA2GRAY,
    'bgra8': cv2.COLOR_BGRA2GRAY,
    'bayer_rggb8': cv2.COLOR_BayerBG2GRAY,
    'bayer_bggr8': cv2.COLOR_BayerRG2GRAY,
    'bayer_gbrg8': cv2.COLOR_BayerGR2GRAY,
    'bayer_grbg8': cv2.COLOR_BayerGB2GRAY,
    'yuv422': cv2.COLOR_YUV2GRAY_UYVY,
    'yuv422_yuy2': cv2.COLOR_YUV2GRAY_YUY2,
}
FEW = settings(max_examples=50, deadline=None)
SEEDS = st.integers(0, 2**32 - 1)
NON_FINITE = st.sampled_from([np.nan, np.inf, -np.inf])


# --- images -------------------------------------------------------------------------------------


@st.composite
def raw_images(draw):
    """(Image fields, the (H, W, C) pixels they hold): random size, encoding, row padding."""
    encoding = draw(st.sampled_from(SUPPORTED_ENCODINGS))
    channels = CHANNELS[encoding]
    height, width = draw(st.integers(1, 24)), draw(st.integers(1, 24))
    step = width * channels + draw(st.integers(0, 9))
    extra = draw(st.integers(0, 7))
    rng = np.random.default_rng(draw(SEEDS))
    data = rng.integers(0, 256, step * height + extra, dtype=np.uint8)
    pixels = data[: step * height].reshape(height, step)[:, : width * channels]
    fields = {'height': height, 'width': width, 'encoding': encoding, 'step': step, 'data': data}
    return fields, pixels.reshape(height, width, channels)


def _image(**fields):
    return FACTORY.make('sensor_msgs/msg/Image', header=HEADER, **fields)


@FEW
@given(raw_images())
def test_image_to_gray_of_any_valid_image_is_its_grey_conversion(image):
    fields, pixels = image
    gray = conversions.image_to_gray(_image(**fields))
    encoding = fields['encoding']
    grey = encoding in ('mono8', '8UC1')
    expected = pixels[:, :, 0] if grey else cv2.cvtColor(pixels, TO_GRAY[encoding])
    assert gray.dtype == np.uint8
    np.testing.assert_array_equal(gray, expected)


@FEW
@given(raw_images(), st.text(min_size=0, max_size=12))
def test_image_of_an_unknown_encoding_is_refused_by_name(image, encoding):
    fields, _ = image
    if encoding in SUPPORTED_ENCODINGS:
        encoding += '_'
    with pytest.raises(InputError, match=re.escape(f'unsupported image encoding {encoding!r}')):
        conversions.image_to_gray(_image(**{**fields, 'encoding': encoding}))


@FEW
@given(raw_images(), st.integers(1, 1000), st.booleans())
def test_image_whose_step_or_data_is_short_is_refused(image, shortfall, short_step):
    fields, _ = image
    row = fields['width'] * CHANNELS[fields['encoding']]
    if short_step:
        fields = {**fields, 'step': max(0, row - shortfall)}
    else:
        fields = {
            **fields,
            'data': fields['data'][: max(0, fields['step'] * fields['height'] - shortfall)],
        }
    with pytest.raises(InputError, match=r'needs step >= \d+ and step x height = \d+ bytes'):
        conversions.image_to_gray(_image(**fields))


# --- cameras ------------------------------------------------------------------------------------


@st.composite
def camera_infos(draw):
    """CameraInfo fields of a random calibrated camera (K, P with Tx, D, R)."""
    width, height = draw(st.integers(1, 4000)), draw(st.integers(1, 3000))
    fx, fy = draw(st.floats(1.0, 5000.0)), draw(st.floats(1.0, 5000.0))
    cx, cy = draw(st.floats(-100.0, width + 100.0)), draw(st.floats(-100.0, height + 100.0))
    tx = draw(st.floats(-1000.0, 0.0))
    d = draw(st.lists(st.floats(-1.0, 1.0), min_size=5, max_size=5))
    k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    p = [fx, 0.0, cx, tx, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    r = Rotation.from_rotvec(draw(st.lists(st.floats(-0.1, 0.1), min_size=3, max_size=3)))
    return {
        'width': width,
        'height': height,
        'distortion_model': 'plumb_bob',
        'd': np.array(d),
        'k': np.array(k),
        'p': np.array(p),
        'r': r.as_matrix().ravel(),
    }


def _info(**fields):
    return FACTORY.make('sensor_msgs/msg/CameraInfo', header=HEADER, **fields)


@FEW
@given(camera_infos(), st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_camera_from_any_calibrated_info_projects_with_its_p(fields, point):
    camera = conversions.camera_from_info(_info(**fields))
    assert (camera.width, camera.height) == (fields['width'], fields['height'])
    x = np.array([point[0], point[1], 2.0 + point[2]])
    homogeneous = fields['p'].reshape(3, 4) @ np.append(x, 1.0)
    np.testing.assert_allclose(camera.project(x[None])[0], homogeneous[:2] / homogeneous[2])


@FEW
@given(camera_infos(), st.sampled_from(['k', 'p', 'd', 'r']), st.integers(0, 11), NON_FINITE)
def test_camera_info_with_nan_or_inf_is_refused(fields, name, index, value):
    array = fields[name].copy()
    array[index % array.size] = value
    with pytest.raises(InputError, match='camera_info|NaN or Inf'):
        conversions.camera_from_info(_info(**{**fields, name: array}))


@FEW
@given(camera_infos(), st.sampled_from(['k', 'p', 'r']), st.integers(0, 14))
def test_camera_info_of_malformed_matrix_length_is_refused_by_name(fields, name, length):
    size = fields[name].size
    if length == size:
        length += 1
    info = SimpleNamespace(**{**fields, name: np.ones(length)})
    with pytest.raises(InputError, match=f'camera_info {name.upper()} has {length} values'):
        conversions.camera_from_info(info)


@FEW
@given(camera_infos(), st.sampled_from(['width', 'height', 'focal', 'k_focal']))
def test_camera_info_of_zero_size_or_focal_is_refused(fields, what):
    if what in ('focal', 'k_focal'):  # P's, or K's alone (P valid: the name was NaN init points)
        name = what.removesuffix('_focal') if what == 'k_focal' else 'p'
        matrix = fields[name].copy()
        matrix[0] = 0.0
        fields = {**fields, name: matrix}
    else:
        fields = {**fields, what: 0}
    with pytest.raises(
        InputError, match='invalid camera: (image size|[KP] has a focal length <= 0)'
    ):
        conversions.camera_from_info(_info(**fields))


@FEW
@given(camera_infos(), SEEDS)
def test_projection_jacobian_matches_finite_differences(fields, seed):
    camera = conversions.camera_from_info(_info(**fields))
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-0.5, 0.5, (5, 2)), rng.uniform(0.2, 5.0, 5)])
    pixels, jacobian = camera.project_with_jacobian(points)
    np.testing.assert_allclose(pixels, camera.project(points))
    h = 1e-6
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        numeric = (camera.project(points + step) - camera.project(points - step)) / (2 * h)
        np.testing.assert_allclose(jacobian[:, :, k], numeric, rtol=1e-5, atol=1e-3)


# --- finite vectors -----------------------------------------------------------------------------

FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)


@FEW
@given(st.lists(FLOATS, max_size=12), st.sampled_from(['ActionParams.alpha', 'x.y']))
def test_finite_vector_accepts_exactly_the_finite_vectors(values, field):
    if all(np.isfinite(values)):
        np.testing.assert_array_equal(conversions.finite_vector(values, field), values)
    else:
        with pytest.raises(InputError, match=f'{field} holds NaN or Inf'):
            conversions.finite_vector(values, field)


@FEW
@given(st.lists(st.floats(-1e9, 1e9), max_size=12), st.integers(0, 12))
def test_finite_vector_of_another_length_is_refused(values, length):
    if len(values) == length:
        assert conversions.finite_vector(values, 'f', length).shape == (length,)
    else:
        with pytest.raises(InputError, match=f'f has {len(values)} values, expected {length}'):
            conversions.finite_vector(values, 'f', length)


# --- face models --------------------------------------------------------------------------------


@st.composite
def face_models(draw):
    """A random valid FaceModel: 19 or 34 nodes, 1-4 identity and 1-6 expression modes."""
    num_nodes = draw(st.sampled_from([19, 34]))
    p, q = draw(st.integers(1, 4)), draw(st.integers(1, 6))
    rng = np.random.default_rng(draw(SEEDS))
    topology = mesh_topology(num_nodes)
    basis = np.linalg.qr(rng.normal(size=(3 * num_nodes, p + q)))[0]
    sigma_factor = rng.normal(scale=0.01, size=(p, p))
    alpha_factor = rng.normal(scale=0.01, size=(q, q))
    return FaceModel(
        node_names=topology.node_names,
        mean_shape=topology.reference_shape.ravel() + rng.normal(scale=1e-3, size=3 * num_nodes),
        shape_basis=basis[:, :p],
        action_basis=basis[:, p:],
        shape_eigenvalues=rng.uniform(1e-6, 1e-3, p),
        action_eigenvalues=rng.uniform(1e-6, 1e-3, q),
        sigma_prior_covariance=sigma_factor @ sigma_factor.T + 1e-8 * np.eye(p),
        alpha_prior_covariance=alpha_factor @ alpha_factor.T + 1e-8 * np.eye(q),
        method=draw(st.sampled_from(['seed', 'joint'])),
        metadata={'subjects': draw(st.lists(st.text(max_size=5), max_size=3))},
    )


@FEW
@given(face_models())
def test_model_round_trips_through_its_message(model):
    back = conversions.model_from_msg(conversions.model_to_msg(FACTORY, HEADER, model))
    assert (back.node_names, back.method, back.metadata) == (
        model.node_names,
        model.method,
        model.metadata,
    )
    for name in ARRAY_FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name))


@FEW
@given(face_models(), st.sampled_from(ARRAY_FIELDS), st.integers(0, 10_000), NON_FINITE)
def test_model_message_with_nan_or_inf_is_refused_naming_the_field(model, name, index, value):
    msg = conversions.model_to_msg(FACTORY, HEADER, model)
    array = getattr(msg, name)
    array[index % array.size] = value
    with pytest.raises(FaceTrackingError, match=f'{name} holds NaN or Inf'):
        conversions.model_from_msg(msg)


@FEW
@given(face_models(), st.sampled_from(ARRAY_FIELDS), st.integers(1, 5))
def test_model_message_of_wrong_array_length_is_refused_naming_the_field(model, name, cut):
    msg = conversions.model_to_msg(FACTORY, HEADER, model)
    setattr(msg, name, getattr(msg, name)[:-cut])
    with pytest.raises(InputError, match=f'FaceModel.{name} has \\d+ values, expected'):
        conversions.model_from_msg(msg)


@FEW
@given(face_models(), st.sampled_from(['shape_basis', 'action_basis']), st.floats(1.01, 3.0))
def test_model_with_a_non_orthonormal_basis_is_refused(model, name, scale):
    basis = getattr(model, name).copy()
    basis[:, 0] *= scale
    with pytest.raises(ModelFileError, match=f'{name} is not orthonormal'):
        replace(model, **{name: basis})


@FEW
@given(face_models(), st.sampled_from(['sigma', 'alpha']), st.booleans())
def test_model_with_an_invalid_prior_covariance_is_refused(model, which, asymmetric):
    name = f'{which}_prior_covariance'
    covariance = getattr(model, name).copy()
    if asymmetric and len(covariance) > 1:
        covariance[0, 1] += 1e-3
        problem = 'is not symmetric'
    else:
        covariance[0, 0] = -covariance[0, 0] - 1e-3
        problem = 'is not positive semi-definite'
    with pytest.raises(ModelFileError, match=f'{name} {problem}'):
        replace(model, **{name: covariance})


@FEW
@given(face_models(), st.sampled_from(['shape_eigenvalues', 'action_eigenvalues']))
def test_model_with_a_negative_variance_is_refused(model, name):
    values = getattr(model, name).copy()
    values[-1] = -1e-6
    with pytest.raises(ModelFileError, match=f'{name} holds a negative variance'):
        replace(model, **{name: values})


@FEW
@given(face_models(), st.integers(1, 40).filter(lambda n: n not in (19, 34)))
def test_model_of_another_node_count_is_refused(model, num_nodes):
    with pytest.raises(ModelFileError, match=f'node count is {num_nodes}'):
        replace(model, node_names=tuple(f'n{i}' for i in range(num_nodes)))


# --- rotations and Procrustes -------------------------------------------------------------------

OMEGAS = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)


@FEW
@given(OMEGAS)
def test_rodrigues_matches_scipy_and_its_jacobian_finite_differences(omega):
    rotation, jacobian = rodrigues(omega)
    np.testing.assert_allclose(rotation, Rotation.from_rotvec(omega).as_matrix(), atol=1e-12)
    h = 1e-6
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        numeric = (rodrigues(omega + step)[0] - rodrigues(omega - step)[0]) / (2 * h)
        np.testing.assert_allclose(jacobian[k], numeric, atol=1e-6)


@FEW
@given(
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=5).filter(
        lambda values: len(values) != 3 or not all(np.isfinite(values))
    )
)
def test_rodrigues_refuses_anything_but_a_finite_3_vector(values):
    with pytest.raises(InputError, match=r'omega must be a finite \(3,\) rotation vector'):
        rodrigues(np.array(values))


@FEW
@given(OMEGAS, st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3), SEEDS, st.integers(3, 34))
def test_rigid_align_recovers_a_random_rigid_motion(omega, t, seed, num_nodes):
    rng = np.random.default_rng(seed)
    source = rng.normal(scale=0.05, size=(num_nodes, 3))
    rotation = Rotation.from_rotvec(omega).as_matrix()
    target = source @ rotation.T + np.array(t)
    weights = rng.uniform(0.1, 1.0, num_nodes)
    alignment = rigid_align(source, target, weights)
    np.testing.assert_allclose(alignment.rotation, rotation, atol=1e-8)
    np.testing.assert_allclose(alignment.t, t, atol=1e-8)
    assert alignment.rms < 1e-9


@FEW
@given(SEEDS, st.sampled_from(['source', 'target']), st.integers(0, 29), NON_FINITE)
def test_rigid_align_refuses_non_finite_meshes(seed, which, index, value):
    meshes = {'source': np.random.default_rng(seed).normal(size=(10, 3))}
    meshes['target'] = meshes['source'] + 1.0
    meshes[which].flat[index] = value
    with pytest.raises(InputError, match=f'{which} holds NaN or Inf'):
        rigid_align(meshes['source'], meshes['target'])


@FEW
@given(SEEDS, st.integers(0, 2))
def test_rigid_align_refuses_fewer_than_three_weighted_nodes(seed, positive):
    source = np.random.default_rng(seed).normal(size=(6, 3))
    weights = np.zeros(6)
    weights[:positive] = 1.0
    with pytest.raises(InputError, match='at least 3 nodes a positive weight'):
        rigid_align(source, source, weights)


@FEW
@given(camera_infos(), st.integers(1, 4), st.integers(1, 4))
def test_a_binning_camera_s_calibration_is_scaled_to_its_images(fields, binning_x, binning_y):
    """A camera binning pixels sends images that much smaller than its calibration's size.

    It was refused: the image size did not match camera_info's.
    """
    fields = {**fields, 'width': 4 * fields['width'], 'height': 4 * fields['height']}
    full = conversions.camera_from_info(_info(**fields))
    binned = conversions.camera_from_info(
        _info(**fields, binning_x=binning_x, binning_y=binning_y)
    )
    sizes = (fields['width'] // binning_x, fields['height'] // binning_y)
    assert (binned.width, binned.height) == sizes
    point = np.array([[0.1, -0.05, 2.0]])
    expected = full.project(point) / [binning_x, binning_y]
    np.testing.assert_allclose(binned.project(point), expected, rtol=1e-9)
    np.testing.assert_array_equal(binned.d, full.d)


@FEW
@given(camera_infos())
def test_a_camera_info_with_a_region_of_interest_is_refused_by_name(fields):
    roi = FACTORY.make(
        'sensor_msgs/msg/RegionOfInterest',
        x_offset=10,
        y_offset=20,
        height=100,
        width=200,
        do_rectify=False,
    )
    with pytest.raises(InputError, match=r'region of interest \(200x100 at 10, 20\): not supp'):
        conversions.camera_from_info(_info(**fields, roi=roi))
    whole = FACTORY.make(  # as many drivers fill it: the whole image, which is no cropping
        'sensor_msgs/msg/RegionOfInterest',
        x_offset=0,
        y_offset=0,
        height=fields['height'],
        width=fields['width'],
        do_rectify=False,
    )
    camera = conversions.camera_from_info(_info(**fields, roi=whole))
    assert (camera.width, camera.height) == (fields['width'], fields['height'])
