"""Tests of the synthetic renderer: truth nodes land on their features; occlusion; noise."""

from __future__ import annotations

from dataclasses import replace
import json

import cv2
import numpy as np
import pytest

from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.geometry.camera import PinholeCamera, StereoRig
from face_tracking_ros.geometry.rotation import angles_to_omega
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.background import Backdrop
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.render import FacePose, FaceRenderer, Lighting, Occluder, Sensor
from face_tracking_ros.synthetic.texture import (
    atlas_from_rgb,
    atlas_uv,
    load_photo_texture,
    photo_texture,
)

PERIOD_MM = 16.0  # period of the phase textures
CLEAN = Sensor(blur_sigma=0.0, read_noise=0.0, shot_noise=0.0)
FLAT = Lighting(ambient=1.0, diffuse=0.0, specular=0.0, colour=np.ones(3))
REFERENCE_UV_MM = 1000.0 * mesh_topology(34).reference_shape[:, :2]
# Node placement is measured on 4x finer renders (same scene, focal and size times 4): a bilinear
# read of the image at a node mixes the four pixels around it, which at 1x straddle the crease
# of a strongly curved surface (chin, lips, nose tip) and bias the read by up to a pixel. Errors
# are reported in pixels of the 1x camera.
FINE = 4
CAMERA = PinholeCamera.ideal(640 * FINE, 480 * FINE, 600.0 * FINE)
POPULATION = FacePopulation('realistic', seed=1)
MODERATE_POSES = [  # (pitch, yaw, roll) in degrees, expression weights
    ((0.0, 0.0, 0.0), {}),
    ((10.0, 20.0, 5.0), {'smile': 1.0}),
    ((-12.0, -15.0, -10.0), {'jaw_open': 1.0, 'brow_raise': 0.7}),
    ((8.0, 10.0, 15.0), {'pucker': 0.8}),
]
EXTREME_POSES = [
    ((15.0, 35.0, 10.0), {'smile': 1.0}),
    ((-20.0, -30.0, -20.0), {'surprise': 1.0}),
    ((25.0, 10.0, 20.0), {'pucker': 1.0}),
]
# Nodes on sharp texture features away from depth edges: eyes, eye corners, brows, mouth
# corners, nostril wings. (At large angles the nose tip, protruding lips and the chin sit on the
# face's own occluding contour, where a bilinear read of the image mixes two surfaces.)
FEATURE_NODES = [
    mesh_topology(34).index(name)
    for name in mesh_topology(34).node_names
    if 'eye' in name
    or 'brow' in name
    or name in ('mouth_left', 'mouth_right')
    or name in ('nose_left', 'nose_right')
]


def _phase_atlases(u: np.ndarray, v: np.ndarray) -> list:
    """Four mono atlases encoding (u, v) as sin/cos phases of period PERIOD_MM."""
    waves = []
    for coordinate in (u, v):
        phase = 2 * np.pi * coordinate / PERIOD_MM
        waves += [np.sin(phase), np.cos(phase)]
    return [
        atlas_from_rgb(np.repeat((0.5 + 0.4 * w)[..., None], 3, axis=2), 'mono8') for w in waves
    ]


@pytest.fixture(scope='module')
def phase_renderers() -> list[FaceRenderer]:
    return [FaceRenderer(atlas, CLEAN) for atlas in _phase_atlases(*atlas_uv())]


def _decoded_uv(renderers, camera, pose, background) -> np.ndarray:
    """(34, 2) uv (mm, modulo the period) rendered at the projections of the truth nodes."""
    pixels = camera.project(pose.camera_nodes()).astype(np.float32)
    samples = []
    for renderer in renderers:
        image = renderer.render(camera, [pose], background, FLAT).astype(np.float32)
        sample = cv2.remap(image, pixels[None, :, 0], pixels[None, :, 1], cv2.INTER_LINEAR)[0]
        samples.append((sample / 255.0 - 0.5) / 0.4)
    return np.stack([np.arctan2(samples[0], samples[1]), np.arctan2(samples[2], samples[3])], 1)


def _node_errors_px(renderers, camera, pose) -> tuple[np.ndarray, np.ndarray]:
    """Distance (px) between each node's projection and where its texture point was rendered."""
    background = np.zeros((camera.height, camera.width), np.float32)
    decoded = _decoded_uv(renderers, camera, pose, background)
    expected = 2 * np.pi * REFERENCE_UV_MM / PERIOD_MM
    error_mm = np.angle(np.exp(1j * (decoded - expected))) * PERIOD_MM / (2 * np.pi)
    depth_mm = 1000.0 * (pose.camera_nodes()[:, 2])
    error_px = np.linalg.norm(error_mm, axis=1) * camera.focal / depth_mm / FINE
    return error_px, renderers[0].visible_nodes(camera, pose)


def _pose(angles_deg, weights, t=(0.02, 0.0, 0.55), subject=3) -> FacePose:
    nodes = POPULATION.nodes(POPULATION.subject(subject), weights)
    return FacePose(nodes, angles_to_omega(np.radians(angles_deg)), np.array(t))


@pytest.mark.parametrize(('angles', 'weights'), MODERATE_POSES)
def test_truth_nodes_land_on_their_rendered_texture_points(phase_renderers, angles, weights):
    error_px, visible = _node_errors_px(phase_renderers, CAMERA, _pose(angles, weights))
    assert visible.sum() >= 28
    assert np.max(error_px[visible]) < 0.5
    assert np.median(error_px[visible]) < 0.05


@pytest.mark.parametrize(('angles', 'weights'), EXTREME_POSES)
def test_feature_nodes_land_on_their_features_at_large_angles(phase_renderers, angles, weights):
    error_px, visible = _node_errors_px(phase_renderers, CAMERA, _pose(angles, weights))
    checked = [node for node in FEATURE_NODES if visible[node]]
    assert len(checked) >= 10
    assert np.max(error_px[checked]) < 0.5
    assert np.max(error_px[visible]) < 1.0


def test_truth_nodes_land_on_features_in_the_right_camera_of_a_rig(phase_renderers):
    rig = StereoRig.ideal(640 * FINE, 480 * FINE, 600.0 * FINE, baseline=0.11)
    pose = _pose((5.0, 15.0, 0.0), {'smile': 0.6}, t=(0.055, 0.0, 0.6))
    error_px, visible = _node_errors_px(phase_renderers, rig.right, pose)
    assert visible.sum() >= 28
    assert np.max(error_px[visible]) < 0.5


def test_distorted_camera_shows_nodes_at_their_distorted_projections(phase_renderers):
    """With plumb_bob D the image is raw: a node appears where cv2.projectPoints puts it."""
    distortion = np.array([-0.28, 0.09, 0.001, -0.001, 0.0])
    camera = replace(CAMERA, d=distortion)
    pose = _pose((5.0, -15.0, 5.0), {'smile': 0.7}, t=(0.1, 0.05, 0.55))
    nodes = pose.camera_nodes()
    raw, _ = cv2.projectPoints(nodes, np.zeros(3), np.zeros(3), camera.k, distortion)
    raw = raw.reshape(-1, 2).astype(np.float32)
    images = [
        r.render(camera, [pose], np.zeros((camera.height, camera.width), np.float32), FLAT)
        for r in phase_renderers
    ]
    samples = [
        (cv2.remap(im.astype(np.float32), raw[None, :, 0], raw[None, :, 1], cv2.INTER_LINEAR)[0]
         / 255.0 - 0.5) / 0.4
        for im in images
    ]  # fmt: skip
    decoded = np.stack(
        [np.arctan2(samples[0], samples[1]), np.arctan2(samples[2], samples[3])], axis=1
    )
    expected = 2 * np.pi * REFERENCE_UV_MM / PERIOD_MM
    error_mm = np.angle(np.exp(1j * (decoded - expected))) * PERIOD_MM / (2 * np.pi)
    error_px = np.linalg.norm(error_mm, axis=1) * camera.focal / (1000.0 * nodes[:, 2]) / FINE
    visible = phase_renderers[0].visible_nodes(CAMERA, pose)
    checked = [node for node in FEATURE_NODES if visible[node]]
    assert len(checked) >= 12
    assert np.max(error_px[checked]) < 0.5  # the raw image is the rendered one resampled once,
    assert np.max(error_px[visible]) < 1.0  # so contour nodes read a little worse
    rectified = cv2.remap(images[0], *camera.rectify_maps(), cv2.INTER_LINEAR)
    ideal = phase_renderers[0].render(CAMERA, [pose], np.zeros_like(rectified, np.float32), FLAT)
    face = ideal > 0
    assert np.mean(np.abs(rectified[face].astype(float) - ideal[face])) < 2.0


def test_large_yaw_hides_the_far_face_edge_and_shows_the_near_one(phase_renderers):
    topology = mesh_topology(34)
    pose = _pose((0.0, 35.0, 0.0), {})  # turned towards image left: the subject's right is far
    visible = phase_renderers[0].visible_nodes(PinholeCamera.ideal(), pose)
    far = [topology.index(n) for n in ('right_cheek_upper', 'right_cheek_lower', 'right_jaw')]
    near = [topology.index(n) for n in ('left_cheek_upper', 'left_cheek_lower', 'left_jaw')]
    assert not visible[far].any()
    assert visible[near].all()


@pytest.mark.parametrize(('encoding', 'channels'), [('mono8', ()), ('rgb8', (3,))])
def test_render_without_noise_is_deterministic_and_noise_has_the_sensor_std(encoding, channels):
    atlas = atlas_from_rgb(np.full((*atlas_uv()[0].shape, 3), 0.5, np.float32), encoding)
    sensor = Sensor(blur_sigma=0.0, read_noise=2.0, shot_noise=0.05)
    renderer = FaceRenderer(atlas, sensor, seed=4)
    camera = PinholeCamera.ideal()
    background = np.full((480, 640, *channels), 100.0, np.float32)
    pose = _pose((0, 0, 0), {})
    first = renderer.render(camera, [pose], background, FLAT)
    np.testing.assert_array_equal(first, renderer.render(camera, [pose], background, FLAT))
    noisy = renderer.render(camera, [pose], background, FLAT, rng=np.random.default_rng(0))
    corner = noisy[:100, :100].astype(float)
    assert np.abs(corner.mean() - 100.0) < 0.3
    assert corner.std() == pytest.approx(np.sqrt(2.0**2 + 0.05 * 100.0 + 1 / 12), rel=0.05)
    again = renderer.render(camera, [pose], background, FLAT, rng=np.random.default_rng(0))
    np.testing.assert_array_equal(noisy, again)
    if channels:  # each colour channel has its own noise
        red, green, blue = (corner[..., k].ravel() for k in range(3))
        assert (
            abs(np.corrcoef(red, green)[0, 1]) < 0.05 and abs(np.corrcoef(red, blue)[0, 1]) < 0.05
        )


def test_motion_blur_of_a_still_face_is_the_sharp_image_and_smears_a_moving_one(phase_renderers):
    renderer, camera = phase_renderers[0], PinholeCamera.ideal()
    background = np.zeros((480, 640), np.float32)
    pose = _pose((0, 0, 0), {})
    sharp = renderer.render(camera, [pose], background, FLAT)
    np.testing.assert_array_equal(renderer.render(camera, [pose] * 3, background, FLAT), sharp)
    moving = [FacePose(pose.nodes, pose.omega, pose.t + [dx, 0, 0]) for dx in (-0.006, 0, 0.006)]
    blurred = renderer.render(camera, moving, background, FLAT).astype(float)
    gradient = np.abs(np.diff(blurred, axis=1)).mean()
    assert gradient < 0.8 * np.abs(np.diff(sharp.astype(float), axis=1)).mean()


def test_occluder_covers_the_face():
    atlas = atlas_from_rgb(np.full((*atlas_uv()[0].shape, 3), 0.8, np.float32), 'rgb8')
    renderer = FaceRenderer(atlas, CLEAN)
    camera = PinholeCamera.ideal()
    background = np.zeros((480, 640, 3), np.float32)
    pose = _pose((0, 0, 0), {})
    centre = camera.project(pose.camera_nodes()[[2]])[0]
    occluder = Occluder(
        (float(centre[0]), float(centre[1])), (30.0, 20.0), 0.0, (20.0, 40.0, 200.0)
    )
    image = renderer.render(camera, [pose], background, FLAT, occluders=[occluder])
    patch = image[int(centre[1]) - 5 : int(centre[1]) + 5, int(centre[0]) - 5 : int(centre[0]) + 5]
    assert np.all(np.abs(patch.reshape(-1, 3).mean(axis=0) - [20, 40, 200]) < 30)
    assert image.shape == (480, 640, 3) and image.dtype == np.uint8


def test_render_rejects_bad_input(phase_renderers):
    renderer, camera = phase_renderers[0], PinholeCamera.ideal()
    background = np.zeros((480, 640), np.float32)
    pose = _pose((0, 0, 0), {})
    with pytest.raises(InputError, match='at least one face pose'):
        renderer.render(camera, [], background)
    with pytest.raises(InputError, match=r'background has shape \(10, 10\)'):
        renderer.render(camera, [pose], np.zeros((10, 10), np.float32))
    behind = FacePose(pose.nodes, pose.omega, np.array([0.0, 0.0, -0.5]))
    with pytest.raises(InputError, match='behind or too close'):
        renderer.render(camera, [behind], background)


def test_backdrop_shows_true_disparity_in_the_right_camera():
    rig = StereoRig.ideal(baseline=0.11)
    backdrop = Backdrop.cluttered(640, 480, seed=5, depth=2.2)
    left, right = backdrop.view(rig.left, 'mono8'), backdrop.view(rig.right, 'mono8')
    shift = round(600.0 * 0.11 / 2.2)  # focal * baseline / depth = 30 px
    np.testing.assert_allclose(right[:, 100:600], left[:, 100 + shift : 600 + shift], atol=1e-3)
    with pytest.raises(ConfigError, match='positive size and depth'):
        Backdrop.cluttered(640, 480, seed=5, depth=0.0)


def test_photo_texture_maps_photo_features_onto_the_nodes(tmp_path, phase_renderers):
    """A frontal render of the phase textures, used as a photo, puts each node's phase back.

    The photo is rendered at twice the 1x resolution: from the front the jaw is seen at a grazing
    angle and, at 1x, spans so few photo pixels that the texture there is off by 0.5 px.
    """
    camera = PinholeCamera.ideal(640 * 2, 480 * 2, 600.0 * 2)
    frontal = _pose((0, 0, 0), {}, subject=0)
    background = np.zeros((camera.height, camera.width), np.float32)
    pixels = camera.project(frontal.camera_nodes())
    node_pixels = dict(zip(mesh_topology(34).node_names, pixels.tolist(), strict=True))
    photos = [r.render(camera, [frontal], background, FLAT) for r in phase_renderers]
    renderers = [FaceRenderer(photo_texture(photo, node_pixels), CLEAN) for photo in photos]
    error_px, visible = _node_errors_px(renderers, CAMERA, _pose((5, 20, 0), {'smile': 0.5}))
    assert np.max(error_px[visible]) < 0.5
    cv2.imwrite(str(tmp_path / 'photo.png'), photos[0])
    (tmp_path / 'nodes.json').write_text(json.dumps(node_pixels))
    loaded = load_photo_texture(tmp_path / 'photo.png', tmp_path / 'nodes.json')
    assert loaded.encoding == 'mono8' and loaded.levels[0].shape == atlas_uv()[0].shape


def test_a_texture_file_that_is_a_directory_is_named_so(tmp_path, capsys):
    """It said 'texture_nodes file not found: /tmp'."""
    photo = tmp_path / 'photo.png'
    cv2.imwrite(str(photo), np.zeros((100, 100), np.uint8))
    synth = ['synth', '--out', str(tmp_path / 'bags'), '--texture']
    assert main([*synth, str(photo), '--texture-nodes', str(tmp_path)]) == 2
    assert (
        capsys.readouterr().err == f'error: texture_nodes {tmp_path} is a directory, not a file\n'
    )
    with pytest.raises(ConfigError, match=f'^texture node positions {tmp_path} is a directory'):
        load_photo_texture(photo, tmp_path)
    assert not (tmp_path / 'bags').exists()


def test_photo_texture_errors_name_the_problem(tmp_path):
    photo = np.zeros((100, 100), np.uint8)
    few = {'right_eye': (30, 40), 'left_eye': (70, 40), 'nose_tip': (50, 60)}
    with pytest.raises(ConfigError, match='at least 10 nodes'):
        photo_texture(photo, few)
    with pytest.raises(ConfigError, match='unknown node ear; known: '):
        photo_texture(photo, {**few, 'ear': (0, 0)})
    with pytest.raises(ConfigError, match='texture photo file not found'):
        load_photo_texture(tmp_path / 'missing.png', tmp_path / 'missing.json')
    cv2.imwrite(str(tmp_path / 'photo.png'), photo)
    (tmp_path / 'nodes.json').write_text('[1, 2]')
    with pytest.raises(ConfigError, match='must be a JSON object'):
        load_photo_texture(tmp_path / 'photo.png', tmp_path / 'nodes.json')
    # An integer past float's range crashed with OverflowError; a third value and a node given
    # twice (the last kept) were taken without a word
    for text, problem in (
        (json.dumps(few)[:-1] + f', "chin": [{10**400}, 50]}}', 'must be \\[x, y\\]'),
        (json.dumps({**few, 'chin': (50, 50, 7)}), 'must be \\[x, y\\]'),
        (json.dumps(few)[:-1] + ', "nose_tip": [1, 2]}', "key 'nose_tip' given twice"),
        ('[1, 2]', 'got a JSON list'),
    ):
        (tmp_path / 'nodes.json').write_text(text)
        with pytest.raises(ConfigError, match=f'must be a JSON object .*{problem}'):
            load_photo_texture(tmp_path / 'photo.png', tmp_path / 'nodes.json')
    for bad in (float('nan'), 1e6):  # these hung the renderer inside OpenCV
        (tmp_path / 'nodes.json').write_text(json.dumps({**few, 'chin': (bad, 50)}))
        with pytest.raises(ConfigError, match='node chin not inside the 100x100 photo'):
            load_photo_texture(tmp_path / 'photo.png', tmp_path / 'nodes.json')
    with pytest.raises(ConfigError, match="unknown image encoding 'bgr8'"):
        photo_texture(photo, few, encoding='bgr8')


def test_shading_is_lambert_plus_a_narrow_blinn_phong_highlight(phase_renderers):
    renderer = phase_renderers[0]
    vertices = renderer.surface.vertices(mesh_topology(34).reference_shape) + [0.0, 0.0, 0.6]
    light = Lighting()  # ambient 0.38, diffuse 0.72, specular 0.10, shininess 24
    diffuse, highlight = renderer._shading(vertices, light)
    # Lambert: ambient where the light does not reach, up to ambient + diffuse facing it.
    assert diffuse.min() == pytest.approx(0.38) and 1.05 < diffuse.max() <= 0.38 + 0.72 + 1e-6
    np.testing.assert_array_equal(highlight[diffuse <= 0.38 + 1e-7], 0.0)
    # Blinn-Phong (n.h)^24: full strength near the mirror direction only.
    lit = highlight[highlight > 0]
    assert 0.09 < lit.max() <= 0.10 + 1e-7
    assert np.median(lit) < 0.005 and np.mean(lit > 0.05) < 0.15  # within 14 deg of h only
