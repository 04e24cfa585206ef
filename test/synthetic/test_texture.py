"""Tests of the subjects' appearance (texture.py): natural skin, lip and stubble colours."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.texture import (
    ATLAS_MM_PER_PX,
    ATLAS_ORIGIN,
    Appearance,
    procedural_texture,
)


def test_appearances_span_light_to_dark_skin_with_redder_lips_and_some_beards():
    appearances = [Appearance.from_seed(seed) for seed in range(200)]
    skin = np.array([a.skin for a in appearances])
    lips = np.array([a.lips for a in appearances])
    # skin between the dark (0.36, 0.23, 0.16) and light (0.86, 0.68, 0.58) tones, +- noise
    assert np.all((skin > [0.28, 0.15, 0.08]) & (skin < [0.94, 0.76, 0.66]))
    assert skin[:, 0].min() < 0.42 and skin[:, 0].max() > 0.80
    # lips: the skin times (0.92, 0.6, 0.62), redder and darker than it
    assert np.all(lips[:, 0] / lips[:, 2] > skin[:, 0] / skin[:, 2])
    assert np.all(lips <= skin + 1e-12)
    bearded = np.array([a.stubble > 0 for a in appearances])
    assert 0.3 < bearded.mean() < 0.5  # 40 % of the subjects
    assert all(0.3 <= a.stubble <= 1.0 for a in appearances if a.stubble)


def test_procedural_features_are_dark_at_their_nodes_uv():
    topology = mesh_topology(34)
    reference_mm = 1000.0 * topology.reference_shape
    features = ['right_eye', 'left_eye']
    features += ['mouth_right', 'mouth_left']
    ring = 6.0 * np.array([(np.cos(a), np.sin(a)) for a in np.linspace(0, 2 * np.pi, 16)[:-1]])
    for seed in range(4):
        atlas = procedural_texture(seed, 'mono8').levels[0].astype(float)

        def grey(uv: np.ndarray, atlas: np.ndarray = atlas) -> np.ndarray:
            col, row = np.round((uv - ATLAS_ORIGIN) / ATLAS_MM_PER_PX).astype(int).T
            return atlas[row, col]

        for name in features:
            uv = reference_mm[topology.index(name), :2]
            around = np.median(grey(uv + ring))
            assert grey(uv[None])[0] < 0.75 * around, (seed, name)  # pupils, mouth corners
