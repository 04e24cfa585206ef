"""The stereo tracker on rendered synthetic faces (still head, training expressions), vs truth.

One short training sequence (neutral start, then a smile) of the synthetic world, rendered once
per module. Bounds are those measured on this sequence with some margin; the 380-frame figures
are in docs/benchmarks.md, "The stereo protocol (issue 5)" (issue 5 closing note).
"""

from __future__ import annotations

from dataclasses import replace
import itertools
from typing import NamedTuple

import numpy as np
import pytest
from recognition_streams import truth_model

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.imaging.rectification import Rectifier
from face_tracking_ros.io.conversions import face_messages, make_header
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.topology import Group, mesh_topology
from face_tracking_ros.synthetic.faces import ACTIVE_EXPRESSIONS, FacePopulation
from face_tracking_ros.synthetic.scenes import SceneConfig, SequenceRenderer
from face_tracking_ros.tracking.regularisation import RegularisationConfig
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.tracking.stereo import StereoTracker, track_sequence
from face_tracking_ros.tracking.stereo_config import StereoInitConfig, StereoTrackerConfig
from face_tracking_ros.tracking.stereo_data import SampleSet, depth_terms
from face_tracking_ros.tracking.stereo_evaluation import evaluate_stereo
from face_tracking_ros.tracking.stereo_init import (
    InitialNodes,
    check_face_scale,
    check_not_swapped,
    check_raw_not_swapped,
    initial_nodes,
)
from face_tracking_ros.tracking.stereo_templates import TemplateSamples

FRAMES = 30
TOPOLOGY = mesh_topology(34)
INNER = ~TOPOLOGY.group_mask(Group.EDGE)
FACTORY = RosbagsMessages(typestore())


@pytest.fixture(scope='module')
def scene() -> tuple[StereoRig, list, np.ndarray, list, SequenceRenderer]:
    """(rig, [(left, right)], (F, 34, 3) true nodes, [FrameTruth], renderer) of a sequence."""
    renderer = SequenceRenderer(SceneConfig(kind='stereo', frames=FRAMES, seed=0), 0)
    rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
    frames = list(renderer.frames(0))
    pairs = [(f.images['left'], f.images['right']) for f in frames]
    truths = [f.truth for f in frames]
    return rig, pairs, np.array([t.nodes_camera for t in truths]), truths, renderer


@pytest.fixture(scope='module')
def tracked(scene):
    rig, pairs, truth, _, _ = scene
    tracker = StereoTracker(rig, StereoTrackerConfig(refine_depths=True))
    return track_sequence(tracker, pairs, rig.left.project(truth[0]))


def test_tracks_every_frame_of_a_training_sequence(scene, tracked) -> None:
    assert any(truth.label == 'smile' for truth in scene[3])  # it reaches an expression
    assert tracked.meshes.shape == (FRAMES, 34, 3)
    assert np.all(tracked.status == TrackStatus.TRACKING)
    assert len(tracked.results) == FRAMES and all(r.reason == '' for r in tracked.results)


def test_accuracy_against_truth(scene, tracked) -> None:
    rig, _, truth, _, _ = scene
    evaluation = evaluate_stereo(tracked.meshes, truth, rig, TOPOLOGY, tracked.status)
    error = np.linalg.norm(tracked.meshes - truth, axis=2)
    # Measured: node RMS 2.1 mm, inner 0.68, eyes 0.19, eye corners 0.39, edge 3.55; max
    # reprojection 1.3 px; drift 0.12 mm, boundary slip 0.40 mm; inner nodes 0.29 px off in the
    # left image at most. Frame 1's mesh held throughout: 4.7, 4.2, 2.7, 2.7 and 5.6 mm,
    # 13.3 px, 3.4 and 5.4 mm, 10.2 px.
    assert evaluation.node_rms < 0.0025
    # Inner nodes (eyes, nose, mouth, brows, eye corners): stereo-matched at frame 1.
    assert np.sqrt(np.mean(error[:, INNER] ** 2)) < 0.001
    assert evaluation.node_rms_by_group['eye'] < 0.0005
    assert evaluation.node_rms_by_group['eye_corner'] < 0.0007
    # Boundary nodes take the reference face's depth at frame 1 (see stereo_init), which the
    # pooled left-right evidence of the pairs then corrects: looser.
    assert evaluation.node_rms_by_group['edge'] < 0.004
    assert evaluation.max_reprojection < 2.0
    # Over the sequence the error changes little: no drift, no slip along the face edge.
    assert evaluation.drift < 0.0005
    assert evaluation.boundary_slip < 0.0015
    left_inner = np.abs(
        rig.left.project(tracked.meshes[:, INNER].reshape(-1, 3))
        - rig.left.project(truth[:, INNER].reshape(-1, 3))
    )
    assert left_inner.max() < 1.0


def test_depth_refinement_corrects_the_initial_depths(scene, tracked) -> None:
    rig, pairs, truth, _, _ = scene
    edge = ~INNER
    # Online, pair 1 has the initialisation's depths; the sequence's meshes carry the depths
    # refined over all pairs on every frame (frame 1 included).
    online = np.linalg.norm(tracked.results[0].nodes_cam - truth[0], axis=1)
    offline = np.linalg.norm(tracked.meshes[0] - truth[0], axis=1)
    assert np.sqrt(np.mean(online[edge] ** 2)) > 0.008  # 9.5 mm
    assert np.sqrt(np.mean(offline[edge] ** 2)) < 0.004  # 3.0 mm
    final = tracked.results[-1]
    assert final.first_nodes is not None and final.rotation is not None
    np.testing.assert_allclose(
        rig.left.project(final.first_nodes), rig.left.project(truth[0]), atol=0.02
    )
    # Without the refinement the initial depths stay: edge nodes 9.7 mm RMS over the sequence.
    plain = track_sequence(
        StereoTracker(rig, StereoTrackerConfig(refine_depths=False)),
        pairs,
        rig.left.project(truth[0]),
    )
    plain_error = np.linalg.norm(plain.meshes - truth, axis=2)
    assert np.sqrt(np.mean(plain_error[:, edge] ** 2)) > 0.008
    np.testing.assert_array_equal(plain.meshes, np.stack([r.nodes_cam for r in plain.results]))


def _left_right_depth_offsets(scene, config: StereoTrackerConfig) -> np.ndarray:
    """(34,) depth offsets, m, of the left-right term's minimum along the rays from the truth.

    The tracker's node patches laid at the true frame-1 nodes, their left-right terms
    (:func:`depth_terms`) pooled over the sequence's neutral start (9 pairs, the head still) and
    minimised by Gauss-Newton in one depth change per node along its ray.
    """
    rig, pairs, truth, truths, _ = scene
    neutral = [index for index in range(9) if truths[index].label == 'neutral']
    assert len(neutral) == 9
    layout = TemplateSamples(config, TOPOLOGY).node_patches(truth[0], rig.left.focal)
    patches = SampleSet.of((layout,), 34)
    depth = np.zeros(34)
    for _ in range(6):
        slope = curvature = np.zeros(34)
        for index in neutral:
            rays = truth[index] / np.linalg.norm(truth[index], axis=1, keepdims=True)
            left, right = (image.astype(np.float32) for image in pairs[index])
            nodes = truth[index] + depth[:, None] * rays
            terms = depth_terms(rig, left, right, patches, nodes, rays, np.eye(3), 1e6)
            slope, curvature = slope + terms.slope, curvature + terms.curvature
        depth += np.clip(-slope / curvature, -0.003, 0.003)
    return depth


def test_left_right_depths_of_the_nose_tip_and_upper_lip(scene) -> None:
    # The node patches lie on the thin plate through the nodes, which runs in front of the skin
    # around the nose tip and the upper lip, so the left-right minimum of equally weighted
    # patches (the default) lies 1.13 / 1.22 mm too far. Weighing the samples by a Gaussian of
    # their distance from the node (tracker.cross_taper 1.5 samples): 0.54 / 0.31 mm; inner
    # nodes 0.51 -> 0.43 mm RMS.
    nose_tip, upper_lip = TOPOLOGY.index('nose_tip'), TOPOLOGY.index('upper_lip')
    equal = _left_right_depth_offsets(scene, StereoTrackerConfig())
    assert equal[nose_tip] > 0.001 and equal[upper_lip] > 0.001
    tapered = _left_right_depth_offsets(scene, StereoTrackerConfig(cross_taper=1.5))
    assert 0 < tapered[nose_tip] < 0.0007 and 0 < tapered[upper_lip] < 0.0005
    assert np.sqrt(np.mean(tapered[INNER] ** 2)) < 0.00046
    # The face edge's one-sided patches keep equal weights.
    np.testing.assert_array_equal(tapered[~INNER], equal[~INNER])


def _cropped(rig: StereoRig, columns: int) -> StereoRig:
    """The rig whose images lose their first ``columns`` columns (principal points move)."""

    def crop(camera):
        k, p = camera.k.copy(), camera.p.copy()
        k[0, 2] -= columns
        p[0, 2] -= columns
        return replace(camera, width=camera.width - columns, k=k, p=p)

    return StereoRig(crop(rig.left), crop(rig.right))


def _cut_off_run(scene, columns: int):
    """The scene's pairs, both images cropped by ``columns`` on the left, tracked.

    Returns:
        (the cropped rig, nodes beyond the right image's side at frame 1, the run).
    """
    rig, pairs, truth, _, _ = scene
    cropped = _cropped(rig, columns)
    out = cropped.right.project(truth[0])[:, 0] < 0
    assert np.all(cropped.left.project(truth[0])[:, 0] > 20)
    tracker = StereoTracker(cropped, StereoTrackerConfig(refine_depths=True))
    cut = [(left[:, columns:], right[:, columns:]) for left, right in pairs]
    return cropped, out, track_sequence(tracker, cut, cropped.left.project(truth[0]))


def test_a_face_edge_the_right_image_cuts_off_is_tracked(scene) -> None:
    """The face near the side of the frame: the right image misses part of its edge.

    Both images cropped by 215 columns on the left: the right camera, which sees the face
    f B / z = 100 px further left than the left one, misses the subject's right temple and
    cheeks. Their depth comes from the reference face and the face-model term in any case, and
    the left image carries them; until 2026-12-06 the track was lost on the second pair ('a
    node left the image').
    """
    _, out, run = _cut_off_run(scene, 215)
    assert out.sum() == 3 and np.all(TOPOLOGY.group_mask(Group.EDGE)[out])
    assert np.all(run.status == TrackStatus.TRACKING)
    error = np.linalg.norm(run.meshes - scene[2], axis=2)
    # Measured: node RMS 2.22 mm (in full view 2.10), the three nodes cut off 3.69 mm.
    assert np.sqrt(np.mean(error**2)) < 0.0025
    assert np.sqrt(np.mean(error[:, out] ** 2)) < 0.0045


def test_inner_nodes_the_right_image_cuts_off_are_named(scene) -> None:
    """Cropped by 230 columns, the right image misses the subject's right brow and eye corner.

    Their depth would be a guess (the reference face fitted to the rest of the face), so the
    initialisation is refused, naming them and what to do. Until 2026-12-06 the track started
    and was lost on the second pair ('a node left the image'); a learn run took one mesh.
    Cropped by 250 (the right eye and mouth corner out too), those are named as well. Until
    2026-12-07 their matches inside the right image (the other eye and brow, a metre off in
    depth, each correlation rising to the end of the depth range searched) were taken, left
    too few consistent ones, and the reason asked to check that both images show the whole face.
    """
    _, out, run = _cut_off_run(scene, 230)
    assert out.sum() == 6
    assert np.all(run.status == TrackStatus.INITIALIZING)
    assert run.results[-1].reason == (
        'initialisation failed: inner nodes outside the right image (right_brow_outer, '
        'right_eye_outer): the eyes, nose, mouth and brows must be inside both images and the '
        "face's edge inside one at least; move the face towards the middle of the frame (or the "
        'rig away from it)'
    )
    _, out, run = _cut_off_run(scene, 250)
    assert out.sum() == 12 and np.all(run.status == TrackStatus.INITIALIZING)
    assert run.results[-1].reason.startswith(
        'initialisation failed: inner nodes outside the right image (right_eye, nose_right, '
        'mouth_right, right_brow_inner, right_brow_middle, right_brow_outer, right_eye_outer): '
    )


def test_a_face_edge_both_images_cut_off_is_named(scene) -> None:
    """Both images keep their top 330 rows: the chin (at row 333) is below them.

    The eyes, nose, mouth and brows are inside both images and given, the chin is not (its
    position is the reference face's); no camera sees it, so the initialisation is refused,
    naming it. Until 2026-12-06 the reason named no node and asked for the eyes, nose, mouth
    and brows to be inside both images, which they were.
    """
    rig, pairs, truth, _, _ = scene
    rows = 330

    def crop(camera):
        return replace(camera, height=rows)

    cropped = StereoRig(crop(rig.left), crop(rig.right))
    clicks = rig.left.project(truth[0])
    below = clicks[:, 1] > rows - 1
    assert [TOPOLOGY.node_names[i] for i in np.flatnonzero(below)] == ['chin']
    clicks[below] = np.nan
    tracker = StereoTracker(cropped, StereoTrackerConfig(refine_depths=True))
    cut = [(left[:rows], right[:rows]) for left, right in pairs[:2]]
    run = track_sequence(tracker, cut, clicks)
    assert np.all(run.status == TrackStatus.INITIALIZING)
    assert run.results[-1].reason == (
        'initialisation failed: face-edge nodes outside both images (chin): the eyes, nose, '
        "mouth and brows must be inside both images and the face's edge inside one at least; "
        'move the face towards the middle of the frame (or the rig away from it)'
    )


@pytest.fixture(scope='module')
def occluded() -> tuple[StereoRig, list, np.ndarray]:
    """(rig, [(left, right)], (F, 34, 3) true nodes): an occluder passes over subject 0.

    The synthetic world at 320x240 (focal 300 px), 60 pairs at 30 fps; the occluder covers the
    mouth, nose and right cheek over pairs 20-45.
    """
    config = SceneConfig(
        kind='stereo',
        frames=60,
        fps=30.0,
        seed=0,
        occlusion=True,
        width=320,
        height=240,
        focal=300.0,
    )
    renderer = SequenceRenderer(config, 0)
    rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
    frames = list(renderer.frames(0))
    truth = np.array([frame.truth.nodes_camera for frame in frames])
    return rig, [(frame.images['left'], frame.images['right']) for frame in frames], truth


def _pixel_errors(rig: StereoRig, meshes: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(..., N) left-image distance of every tracked node from the truth, px."""
    shape = meshes.shape[:-1]
    error = rig.left.project(meshes.reshape(-1, 3)) - rig.left.project(truth.reshape(-1, 3))
    return np.linalg.norm(error, axis=1).reshape(shape)


def test_a_track_lost_to_an_occluder_is_found_again_after_it(occluded) -> None:
    """An occluder passes over the face: the track is lost, then re-acquired, not LOST to the end.

    Exact clicks, the occlusion check off (``occlusion_ratio`` 0: with it the track is not lost
    here, see the next test). The pairs before the loss had the occluder over part of the face
    under the loss check's median, so the last tracked pair's templates and face view show it;
    re-acquiring from them alone, the track stayed LOST from pair 27 to the end (26 pairs). Now
    re-acquired from frame 1 on pair 29, 2.1 px off at most.
    """
    rig, pairs, truth = occluded
    tracker = StereoTracker(rig, StereoTrackerConfig(refine_depths=True, occlusion_ratio=0.0))
    run = track_sequence(tracker, pairs, rig.left.project(truth[0]))
    lost = np.flatnonzero(run.status != TrackStatus.TRACKING)
    assert 1 <= lost.size <= 5  # measured 3 (pairs 25, 27, 28); 26 before
    found = lost[-1] + 1
    assert found < 40
    assert _pixel_errors(rig, run.meshes[found], truth[found]).max() < 3.0  # px; measured 2.1


def test_nodes_an_occluder_covers_are_held_to_the_head_not_dragged(occluded) -> None:
    """Covered nodes move with the head and keep their templates, so the occluder cannot drag them.

    Without the check the mouth and chin nodes followed the occluder (the templates were the
    last pair's, the occluder in them): the track went LOST on 3 pairs, was 17.5 px off at worst
    and 14.0 px over the last 10 pairs. With it every pair is tracked, at worst 7.4 px off while
    the occluder passes (the right mouth corner, which moves 5.9 px under it while the covered
    nodes keep their shape), 0.5 px over the last 10 pairs.

    The nodes flagged are each result's ``occluded``, which FaceState publishes (learn leaves
    such frames out): the occluder covers nodes' centres on pairs 15-37, the check holds nodes on
    pairs 18-34 (224 node-pairs, up to 20 at once; 196 were covered at their centre, the rest by
    part of their patch) and flags 210 of them, on pairs 19-33 (a held node with no held
    neighbour is not flagged).
    """
    rig, pairs, truth = occluded
    tracker = StereoTracker(rig, StereoTrackerConfig(refine_depths=True))
    run = track_sequence(tracker, pairs, rig.left.project(truth[0]))
    assert np.all(run.status == TrackStatus.TRACKING)
    errors = _pixel_errors(rig, run.meshes, truth)
    assert errors.max() < 11.0  # px; measured 7.4, 17.5 before
    assert errors[-10:].max() < 2.0  # px; measured 0.5, 14.0 before
    held = np.array([result.occluded for result in run.results])
    passing = np.flatnonzero(held.any(axis=1))
    assert 15 <= passing.min() and passing.max() <= 37  # measured 19 and 33
    assert held.sum(axis=1).max() >= 12  # measured 20
    widest = run.results[int(np.argmax(held.sum(axis=1)))].as_track_result()
    header = make_header(FACTORY, 0, 'left_optical')
    state = face_messages(FACTORY, header, 'face_0', widest, TOPOLOGY).state
    assert np.array_equal(np.asarray(state.occluded), widest.occluded)


def test_model_fit_gives_the_head_pose(scene) -> None:
    rig, pairs, truth, truths, renderer = scene
    model = truth_model(renderer.population)
    tracker = StereoTracker(rig, StereoTrackerConfig(refine_depths=True), model)
    tracker.reset(rig.left.project(truth[0]))
    results = [tracker.step(*pair) for pair in pairs[:3]]
    assert results[-1].fit is not None and results[-1].fit.rms[0] < 0.005
    view = results[-1].as_track_result()
    assert view.ok and view.sigma.shape == (model.p,) and view.alpha.shape == (model.q,)
    # The fitted head pose is the true one within what the node errors allow. The face-edge
    # nodes, whose depth is least certain, weigh 0.1 in the fit: 1.0 degree here after three
    # pairs of depth refinement (1.7 without it), translation 0.2 mm.
    assert np.linalg.norm(view.t - truths[2].t) < 0.001
    assert np.degrees(np.linalg.norm(view.omega - truths[2].omega)) < 1.2

    def equal_weights_error(refine_depths: bool) -> float:
        config = StereoTrackerConfig(fit_edge_weight=1.0, refine_depths=refine_depths)
        equal = StereoTracker(rig, config, model)
        equal.reset(rig.left.project(truth[0]))
        equal_view = [equal.step(*pair) for pair in pairs[:3]][-1].as_track_result()
        return float(np.degrees(np.linalg.norm(equal_view.omega - truths[2].omega)))

    # With equal weights the edge nodes' initial depths tilt the fit: 4.3 degrees at their
    # initial depths, 3.0 after three pairs of refinement.
    initial, refined = equal_weights_error(False), equal_weights_error(True)
    assert initial > 3.5 and refined < initial - 1.0
    # Without a model there is no fit: the pose is NaN, sigma and alpha are empty.
    plain = StereoTracker(rig, StereoTrackerConfig())
    plain.reset(rig.left.project(truth[0]))
    result = plain.step(*pairs[0])
    view = result.as_track_result()
    assert result.fit is None and view.omega.shape == view.t.shape == (3,)
    assert np.all(np.isnan(view.omega)) and np.all(np.isnan(view.t))
    assert view.sigma.shape == view.alpha.shape == (0,)


def test_patches_deforming_with_the_mesh_follow_a_brow_raise() -> None:
    # Subject 2's training sequence starts with a brow raise: the brows rise 8.7 px in 0.3 s.
    renderer = SequenceRenderer(SceneConfig(kind='stereo', frames=60, seed=0), 2)
    rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
    frames = list(renderer.frames(0))
    assert any(frame.truth.label == 'brow_raise' for frame in frames)
    truth = np.array([frame.truth.nodes_camera[:19] for frame in frames])
    pairs = [(frame.images['left'], frame.images['right']) for frame in frames]
    brows = mesh_topology(19).group_mask(Group.BROW)

    def brow_errors(deform_patches: bool) -> np.ndarray:
        config = StereoTrackerConfig(num_nodes=19, deform_patches=deform_patches)
        tracked = track_sequence(StereoTracker(rig, config), pairs, rig.left.project(truth[0]))
        assert np.all(tracked.status == TrackStatus.TRACKING)
        meshes, true = tracked.meshes[:, brows], truth[:, brows]
        return np.linalg.norm(
            rig.left.project(meshes.reshape(-1, 3)) - rig.left.project(true.reshape(-1, 3)), axis=1
        )

    motion = rig.left.project(truth[:, brows].reshape(-1, 3)) - np.tile(
        rig.left.project(truth[0, brows]), (len(frames), 1)
    )
    assert np.linalg.norm(motion, axis=1).max() > 8.0
    # Measured: 0.68 px with the patches deforming; rigid patches stop 1.25 px short.
    assert brow_errors(True).max() < 0.9
    assert brow_errors(False).max() > 1.1


def test_soft_brows_keep_up_with_a_fast_frown() -> None:
    # Seed 2's subject 1 frowns from about frame 205: its inner brow moves 0.5 px a frame until
    # frame 215. Tracked from the neutral frame 195, eq. 5's differential-motion cost (beta)
    # holds the brow back while it moves.
    start, end = 195, 226
    scene = SceneConfig(kind='stereo', frames=380, fps=30.0, seed=2, motion='still')
    renderer = SequenceRenderer(scene, 1)
    rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
    frames = list(itertools.islice(renderer.frames(0), end))[start:]
    assert frames[0].truth.label == 'neutral' and frames[-1].truth.label == 'frown'
    brow = mesh_topology(19).index('right_brow_inner')
    truth = np.array([frame.truth.nodes_camera[:19] for frame in frames])
    pairs = [(frame.images['left'], frame.images['right']) for frame in frames]

    def largest_error(regularisation: RegularisationConfig) -> float:
        config = StereoTrackerConfig(num_nodes=19, regularisation=regularisation)
        tracked = track_sequence(StereoTracker(rig, config), pairs, rig.left.project(truth[0]))
        projected = rig.left.project(tracked.meshes[:, brow])
        return float(np.linalg.norm(projected - rig.left.project(truth[:, brow]), axis=1).max())

    motion = rig.left.project(truth[:, brow]) - rig.left.project(truth[:1, brow])
    assert np.linalg.norm(motion, axis=1).max() > 5.0
    # Measured: 1.15 px with the default brow stiffness (0.1), 1.45 px with the earlier 0.2.
    assert largest_error(RegularisationConfig()) < 1.3
    assert largest_error(RegularisationConfig(brow=0.2)) > 1.35


class _Followed(NamedTuple):
    """A rendered sequence tracked from its true nodes (:func:`_followed_at_10_fps`)."""

    frames: list
    status: np.ndarray  # (F,)
    errors: np.ndarray  # (F, N) each node's left-image distance from the truth, px
    rms: np.ndarray  # (F,) over the nodes both cameras see, px
    occluded: np.ndarray  # (F, N) the nodes flagged as under an occluder


def _followed_at_10_fps(seed: int, frames: int, tracked: int) -> _Followed:
    """Subject 0 moving freely at 10 fps (``frames`` rendered): the first ``tracked`` pairs."""
    scene = SceneConfig(kind='stereo', frames=frames, fps=10.0, seed=seed, motion='free')
    renderer = SequenceRenderer(scene, 0)
    rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
    shown = list(itertools.islice(renderer.frames(0), tracked))
    truth = np.array([frame.truth.nodes_camera[:34] for frame in shown])
    pairs = [(frame.images['left'], frame.images['right']) for frame in shown]
    run = track_sequence(
        StereoTracker(rig, StereoTrackerConfig()), pairs, rig.left.project(truth[0])
    )
    seen = np.array([f.truth.visible['left'] & f.truth.visible['right'] for f in shown])
    errors = np.linalg.norm(
        rig.left.project(run.meshes.reshape(-1, 3)) - rig.left.project(truth.reshape(-1, 3)),
        axis=1,
    ).reshape(seen.shape)
    rms = np.sqrt([np.mean(error[mask] ** 2) for error, mask in zip(errors, seen, strict=True)])
    occluded = np.array([result.occluded for result in run.results])
    return _Followed(shown, run.status, errors, rms, occluded)


def test_a_jaw_closing_at_10_fps_is_followed_on_a_turning_head() -> None:
    # Seed 6's subject 0 moving freely at 10 fps (the head 5-6 px a pair) holds its jaw open,
    # then closes it over pairs 26-28 while the head turns; 40 pairs tracked from the true nodes.
    # Solved from two pyramid levels (``fast_motion_px`` 0), the lower lip and chin were left
    # below the closed mouth from pair 29, TRACKING.
    followed = _followed_at_10_fps(6, 40, 40)
    frames = followed.frames
    assert frames[25].truth.label == 'jaw_open' and frames[29].truth.label == 'neutral'
    assert np.all(followed.status == TrackStatus.TRACKING)
    # Measured: at most 0.82 px RMS over the nodes both cameras see; 5.0 px without the third
    # level.
    assert followed.rms.max() < 3.0


def test_a_talking_jaw_at_10_fps_is_followed() -> None:
    # Seed 13's subject 0 moving freely at 10 fps opens and closes its jaw by up to half its
    # range from one pair to the next from pair 37 (talking); its first 56 pairs tracked from
    # the true nodes. Started from each node's own motion, the jaw's motion carried on was
    # doubled where it turned back, and from pair 47 the lower lip and chin were 9-13 px off,
    # TRACKING.
    followed = _followed_at_10_fps(13, 100, 56)
    talking = followed.frames[37:]
    assert {frame.truth.label for frame in talking} == {'jaw_open'}
    assert np.abs(np.diff([frame.truth.intensity for frame in talking])).max() > 0.3
    assert np.all(followed.status == TrackStatus.TRACKING)
    lower = [mesh_topology(34).index(name) for name in ('lower_lip', 'chin')]
    # Measured: at most 2.75 px RMS over the nodes both cameras see, the lower lip and chin
    # 6.8 px off at most; from each node's own motion 5.07 px and 12.7 px.
    assert followed.rms.max() < 3.5
    assert followed.errors[:, lower].max() < 9.0


def test_brows_drifting_on_a_fast_head_are_not_held_off_their_features() -> None:
    # Seed 9's subject 0 moving freely at 10 fps, the head pitching 2 degrees and moving 10-12
    # px a pair, starts to smile at pair 8; 100 pairs tracked from the true nodes. The inner
    # brows drift 1.8-2.8 px off by pair 8 and disagree left and right together (0.77-0.80 of
    # their contrast), with no occluder rendered. Until 2026-12-07 that was beyond the ratio
    # (0.7): they were flagged and held to the head's rigid motion on 90 of the 92 pairs from
    # pair 8, and 20 pairs were tracked more than 3 px RMS off (14.8 px at worst). (Before the
    # forty-third session such flags also turned off the start from the head's motion and the
    # coarser level of a fast head, and the smile's lower lip and chin were left 10-17 px off
    # from pair 16; `occluder_shown` keeps them on, tested on made-up patches.) A patch is now
    # covered only beyond twice its usual disagreement: flagged on 13 pairs, none more than
    # 3 px off.
    followed = _followed_at_10_fps(9, 100, 100)
    assert followed.frames[8].truth.label == 'smile'
    assert np.all(followed.status == TrackStatus.TRACKING)
    assert followed.occluded[8:].any(axis=1).mean() < 0.5  # measured 0.14; 0.98 before
    # Measured: at most 2.89 px RMS over the nodes both cameras see; 14.79 px before.
    assert followed.rms.max() < 4.0


def test_a_jaw_opening_and_closing_between_pairs_at_10_fps_is_followed() -> None:
    # Seed 8's subject 0 moving freely at 10 fps talks from pair 61: the jaw at 0.79, 0.27 and
    # 0.69 of its range on pairs 64-66, the head slow (no coarser level for it). Solved from the
    # motion prediction on two levels, the lower lip and chin were left 4-5 px off on pair 65,
    # where their frame n - 1 templates held them: 15.6 px off by pair 81, 31 pairs more than 3
    # px RMS off (7.78 px at worst), TRACKING. Their patches' residuals leap on pair 65 (the
    # chin's 9.1 grey levels against 1.9), and such a pair is solved from a coarser level too.
    followed = _followed_at_10_fps(8, 100, 100)
    assert [frame.truth.label for frame in followed.frames[61:67]] == ['jaw_open'] * 6
    assert np.all(followed.status == TrackStatus.TRACKING)
    # Measured: at most 2.04 px RMS over the nodes both cameras see.
    assert followed.rms.max() < 3.0


def test_initial_depths_of_smooth_lips_and_brows() -> None:
    # Two subjects of another population, whose smooth lips and brows a single pair matches
    # poorly in depth: 7x7 refinement patches put a lip 10 mm and two brows 8-10 mm off.
    # Measured, matched nodes' depth error along the rays: 1.40 and 3.05 mm RMS (11x11
    # patches, the default; 2.37 mm together) against 3.18 and 3.71 mm (7x7; 3.46 together).
    topology = mesh_topology(19)
    pairs = []
    for subject in (0, 1):
        renderer = SequenceRenderer(SceneConfig(kind='stereo', frames=1, seed=2), subject)
        frame = next(iter(renderer.frames(0)))
        images = (frame.images[side].astype(np.float32) for side in ('left', 'right'))
        rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
        pairs.append((rig, *images, frame.truth.nodes_camera[:19]))

    def depth_errors(config: StereoInitConfig) -> np.ndarray:
        errors = []
        for rig, left, right, truth in pairs:
            initial = initial_nodes(rig, left, right, rig.left.project(truth), topology, config)
            assert initial.matched.all()
            rays = truth / np.linalg.norm(truth, axis=1, keepdims=True)
            errors.append(np.einsum('nd,nd->n', initial.nodes - truth, rays))
        return np.concatenate(errors)

    def rms(errors: np.ndarray) -> float:
        return float(np.sqrt(np.mean(errors**2)))

    assert rms(depth_errors(StereoInitConfig())) < 0.0028
    assert rms(depth_errors(StereoInitConfig(refine_half_size=3))) > 0.0032


def test_initial_depths_of_a_turned_head() -> None:
    """Heads turned 19-22 degrees from the cameras: a brow end's window straddles the outline.

    Over the whole depth range, the far brow end's correlation window (half the face's, half
    the background) peaks 33-115 mm too far, so the reference face fitted to the matches drops
    it and it is searched again within ``max_face_error`` of that face. There its correlation
    only rises towards the band's far end, which is no peak: the node takes the fitted face's
    depth. Until 2026-12-07 the band's end was taken as its match and refined further out:
    16.4 and 33.6 mm too far (seeds 3 and 4), the track's far brow held and 9-12 px off.
    Measured: the inner nodes' largest depth error 2.1 and 4.4 mm.
    """
    topology = mesh_topology(34)
    inner = ~topology.group_mask(Group.EDGE)
    config = SceneConfig(kind='stereo', frames=1, fps=30.0, motion='free')
    for seed, subject in ((3, 0), (4, 2)):
        renderer = SequenceRenderer(replace(config, seed=seed), subject)
        frame = next(iter(renderer.frames(0)))
        left, right = (frame.images[side].astype(np.float32) for side in ('left', 'right'))
        rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
        truth = frame.truth.nodes_camera
        initial = initial_nodes(
            rig, left, right, rig.left.project(truth), topology, StereoInitConfig()
        )
        assert np.abs(initial.nodes[inner, 2] - truth[inner, 2]).max() < 0.006


def _with_baseline_times(rig: StereoRig, factor: float) -> StereoRig:
    """``rig`` whose right camera_info gives ``factor`` times the baseline (P[0,3] = -fx k B)."""
    p = rig.right.p.copy()
    p[0, 3] *= factor
    return StereoRig(rig.left, replace(rig.right, p=p))


@pytest.mark.parametrize(
    ('factor', 'read', 'calibrated'),
    [(2.0, '1.99 times', 'P[0,3] = -132 (-fx B) gives B = 0.22 m'),
     (0.5, '0.50 times', 'P[0,3] = -33 (-fx B) gives B = 0.055 m')],
)  # fmt: skip
def test_a_rig_of_a_wrong_baseline_is_refused_with_the_baseline_that_fits(
    scene, factor: float, read: str, calibrated: str
) -> None:
    """The sequence's first pair with its right camera_info's baseline doubled or halved.

    Triangulated sizes scale with the baseline: subject 0's face (0.99 of the adult face) reads
    1.99 and 0.50. Doubled, it was tracked (the check allowed 0.5-2) as TRACKING on every pair,
    the nodes twice as far as they are.
    """
    rig, pairs, truth, _, _ = scene
    tracker = StereoTracker(_with_baseline_times(rig, factor), StereoTrackerConfig())
    tracker.reset(rig.left.project(truth[0]))
    result = tracker.step(*pairs[0])
    assert result.status == TrackStatus.INITIALIZING, result.reason
    assert result.reason.startswith(
        f'initialisation failed: the matched inner nodes triangulate to a face {read} the size '
        'of an adult face (allowed 0.7-1.5): the stereo calibration does not fit these images. '
        f"Check its baseline first: the right camera_info's {calibrated}, and an adult-sized "
        'face needs B = 0.11'
    ), result.reason
    assert 'rectified (rectify)' in result.reason


def test_no_face_of_the_synthetic_populations_reads_a_wrong_calibration() -> None:
    """Their 200 first faces of seeds 0-2, neutral and each expression at full intensity.

    Measured: sizes 0.85-1.21 of the adult face, within 0.7-1.5; twice each 1.70 or more.
    """
    config = StereoInitConfig()
    rig = StereoRig.ideal()
    for num_nodes in (19, 34):
        topology = mesh_topology(num_nodes)
        inner = ~topology.group_mask(Group.EDGE)
        for preset, seed in itertools.product(('default', 'realistic'), range(3)):
            population = FacePopulation(preset, seed)
            for index in range(200):
                subject = population.subject(index)
                for weights in ({}, *({name: 1.0} for name in ACTIVE_EXPRESSIONS)):
                    nodes = population.nodes(subject, weights)[:num_nodes]
                    check_face_scale(InitialNodes(nodes, inner), topology, rig, config)
                    with pytest.raises(InputError, match='Check its baseline first'):
                        check_face_scale(InitialNodes(2 * nodes, inner), topology, rig, config)


def test_swapped_images_are_named_and_pairs_wired_right_never_look_swapped() -> None:
    """12 subjects (2 of seeds 0-2 of both populations), 19 and 34 nodes alternately.

    Exchanged images stop the initialisation saying so, whether the positions are the left
    camera's (simulated clicks, an init file) or are found in the image given as the left one
    (the detector, a user's clicks). Pairs wired right never look swapped, even with clicks 10 px
    off. Measured on 30 subjects, both meshes: every swapped pair matched 22-23 of 23 and 19 of
    19 inner nodes as a face exchanged, pairs wired right at most 4 (8 of 23 from noisy clicks).
    """
    config = StereoInitConfig()
    rng = np.random.default_rng(0)
    for index, (preset, seed, subject) in enumerate(
        itertools.product(('default', 'realistic'), range(3), range(2))
    ):
        scene = SceneConfig(kind='stereo', frames=1, seed=seed, population=preset)
        renderer = SequenceRenderer(scene, subject)
        rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
        frame = next(iter(renderer.frames(0)))
        left, right = (frame.images[side].astype(np.float32) for side in ('left', 'right'))
        num_nodes = (19, 34)[index % 2]
        topology = mesh_topology(num_nodes)
        inner = ~topology.group_mask(Group.EDGE)
        truth = frame.truth.nodes_camera[:num_nodes]
        for camera in (rig.left, rig.right):  # positions in the left camera, or in the image
            tracker = StereoTracker(rig, StereoTrackerConfig(num_nodes=num_nodes))
            tracker.reset(camera.project(truth))
            result = tracker.step(right, left)
            assert result.status == TrackStatus.INITIALIZING
            assert result.reason.startswith(
                'initialisation failed: the left and right images look swapped: '
            ), result.reason
            assert result.reason.endswith(
                "check the image topics' remapping (left/image_raw must carry the left camera's "
                "images, right/image_raw the right one's)"
            )
        clicks = rig.left.project(truth)
        for positions in (clicks, clicks + rng.normal(0.0, 10.0, clicks.shape)):
            check_not_swapped(rig, left, right, positions, inner, topology, config, 0)  # passes


def test_raw_images_exchanged_on_a_turned_rig_are_named_and_pairs_wired_right_never() -> None:
    """Rigs turned 3 degrees, distorted: 4 subjects (seeds 0-1 of both populations), 19/34 nodes.

    Raw images are rectified with the calibration of the topic they came on: exchanged, each
    with the other camera's rotation, and nothing matched either way (3 inner nodes) or the pair
    matched as a face 3 times too large, which the reason said instead. Given the raw pair
    exchanged before rectifying, the tracker names the swap from clicks in the left camera.
    Pairs wired right, exchanged so, never look swapped, even from clicks 10 px off. Measured
    on 12 subjects at 1-3 and 8 degrees: swapped pairs matched 19 of 19 and 23 of 23 inner
    nodes; pairs wired right, exchanged, at most 11 of 19 (from 10 px off; RAW_SWAP_SHARE).
    """
    config = StereoInitConfig()
    rng = np.random.default_rng(0)
    for index, (preset, seed) in enumerate(itertools.product(('default', 'realistic'), (0, 1))):
        scene = SceneConfig(
            kind='stereo',
            frames=1,
            seed=seed,
            population=preset,
            toe_in_deg=3.0,
            distortion=(-0.28, 0.09, 0.001, -0.001, 0.0),
        )
        renderer = SequenceRenderer(scene, 0)
        cameras = renderer.cameras
        rig = StereoRig(cameras['left'], cameras['right'])
        left, right = (Rectifier(cameras[side]) for side in ('left', 'right'))
        frame = next(iter(renderer.frames(0)))
        raw_left, raw_right = frame.images['left'], frame.images['right']
        num_nodes = (19, 34)[index % 2]
        topology = mesh_topology(num_nodes)
        clicks = rig.left.project(frame.truth.nodes_camera[:num_nodes])
        tracker = StereoTracker(rig, StereoTrackerConfig(num_nodes=num_nodes))
        tracker.reset(clicks)
        # Swapped topics: the right camera's raw image rectified as the left one's, and so on.
        swapped = (left.image(raw_right), right.image(raw_left))
        exchanged = (left.image(raw_left), right.image(raw_right))
        result = tracker.step(*swapped, 1, lambda pair=exchanged: pair)
        count = (19, 23)[index % 2]
        assert result.reason == (
            'initialisation failed: the left and right images look swapped: with the raw images '
            f'exchanged before rectifying, {count} of the {count} inner nodes match as an '
            "adult-sized face; check the image topics' remapping (left/image_raw must carry the "
            "left camera's images, right/image_raw the right one's)"
        )
        wired_right = tuple(image.astype(np.float32) for image in swapped)  # exchanged of it
        for positions in (clicks, clicks + rng.normal(0.0, 10.0, clicks.shape)):
            check_raw_not_swapped(rig, wired_right, positions, topology, config)  # passes


def test_a_turning_face_is_not_flagged_as_occluded() -> None:
    """A head turned from one camera: its far brow end disagrees left-right, alone, unflagged.

    Rendered free motion, no occluder (seed 1, 640x480, the head turning from 19 to 28 degrees
    and back to -14 over 80 pairs). The right brow's outer patch, 8 mm too far at frame 1 (its
    window on the turned side straddles the outline), disagrees beyond the ratio alone on 23
    pairs, the left brow's on 8: they are held to the head's rigid motion, but no occluder is
    reported. Before, the 57 pairs with a node held were all flagged. Until 2026-12-07 the
    epipolar search took the end of its depth band for a match: the brow end 27 mm too far,
    held on 49 pairs (the temple next to it on 25) and up to 12.2 px off; the mesh 1.61 px RMS.
    Measured: the brow end 3.3 px off at most, the mesh 1.11 px RMS.
    """
    config = SceneConfig(kind='stereo', frames=80, fps=30.0, seed=1, motion='free')
    renderer = SequenceRenderer(config, 0)
    rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
    frames = list(renderer.frames(0))
    truth = np.array([frame.truth.nodes_camera for frame in frames])
    pairs = [(frame.images['left'], frame.images['right']) for frame in frames]
    tracker = StereoTracker(rig, StereoTrackerConfig(refine_depths=True))
    run = track_sequence(tracker, pairs, rig.left.project(truth[0]))
    assert np.all(run.status == TrackStatus.TRACKING)
    assert not np.array([result.occluded for result in run.results]).any()  # 57 pairs before
    error = _pixel_errors(rig, run.meshes, truth)
    assert error[:, TOPOLOGY.index('right_brow_outer')].max() < 5.0
    assert np.sqrt(np.mean(error**2)) < 1.3


def test_a_brow_whose_patches_usually_disagree_is_not_held_while_it_rises() -> None:
    """Issue 5's protocol, seed 2, subject 1 (19 nodes): a middle brow reading near the ratio.

    Its patch reads 0.71 left against right on the median pair, on its feature (the other
    subjects' 0.19). Held beyond the ratio, it and the inner brow were flagged on 24 of the
    first 180 pairs with no occluder, and the held brows stopped as they rose (the inner one
    2.01 px off on pair 149; later in the sequence the middle one 5.05 px as it fell). Covered
    only beyond twice its usual disagreement: flagged on none, 1.10 px off at most.
    """
    config = SceneConfig(kind='stereo', subjects=6, frames=380, fps=30.0, seed=2)
    renderer = SequenceRenderer(config, 1)
    rig = StereoRig(renderer.cameras['left'], renderer.cameras['right'])
    frames = list(itertools.islice(renderer.frames(0), 180))
    truth = np.array([frame.truth.nodes_camera[:19] for frame in frames])
    pairs = [(frame.images['left'], frame.images['right']) for frame in frames]
    tracker = StereoTracker(rig, StereoTrackerConfig(num_nodes=19, refine_depths=True))
    run = track_sequence(tracker, pairs, rig.left.project(truth[0]))
    assert not np.array([result.occluded for result in run.results]).any()
    error = _pixel_errors(rig, run.meshes, truth)
    assert error.max() < 1.5
