"""The optional dlib landmark detector: a clear error without dlib, a detection with it."""

from __future__ import annotations

import importlib.util
import sys
import types

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


def test_bad_upsampling_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match='upsample = 3'):
        DetectorConfig(upsample=3)


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
