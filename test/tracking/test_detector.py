"""The optional dlib landmark detector: a clear error without dlib, a detection with it.

Without dlib, a stand-in module gives the detector the landmarks of the iBUG 300-W convention, so
its mapping to the mesh nodes is checked all the same.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from typing import NamedTuple

import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.tracking.detector import (
    IBUG68_TO_NODES,
    DetectorConfig,
    DlibLandmarkDetector,
)


def test_every_mapped_landmark_names_a_mesh_node() -> None:
    names = set(mesh_topology(34).node_names)
    assert set(IBUG68_TO_NODES) <= names
    assert all(0 <= i < 68 for indices in IBUG68_TO_NODES.values() for i in indices)


def test_missing_dlib_says_how_to_install_it(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, 'dlib', None)
    with pytest.raises(ConfigError, match='pip install dlib-bin face_recognition_models'):
        DlibLandmarkDetector(mesh_topology(34).node_names)


def test_missing_landmark_model_says_how_to_install_it(monkeypatch) -> None:
    fake_dlib = types.SimpleNamespace(shape_predictor=None, get_frontal_face_detector=None)
    monkeypatch.setitem(sys.modules, 'dlib', fake_dlib)
    monkeypatch.setattr(importlib.util, 'find_spec', lambda name: None)
    with pytest.raises(ConfigError, match="needs 'face_recognition_models' .the landmark model"):
        DlibLandmarkDetector(mesh_topology(34).node_names)


def test_the_packaged_landmark_model_is_found_without_importing_its_package(monkeypatch) -> None:
    site = types.SimpleNamespace(submodule_search_locations=['/site/face_recognition_models'])
    monkeypatch.setattr(importlib.util, 'find_spec', lambda name: site)
    log: list[object] = []
    monkeypatch.setitem(sys.modules, 'dlib', _stand_in_dlib({}, log))
    DlibLandmarkDetector(mesh_topology(34).node_names)
    assert log == ['/site/face_recognition_models/models/shape_predictor_68_face_landmarks.dat']


def test_bad_upsampling_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match='upsample = 3'):
        DetectorConfig(upsample=3)


# What the iBUG 300-W 68 points (0-based) mark: 8 chin; 17-21 the right brow from its outer end,
# 22-26 the left from its inner end; 30 nose tip, 31 / 35 the right / left nostril wing; 36 / 39
# the right eye's outer / inner corner, 42 / 45 the left eye's inner / outer corner (37-38,
# 40-41 and 43-44, 46-47 their lids); 48 / 54 the right / left mouth corner, 49-53 the upper
# lip and 55-59 the lower lip, each running from right to left and back.
CONVENTION = {
    8: 'chin',
    17: 'right_brow_outer',
    19: 'right_brow_middle',
    21: 'right_brow_inner',
    22: 'left_brow_inner',
    24: 'left_brow_middle',
    26: 'left_brow_outer',
    30: 'nose_tip',
    31: 'nose_right',
    35: 'nose_left',
    36: 'right_eye_outer',
    39: 'right_eye_inner',
    42: 'left_eye_inner',
    45: 'left_eye_outer',
    48: 'mouth_right',
    50: 'upper_lip_right',
    51: 'upper_lip',
    52: 'upper_lip_left',
    54: 'mouth_left',
    56: 'lower_lip_left',
    57: 'lower_lip',
    58: 'lower_lip_right',
}
EYES = {'right_eye': (36, 39, (37, 38), (41, 40)), 'left_eye': (42, 45, (43, 44), (47, 46))}


def _landmarks() -> np.ndarray:
    """(68, 2) landmarks of the 34-node reference face 0.5 m in front of a 600 px camera.

    Each point the convention names sits at its node's pixel; each eye's lids 3 px above and
    below its corners' line, so the eye's six points average to its corners' midpoint. The
    other points (jaw, nose bridge, inner lips) lie far off the face: no node is made of them.
    """
    topology = mesh_topology(34)
    shape = topology.reference_shape
    pixels = 600.0 * shape[:, :2] / (0.5 + shape[:, 2:]) + [319.5, 239.5]
    points = 1000.0 + np.arange(136.0).reshape(68, 2)
    for index, name in CONVENTION.items():
        points[index] = pixels[topology.index(name)]
    for first, last, upper, lower in EYES.values():
        for fraction, above, below in zip((1 / 3, 2 / 3), upper, lower, strict=True):
            on_line = points[first] + fraction * (points[last] - points[first])
            points[above], points[below] = on_line - [0.0, 3.0], on_line + [0.0, 3.0]
    return points


class _Box(NamedTuple):
    """A dlib face rectangle."""

    w: int
    h: int

    def width(self) -> int:
        return self.w

    def height(self) -> int:
        return self.h


def _stand_in_dlib(faces: dict[_Box, np.ndarray], log: list[object]) -> types.SimpleNamespace:
    """A dlib module finding ``faces`` (box -> (68, 2) landmarks), logging what it is given."""

    def detect(gray: np.ndarray, upsample: int) -> list[_Box]:
        log.append(upsample)
        return list(faces)

    def predictor(path: str):
        log.append(path)

        def shape(gray: np.ndarray, box: _Box) -> types.SimpleNamespace:
            points = faces[box]
            return types.SimpleNamespace(
                part=lambda i: types.SimpleNamespace(x=points[i, 0], y=points[i, 1])
            )

        return shape

    return types.SimpleNamespace(
        shape_predictor=predictor, get_frontal_face_detector=lambda: detect
    )


def test_the_largest_face_s_landmarks_become_the_nodes_the_ibug_convention_names(
    monkeypatch,
) -> None:
    landmarks, log = _landmarks(), []
    faces = {
        _Box(60, 60): landmarks + 40,
        _Box(150, 160): landmarks,
        _Box(140, 140): landmarks - 40,
    }
    monkeypatch.setitem(sys.modules, 'dlib', _stand_in_dlib(faces, log))
    names = mesh_topology(34).node_names
    detector = DlibLandmarkDetector(names, DetectorConfig(predictor_path='stand-in', upsample=1))

    init = detector(np.zeros((480, 640), np.uint8))

    expected = {name: landmarks[index] for index, name in CONVENTION.items()}
    for eye, (first, last, _, _) in EYES.items():
        expected[eye] = (landmarks[first] + landmarks[last]) / 2
    assert init.node_names == tuple(name for name in names if name in expected)
    np.testing.assert_allclose(init.points, [expected[n] for n in init.node_names], atol=1e-12)
    assert log == ['stand-in', 1]
    inner = detector.for_nodes(mesh_topology(19).node_names)(np.zeros((480, 640), np.uint8))
    assert inner.node_names == mesh_topology(19).node_names  # every inner node has landmarks
    with pytest.raises(ConfigError, match='only 2 of the model nodes have dlib landmarks'):
        detector.for_nodes(('right_eye', 'chin', 'forehead'))
    with pytest.raises(InputError, match=r'uint8 grey image, got \(4, 4, 3\)'):
        detector.landmarks(np.zeros((4, 4, 3), np.uint8))
    monkeypatch.setitem(sys.modules, 'dlib', _stand_in_dlib({}, log))
    no_face = DlibLandmarkDetector(names, DetectorConfig(predictor_path='stand-in'))
    assert no_face(np.zeros((480, 640), np.uint8)) is None


def test_detects_a_synthetic_face_near_the_true_nodes() -> None:
    pytest.importorskip('dlib')
    if importlib.util.find_spec('face_recognition_models') is None:
        pytest.skip('the optional landmark model (face_recognition_models) is not installed')
    from face_tracking_ros.synthetic.scenes import SceneConfig, SequenceRenderer

    config = SceneConfig(kind='mono', subjects=10, frames=1, fps=30.0, motion='free')
    frame = next(SequenceRenderer(config, 9).frames(0))
    detector = DlibLandmarkDetector(mesh_topology(34).node_names)
    init = detector(frame.images['image'])
    assert init is not None and len(init.node_names) == len(IBUG68_TO_NODES)
    true_px = config.cameras()['image'].project(frame.truth.nodes_camera)
    indices = [mesh_topology(34).index(name) for name in init.node_names]
    assert np.median(np.linalg.norm(init.points - true_px[indices], axis=1)) < 8.0
    assert detector(np.full((480, 640), 128, np.uint8)) is None
    inner = detector.for_nodes(mesh_topology(19).node_names)  # dlib's models shared
    assert set(inner(frame.images['image']).node_names) == set(IBUG68_TO_NODES) & set(
        mesh_topology(19).node_names
    )
    with pytest.raises(ConfigError, match='only 2 of the model nodes have dlib landmarks'):
        detector.for_nodes(('right_eye', 'chin', 'forehead'))
    with pytest.raises(InputError, match='uint8 grey image'):
        detector.landmarks(np.zeros((4, 4, 3), np.uint8))
