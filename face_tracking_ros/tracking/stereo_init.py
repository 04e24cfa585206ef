"""Initialisation of the stereo tracker: left-image node positions to 3-D nodes (seed §3.3).

The seed initialises the mesh on the first frame semi-automatically. Here the nodes' positions
in the left image are given (an init file, a service call, or a landmark detector); each given
node is found in the right image by normalised cross-correlation along its epipolar line (the
same row of a rectified pair, ``cv2.matchTemplate``) within a depth range, triangulated
(``StereoRig.triangulate``), and refined along its viewing ray by Gauss-Newton on the left-right
difference of a patch lying on the face surface, which removes the bias that square windows
have on sloping skin. Nodes not given, or whose match is weak or inconsistent with the
face, take their position from the reference face of the topology fitted to the others (a
similarity transform) and keep its depth. A pair whose images come exchanged (the left
camera's on the right topic) is refused as such (:func:`check_not_swapped`; raw images the
caller rectified each with the other camera's calibration: :func:`check_raw_not_swapped`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.geometry.procrustes import rigid_align
from face_tracking_ros.imaging import sample_patches, sample_points, square_offsets
from face_tracking_ros.model.topology import Group, MeshTopology
from face_tracking_ros.tracking.initialisation import check_inside
from face_tracking_ros.tracking.stereo_config import StereoInitConfig
from face_tracking_ros.tracking.stereo_data import SampleLayout, SampleSet, depth_terms
from face_tracking_ros.tracking.stereo_loss import view_problem
from face_tracking_ros.wording import counted

FLAT_STD = 0.5  # grey levels: a correlation window flatter than this cannot be matched
MIN_FIT_NODES = 4  # fewest inner nodes the reference face is fitted to
NOSE_BEHIND_EYES_M = 0.0  # a fitted face whose nose is behind its eyes is turned away
# Share of the inner nodes given that must match as an adult-sized face with the raw images
# exchanged before rectifying for them to be named swapped (check_raw_not_swapped): swapped
# pairs of 12 rendered subjects on rigs turned 1-3 and 8 degrees matched all of them from
# positions in the left camera, pairs wired right, exchanged, up to 11 of 19 (half named
# 2 of 96 of those); at 4-6 degrees either pair, wrongly rectified, can read as a face.
RAW_SWAP_SHARE = 0.75
REMAP_HINT = (  # what to check for images that look exchanged
    "check the image topics' remapping (left/image_raw must carry the left camera's images, "
    "right/image_raw the right one's)"
)


def epipolar_match(
    rig: StereoRig,
    left: np.ndarray,
    right: np.ndarray,
    left_px: np.ndarray,
    depth_range: tuple[np.ndarray, np.ndarray],
    half_size: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Find left-image points in the right image along their epipolar lines.

    Args:
        rig: the rectified rig.
        left: (H, W) float32 left image.
        right: (H, W) float32 right image.
        left_px: (K, 2) left pixel positions.
        depth_range: (K,) nearest and (K,) farthest depths searched, m.
        half_size: correlation windows are (2 h + 1)^2 pixels.

    Returns:
        ``(right_px, score)``: (K, 2) matched right positions (sub-pixel along the row; NaN
        where nothing could be matched) and the (K,) normalised cross-correlation of each match
        (-1 where nothing could be matched). A correlation highest at either end of the range
        is no match: it only rises towards a peak outside the range (on a head turned 19-22
        degrees from the cameras, the far brow end's window straddles the face's outline; its
        correlation within the band of the fitted face rose to the band's far end, 16-34 mm
        too far, and was refined further out).
    """
    rays = _rays(rig, left_px)
    near = rig.right.project(rays * depth_range[0][:, None])
    far = rig.right.project(rays * depth_range[1][:, None])
    return _row_match(left, right, left_px, (near[:, 0], far[:, 0]), far[:, 1], half_size)


def _row_match(
    left: np.ndarray,
    right: np.ndarray,
    left_px: np.ndarray,
    columns: tuple[np.ndarray, np.ndarray],
    rows: np.ndarray,
    half_size: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Find left-image points in the right image along a row, between two columns.

    Args:
        left: (H, W) float32 left image.
        right: (H, W) float32 right image.
        left_px: (K, 2) left pixel positions.
        columns: (K,) first and (K,) last right-image columns searched (the first the
            smaller).
        rows: (K,) right-image rows searched.
        half_size: correlation windows are (2 h + 1)^2 pixels.

    Returns:
        ``(right_px, score)`` as :func:`epipolar_match` returns them.
    """
    h = half_size
    windows = sample_patches(left, left_px, square_offsets(h)).reshape(-1, 2 * h + 1, 2 * h + 1)
    right_px = np.full_like(left_px, np.nan, dtype=float)
    scores = np.full(left_px.shape[0], -1.0)
    for k in range(left_px.shape[0]):
        start, stop = columns[0][k] - h, columns[1][k] + h
        columns_k = start + np.arange(int(np.ceil(stop - start)) + 1, dtype=float)
        rows_k = rows[k] + np.arange(-h, h + 1, dtype=float)
        strip = sample_points(right, np.stack(np.meshgrid(columns_k, rows_k), axis=-1))
        if strip.shape[1] <= 2 * h + 1 or windows[k].std() < FLAT_STD:
            continue
        response = cv2.matchTemplate(strip, windows[k], cv2.TM_CCOEFF_NORMED)[0]
        # On near-flat stretches of the strip the correlation is the noise's (and 0 on exactly
        # flat ones in OpenCV 5.0): exclude them.
        response[_window_std(strip, h) < FLAT_STD] = -1.0
        best = int(np.argmax(response))
        if best in (0, response.size - 1):  # rising to the range's end: no peak inside it
            continue
        scores[k] = float(response[best])
        right_px[k] = [columns_k[h] + best + _parabola_peak(response, best), rows[k]]
    return right_px, scores


@dataclass(frozen=True)
class InitialNodes:
    """The 3-D nodes of the first pair and where each one's depth came from.

    Attributes:
        nodes: (N, 3) nodes in the left camera frame, m.
        matched: (N,) bool, nodes whose depth is their own stereo match; the others' depth is
            the fitted reference face's.
    """

    nodes: np.ndarray
    matched: np.ndarray


def initial_nodes(
    rig: StereoRig,
    left: np.ndarray,
    right: np.ndarray,
    left_px: np.ndarray,
    topology: MeshTopology,
    config: StereoInitConfig,
) -> InitialNodes:
    """3-D nodes (N, 3) in the left camera frame, m, from their left-image positions.

    Inner nodes are matched by stereo in two passes: first over the whole depth range; the
    reference face is fitted to the matches, trimming the worst until all agree with it within
    ``config.max_face_error``; the rejected ones are searched again within that distance of the
    fitted face, and every match is refined in depth. Face-boundary nodes (§4.2) are not matched:
    they lie where the skin turns away from the cameras, each camera sees a different rim there,
    and on the synthetic faces their stereo matches err by 6 to 20 mm against 5 mm for the fitted
    face; they, and nodes not given or not matched, take the fitted face's position (a given node
    at the face's depth on its left viewing ray).

    Args:
        rig: the rectified rig.
        left: (H, W) float32 left image.
        right: (H, W) float32 right image.
        left_px: (N, 2) left pixel positions; NaN rows for nodes not given.
        topology: the mesh (its reference face fills in missing nodes).
        config: the initialisation tunables.

    Raises:
        InputError: if fewer than ``config.min_given_nodes`` nodes are given, a given node lies
            outside the left image, or too few inner nodes are matched to fit the face; or if
            fewer than half of them are, and the images look exchanged
            (:func:`check_not_swapped`).
    """
    height, width = left.shape
    check_inside(topology.node_names, left_px, (width, height), 'left image')
    given = np.all(np.isfinite(left_px), axis=1)
    if given.sum() < config.min_given_nodes:
        given_nodes = counted(int(given.sum()), 'node')
        msg = f'only {given_nodes} given; at least {config.min_given_nodes} are needed'
        raise InputError(msg)
    search = given & ~topology.group_mask(Group.EDGE)
    count = int(search.sum())
    if count < MIN_FIT_NODES:
        msg = (
            f'the initialisation gives {counted(count, "inner node")} (eyes, nose, mouth, '
            f'brows); at least {MIN_FIT_NODES} are needed: the face edge alone cannot place the '
            'face'
        )
        raise InputError(msg)
    full_range = (np.full(count, config.min_depth), np.full(count, config.max_depth))
    right_px, scores = epipolar_match(
        rig, left, right, left_px[search], full_range, config.match_half_size
    )
    triangulated = np.full((topology.num_nodes, 3), np.nan)
    triangulated[search] = rig.triangulate(left_px[search], right_px)
    matched = np.zeros(topology.num_nodes, dtype=bool)
    matched[search] = scores >= config.min_score
    try:
        reference = _trimmed_reference(topology, triangulated, matched, config)
        _check_facing(topology, reference)
    except InputError:
        check_not_swapped(rig, left, right, left_px, search, topology, config, int(matched.sum()))
        raise
    if 2 * matched.sum() < count:  # a weak match: of a pair whose images are exchanged?
        check_not_swapped(rig, left, right, left_px, search, topology, config, int(matched.sum()))
    retry = search & ~matched
    if retry.any():
        rays = _rays(rig, left_px[retry])
        depth = np.einsum('kd,kd->k', reference[retry], rays) / np.einsum('kd,kd->k', rays, rays)
        band = config.max_face_error
        right_px, scores = epipolar_match(
            rig, left, right, left_px[retry], (depth - band, depth + band), config.match_half_size
        )
        found = scores >= config.min_score
        rematched = np.flatnonzero(retry)[found]
        triangulated[rematched] = rig.triangulate(left_px[rematched], right_px[found])
        matched[rematched] = True
    nodes = np.where(matched[:, None], triangulated, reference)
    placed = given & ~matched
    rays = _rays(rig, left_px[placed])
    nodes[placed] = rays * (reference[placed, 2] / rays[:, 2])[:, None]
    # Depth refinement corrects the matches only; their surface alone gives the patches' shape.
    nodes[matched] = refine_depths(rig, left, right, nodes[matched], config)
    return InitialNodes(nodes, matched)


def _reversed_match(
    rig: StereoRig,
    left: np.ndarray,
    right: np.ndarray,
    left_px: np.ndarray,
    config: StereoInitConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """Find left-image points in the right image at the depth range's disparities reversed.

    A rectified pair shows a point at depth Z fx B / Z px further left in the right image than
    in the left (:func:`epipolar_match` searches there); with the images exchanged (the topics
    wired the wrong way round) every point is that far to the right instead. This searches
    there: the same row, the columns of the depth range mirrored about each point's own.

    Returns:
        ``(right_px, score)`` as :func:`epipolar_match` returns them.
    """
    rays = _rays(rig, left_px)
    near = rig.right.project(rays * config.min_depth)
    far = rig.right.project(rays * config.max_depth)
    x = left_px[:, 0]
    columns = (2.0 * x - far[:, 0], 2.0 * x - near[:, 0])
    return _row_match(left, right, left_px, columns, far[:, 1], config.match_half_size)


def check_not_swapped(
    rig: StereoRig,
    left: np.ndarray,
    right: np.ndarray,
    left_px: np.ndarray,
    search: np.ndarray,
    topology: MeshTopology,
    config: StereoInitConfig,
    consistent: int,
) -> None:
    """Refuse a pair whose inner nodes matched weakly as a face that looks exchanged.

    With the left camera's image on the right topic and the right camera's on the left, the
    nodes match as a face either with the images exchanged back (positions in the left camera,
    e.g. clicks simulated from its camera_info or an earlier init file) or at reversed
    disparities (positions found in the image given as the left one, e.g. by the detector or
    clicked on it). Either at least half of the searched inner nodes, at least
    :data:`MIN_FIT_NODES` and more than ``consistent``, matching as a face says so. On 30
    rendered subjects, both meshes, pairs wired right matched at most 4 that way (8 of 23 from
    clicks 10 px off), their images exchanged 22-23 of 23 and 19 of 19 (0-9 as they came).

    Args:
        rig: the rectified rig.
        left: (H, W) float32 image given as the left one.
        right: (H, W) float32 image given as the right one.
        left_px: (N, 2) the nodes' left pixel positions (NaN rows: not given).
        search: (N,) bool, the inner nodes searched.
        topology: the mesh (its reference face is fitted to the matches).
        config: the initialisation tunables.
        consistent: how many of them matched as a face as they come.

    Raises:
        InputError: saying that the images look swapped and which topics to check.
    """
    px = left_px[search]
    count = px.shape[0]
    full_range = (np.full(count, config.min_depth), np.full(count, config.max_depth))
    exchanged, exchanged_scores = epipolar_match(
        rig, right, left, px, full_range, config.match_half_size
    )
    reversed_px, reversed_scores = _reversed_match(rig, left, right, px, config)
    # Each reversed match moved to the same disparity the usual way round: its depth.
    mirrored = np.stack([2.0 * px[:, 0] - reversed_px[:, 0], reversed_px[:, 1]], axis=1)
    found = max(
        _face_matches(topology, search, rig.triangulate(px, exchanged), exchanged_scores, config),
        _face_matches(topology, search, rig.triangulate(px, mirrored), reversed_scores, config),
    )
    if found >= max(MIN_FIT_NODES, count / 2, consistent + 1):
        msg = (
            f'the left and right images look swapped: {found} of the {count} inner nodes match '
            f'as a face with them exchanged, {consistent} as they come; {REMAP_HINT}'
        )
        raise InputError(msg)


def check_raw_not_swapped(
    rig: StereoRig,
    exchanged: tuple[np.ndarray, np.ndarray],
    left_px: np.ndarray,
    topology: MeshTopology,
    config: StereoInitConfig,
) -> None:
    """Refuse raw images whose initialisation failed and that look exchanged before rectifying.

    Raw images are rectified with the calibration of the topic they came on: exchanged, each is
    rectified with the other camera's rotation R, and on a rig whose R turns the cameras by
    about 1.5 degrees or more nothing matches either way (:func:`check_not_swapped` finds
    nothing), or the pair matches as a face 3 times too large. ``exchanged`` is the raw
    images exchanged back, each rectified with its own camera's maps: the pair as it would
    come with the topics wired right. If the initialisation succeeds on it, at least
    :data:`RAW_SWAP_SHARE` of the inner nodes given matched, and the face it finds is of adult
    size (:func:`check_face_scale`), the images are exchanged.

    Args:
        rig: the rectified rig (the calibration's).
        exchanged: (left, right) (H, W) float32: the raw image of the right image topic
            rectified as the left camera's, that of the left topic as the right camera's.
        left_px: (N, 2) the nodes' positions in the left camera (NaN rows: not given).
        topology: the mesh.
        config: the initialisation tunables.

    Raises:
        InputError: saying that the images look swapped and which topics to check.
    """
    search = np.all(np.isfinite(left_px), axis=1) & ~topology.group_mask(Group.EDGE)
    try:
        initial = initial_nodes(rig, *exchanged, left_px, topology, config)
        check_face_scale(initial, topology, rig, config)
    except InputError:  # (one that looks exchanged itself came wired right)
        return
    found, count = int(initial.matched[search].sum()), int(search.sum())
    if found >= RAW_SWAP_SHARE * count:
        msg = (
            'the left and right images look swapped: with the raw images exchanged before '
            f'rectifying, {found} of the {count} inner nodes match as an adult-sized face; '
            f'{REMAP_HINT}'
        )
        raise InputError(msg)


def _face_matches(
    topology: MeshTopology,
    search: np.ndarray,
    points: np.ndarray,
    scores: np.ndarray,
    config: StereoInitConfig,
) -> int:
    """How many of the ``search`` nodes' matches (``points``, ``scores``) agree with a face.

    Those matched at ``config.min_score`` or above that the reference face fitted to them keeps
    (:func:`_trimmed_reference`), facing the camera; 0 if fewer than :data:`MIN_FIT_NODES`.
    """
    nodes = np.full((topology.num_nodes, 3), np.nan)
    nodes[search] = points
    use = np.zeros(topology.num_nodes, dtype=bool)
    use[search] = scores >= config.min_score
    try:
        _check_facing(topology, _trimmed_reference(topology, nodes, use, config))
    except InputError:
        return 0
    return int(use.sum())


def _check_facing(topology: MeshTopology, face: np.ndarray) -> None:
    """Refuse a fitted face turned away from the camera: its nose behind its eyes.

    A face is nearly symmetric, so points named with left and right swapped (the subject's left
    is the image's right) fit it as well turned round, seen from behind.

    Raises:
        InputError: saying so.
    """
    eyes = face[[topology.index('right_eye'), topology.index('left_eye')]].mean(axis=0)
    behind = float(np.dot(face[topology.index('nose_tip')] - eyes, eyes / np.linalg.norm(eyes)))
    if behind > NOSE_BEHIND_EYES_M:
        msg = (
            f'the initial positions fit a face turned away from the camera (its nose '
            f'{1000 * behind:.0f} mm behind its eyes): are left and right swapped? The '
            "subject's left eye (left_eye) is on the image's right"
        )
        raise InputError(msg)


def refine_depths(
    rig: StereoRig,
    left: np.ndarray,
    right: np.ndarray,
    nodes: np.ndarray,
    config: StereoInitConfig,
) -> np.ndarray:
    """Move each node along its left viewing ray to match its surface patch left-right.

    Gauss-Newton on sum_m (I_R(pi_R(P_m)) - I_L(pi_L(P_m)))^2 over the depth of each node, with
    the patch P_m on the surface through the nodes (eq. 4's cross term at frame 1).

    Args:
        rig: the rectified rig.
        left: (H, W) float32 left image.
        right: (H, W) float32 right image.
        nodes: (K, 3) initial nodes, m (they also define the surface).
        config: iterations and patch size.

    Returns:
        (K, 3) refined nodes, m (each on the same left viewing ray).
    """
    count = nodes.shape[0]
    for _ in range(config.refine_iterations):
        layout = SampleLayout.node_patches(
            nodes,
            nodes[:, 2] / rig.left.focal,
            config.refine_half_size,
            np.zeros(count, dtype=bool),
        )
        rays = nodes / np.linalg.norm(nodes, axis=1, keepdims=True)
        patches = SampleSet.of((layout,), count)
        terms = depth_terms(rig, left, right, patches, nodes, rays, np.eye(3), 1e6)
        with np.errstate(divide='ignore', invalid='ignore'):
            step = np.where(terms.curvature > 0, -terms.slope / terms.curvature, 0.0)
        # A step larger than 2 cm is a wrong basin: keep the correlation estimate there.
        step = np.where(np.abs(step) < 0.02, step, 0.0)
        nodes = nodes + rays * step[:, None]
    return nodes


def _window_std(strip: np.ndarray, half_size: int) -> np.ndarray:
    """Standard deviation of every full (2 h + 1)^2 window along a (2 h + 1, W) strip."""
    size = 2 * half_size + 1
    mean = cv2.boxFilter(strip, -1, (size, size), borderType=cv2.BORDER_ISOLATED)
    mean_sq = cv2.boxFilter(strip * strip, -1, (size, size), borderType=cv2.BORDER_ISOLATED)
    variance = (
        mean_sq[half_size, half_size:-half_size] - mean[half_size, half_size:-half_size] ** 2
    )
    return np.sqrt(np.maximum(variance, 0.0))


def _rays(rig: StereoRig, left_px: np.ndarray) -> np.ndarray:
    """Left viewing rays (K, 3) with z = 1 through pixels (K, 2)."""
    p = rig.left.p
    x = (left_px[:, 0] - p[0, 2]) / p[0, 0]
    y = (left_px[:, 1] - p[1, 2]) / p[1, 1]
    return np.stack([x, y, np.ones_like(x)], axis=1)


def _parabola_peak(response: np.ndarray, best: int) -> float:
    """Sub-sample offset in [-0.5, 0.5] of a peak from the parabola through three samples."""
    if best == 0 or best == response.size - 1:
        return 0.0
    before, at, after = response[best - 1], response[best], response[best + 1]
    curvature = before - 2.0 * at + after
    if curvature >= 0:
        return 0.0
    return float(np.clip(0.5 * (before - after) / curvature, -0.5, 0.5))


def _trimmed_reference(
    topology: MeshTopology, nodes: np.ndarray, use: np.ndarray, config: StereoInitConfig
) -> np.ndarray:
    """The reference face (N, 3) fitted to the nodes marked ``use``, trimming outliers.

    The worst node is dropped from ``use`` (in place) until all agree with the fitted face
    within ``config.max_face_error``.

    Raises:
        InputError: when fewer than :data:`MIN_FIT_NODES` nodes remain.
    """
    while True:
        if use.sum() < MIN_FIT_NODES:
            msg = (
                f'only {counted(int(use.sum()), "inner (non-boundary) node")} matched in the '
                f'right image consistently with a face (need {MIN_FIT_NODES}); check the rig '
                'calibration, the initial positions and that both images show the whole face '
                'with some texture (exposure, focus)'
            )
            raise InputError(msg)
        reference = _fit_reference(topology, nodes, use)
        errors = np.where(use, np.linalg.norm(nodes - reference, axis=1), -1.0)
        worst = int(np.argmax(errors))
        if errors[worst] <= config.max_face_error:
            return reference
        use[worst] = False


def face_scale(topology: MeshTopology, nodes: np.ndarray, use: np.ndarray) -> float:
    """The size of the face the nodes marked ``use`` span, in sizes of the reference face."""
    source, target = np.asarray(topology.reference_shape)[use], nodes[use]
    spread_source = np.linalg.norm(source - source.mean(axis=0))
    return float(np.linalg.norm(target - target.mean(axis=0)) / spread_source)


def check_face_scale(
    initial: InitialNodes, topology: MeshTopology, rig: StereoRig, config: StereoInitConfig
) -> None:
    """Refuse initial nodes whose matched ones span a face too small or too large to be one.

    The calibration does not fit the images then (see ``config.min_face_scale``). Sizes
    triangulated by a rectified rig scale with its baseline B, so the message gives the
    baseline that would make the face adult-sized: B / scale.

    Raises:
        InputError: naming the size, that baseline and what else to check.
    """
    scale = face_scale(topology, initial.nodes, initial.matched)
    if not config.min_face_scale <= scale <= config.max_face_scale:
        tx = float(rig.right.p[0, 3])
        msg = (
            f'the matched inner nodes triangulate to a face {scale:.2f} times the size of an '
            f'adult face (allowed {config.min_face_scale:g}-{config.max_face_scale:g}): the '
            f'stereo calibration does not fit these images. Check its baseline first: the right '
            f"camera_info's P[0,3] = {tx:.4g} (-fx B) gives B = {rig.baseline:.4g} m, and an "
            f'adult-sized face needs B = {rig.baseline / scale:.3g} m (P[0,3] = '
            f'{tx / scale:.4g}); then the focal length, that raw images are rectified (rectify) '
            'and that the initial positions are on the face'
        )
        raise InputError(msg)


def check_in_view(initial: InitialNodes, topology: MeshTopology, rig: StereoRig) -> None:
    """Refuse initial nodes that the track would lose at once: the cameras do not see them.

    :func:`~.stereo_loss.view_problem`: an inner node outside either image (the right camera
    sees the face f B / z px further to the side than the left one), or a face-edge node
    outside both.

    Raises:
        InputError: naming the nodes and what to do.
    """
    problem = view_problem(initial.nodes, rig, topology)
    if problem:
        msg = (
            f'{problem}: the eyes, nose, mouth and brows must be inside both images and the '
            "face's edge inside one at least; move the face towards the middle of the frame (or "
            'the rig away from it)'
        )
        raise InputError(msg)


def check_baseline(rig: StereoRig, config: StereoInitConfig) -> None:
    """Refuse a rig whose baseline shows no face of the depth range in both images.

    A point at depth Z appears fx B / Z px further left in the right image than in the left
    (its disparity); a face ``config.max_depth`` away or nearer is shifted by at least
    fx B / max_depth px, and beyond the image's width no part of it is in both images. A
    baseline given in millimetres (CameraInfo's P[0,3] = -fx B takes metres) is 1000 times too
    large: a 0.11 m rig of fx 600 px reads B = 110 m, 33000 px at 2 m.

    Raises:
        InputError: naming the baseline and the likely unit mistake first (a replay's summary
            keeps a problem's first 200 characters), then the shift.
    """
    fx, tx = float(rig.right.p[0, 0]), float(rig.right.p[0, 3])
    least = fx * rig.baseline / config.max_depth
    if least >= rig.right.width:
        msg = (
            f"the right camera_info's P[0,3] = {tx:.4g} (-fx B) gives a baseline B = "
            f'{rig.baseline:.4g} m: is it in millimetres? P[0,3] takes B in metres '
            f'({rig.baseline / 1000:.4g} m: P[0,3] = {tx / 1000:.4g}). A face '
            f'{config.min_depth:g}-{config.max_depth:g} m away would be {least:.0f} px or more '
            f'apart between the images, wider than they are ({rig.right.width} px): no face is '
            'seen by both cameras'
        )
        raise InputError(msg)


def _fit_reference(topology: MeshTopology, nodes: np.ndarray, use: np.ndarray) -> np.ndarray:
    """The reference face (N, 3) moved and scaled onto the nodes marked ``use``."""
    reference = np.asarray(topology.reference_shape)
    scale = face_scale(topology, nodes, use)
    weights = topology.alignment_weights()[use]
    alignment = rigid_align(scale * reference[use], nodes[use], weights)
    return scale * reference @ alignment.rotation.T + alignment.t
