"""The mono tracker's drift check: eq. 6 against the keyframe alone (mono_loss._drift_ratio)."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.imaging.photometric import PhotometricInvariance, PhotometricModel
from face_tracking_ros.model.topology import Group, mesh_topology
from face_tracking_ros.tracking.mono_loss import _drift_ratio, covered_nodes
from face_tracking_ros.tracking.mono_rois import Params
from face_tracking_ros.tracking.mono_templates import Keyframe, Templates

GRID = np.stack(np.meshgrid(np.arange(3.0), np.arange(3.0)), axis=-1).reshape(-1, 2)  # M = 9
# A pattern with no part in a patch's bias: zero mean over the patch.
PATTERN = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 0.0])


def _keyframe(template: np.ndarray, visibility: np.ndarray) -> Keyframe:
    """A keyframe of (N, 9) level-0 templates under the BIAS model."""
    invariance = PhotometricInvariance.of(PhotometricModel.BIAS, GRID)
    zeros = np.zeros(3)
    templates = Templates(
        levels=[template],
        visibility=visibility,
        inside=np.ones(template.shape, dtype=bool),
        params=Params(omega=zeros, t=zeros, alpha=np.zeros(1), sigma=np.zeros(1)),
        covered=np.zeros(len(template), dtype=bool),
    )
    return Keyframe(np.eye(3), templates, invariance.projection(template))


def test_drift_ratio_is_the_median_residual_over_texture_ignoring_brightness() -> None:
    template = np.outer([10.0, 20.0, 30.0], np.arange(9.0))
    keyframe = _keyframe(template, np.ones(3))
    # Node i: the template brightened by 5 (ignored) plus a_i times the pattern.
    amplitude = np.array([0.0, 2.0, 6.0])
    samples = template + 5.0 + amplitude[:, None] * PATTERN
    texture = np.array([1.0, 1.0, 2.0])
    rms = amplitude * np.sqrt(np.mean(PATTERN**2))  # the pattern has no bias to project out

    ratio = _drift_ratio(keyframe, samples, texture, np.ones(3, dtype=bool))

    assert ratio == np.median(rms / texture)  # 0, 1.89 and 2.83: the middle one
    assert np.isclose(ratio, 2.0 * np.sqrt(8 / 9))


def test_drift_ratio_counts_only_nodes_the_keyframe_sees() -> None:
    template = np.outer([10.0, 20.0, 30.0], np.arange(9.0))
    samples = template + np.array([50.0, 1.0, 1.0])[:, None] * PATTERN
    texture = np.ones(3)
    textured = np.array([True, True, False])

    hidden_first = _drift_ratio(
        _keyframe(template, np.array([0.0, 1.0, 1.0])), samples, texture, textured
    )
    none_seen = _drift_ratio(
        _keyframe(template, np.array([0.0, 0.0, 1.0])), samples, texture, textured
    )

    assert np.isclose(hidden_first, np.sqrt(8 / 9))  # node 1 alone: node 0's 50 is not counted
    assert none_seen == 0.0  # no textured node the keyframe sees: no evidence of drift


def _covered(
    ratios: np.ndarray, before: np.ndarray | None = None, expired: np.ndarray | None = None
) -> set[int]:
    """The 34-node mesh's nodes :func:`covered_nodes` gives at ratio 0.5, all visible."""
    topology = mesh_topology(34)
    before = np.zeros(34, dtype=bool) if before is None else before
    inner = ~topology.group_mask(Group.EDGE)
    visible = np.ones(34, dtype=bool)
    expired = np.zeros(34, dtype=bool) if expired is None else expired
    covered = covered_nodes(ratios, visible, inner, before, 0.5, topology.edges, expired)
    return set(np.flatnonzero(covered))


def test_an_occluder_covers_the_nodes_that_fail_together_while_the_rest_fit() -> None:
    """The right eye and its neighbours fail (0.9), the other nodes fit (0.1)."""
    topology = mesh_topology(34)
    ratios = np.full(34, 0.1)
    eye = [topology.index(n) for n in ('right_eye', 'right_eye_outer', 'right_brow_middle')]
    temple = topology.index('right_temple')  # a face-edge node next to the eye
    jaw = topology.index('left_jaw')  # a face-edge node next to no failing node
    ratios[[*eye, temple, jaw]] = 0.9
    assert _covered(ratios) == {*eye, temple}
    # A single inner node failing, or two, starts no cover: their shading changes as the head
    # turns, or the mouth's with the expression.
    assert _covered(np.where(np.isin(np.arange(34), eye[:2]), 0.9, 0.1)) == set()


def test_a_change_of_light_covers_nothing() -> None:
    """Every node fits worse (0.3-0.8 of the texture): none is 3 x the lower quartile."""
    ratios = np.linspace(0.3, 0.8, 34)
    assert _covered(ratios) == set()


def test_a_covered_node_is_uncovered_once_it_fits_its_template_again() -> None:
    before = np.zeros(34, dtype=bool)
    before[[0, 19]] = True
    ratios = np.full(34, 0.1)
    ratios[0], ratios[19] = 0.4, 0.2  # above and below half of 0.5
    assert _covered(ratios, before) == {0}
    # A cover that has lasted too long ends however the node fits, and starts no new one.
    ratios[19] = 0.9
    assert _covered(ratios, before, expired=before) == set()


def test_a_covered_face_edge_node_is_uncovered_with_its_inner_neighbours() -> None:
    """The right temple still fits badly (0.4) once the eye corner and brow beside it fit.

    A face-edge node's patch changes with pose and light more than the inner nodes', so it
    stays covered only next to a covered inner node, as it was covered only next to one.
    """
    topology = mesh_topology(34)
    temple, corner, brow = (
        topology.index(n) for n in ('right_temple', 'right_eye_outer', 'right_brow_outer')
    )
    before = np.zeros(34, dtype=bool)
    before[[temple, corner, brow]] = True
    ratios = np.full(34, 0.1)
    ratios[[temple, corner]] = 0.4
    assert _covered(ratios, before) == {temple, corner}
    ratios[corner] = 0.1
    assert _covered(ratios, before) == set()
