"""The checks that declare the stereo track lost (§3.3; the mono tracker's are :mod:`.mono_loss`).

Loss of track gives status LOST with the last valid nodes. A pair's solution is declared lost
when a node is not finite or lies behind the camera, when the cameras do not see the face's
nodes (:func:`view_problem`), or when the node patches (:class:`~.stereo_data.GroupStatistics`
of level 0, both cameras) tell that the images no longer show the face tracked:

    median_i r_i / c_i > ``lost_ratio``            the patches do not match their templates
                                                   (``gap_lost_ratio`` if lower, for a pair
                                                   after a gap or re-acquiring a lost track)
    median_i t_i / c_i < ``min_texture_ratio``     the images show almost no texture there

medians over the node patches i of both images, with r_i the RMS of patch i's residual against
its frame n - 1 template in the same camera (brightness ramp or, face-edge nodes, mean removed;
about c_i for an unrelated image), c_i the template's contrast (the standard deviation of its
grey levels) and t_i the image's. A blank or dark pair passes the first test (its residual is
the template's own contrast less the ramp), hence the second.
"""

from __future__ import annotations

import numpy as np

from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.imaging import inside_image
from face_tracking_ros.model.topology import Group, MeshTopology, mesh_topology
from face_tracking_ros.tracking.robust import nanmedian
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_data import GroupStatistics


def view_problem(
    nodes: np.ndarray, rig: StereoRig, topology: MeshTopology, slack: float = 0.0
) -> str:
    """What keeps the cameras from seeing the face's nodes, naming them ('' if nothing does).

    Every inner node (eyes, nose, mouth, brows) must project inside both images: its depth is
    measured between them. A face-edge node needs one of them only: its depth comes from the
    reference face and the face-model term whether the other camera sees it or not (the solve
    leaves out samples outside an image), and a face near the side of the frame shows its
    nearer edge to one camera only (the other sees it f B / z px further to the side: 100 px at
    0.65 m on a 0.11 m, 600 px rig). Until 2026-12-06 any node outside either image lost the
    track on the pair after the initialisation. Inner nodes that the right camera misses are
    a guess: the reference face fitted to the rest of a synthetic face put them up to 24 mm off
    in depth.

    Args:
        nodes: (N, 3) nodes in the left camera frame, m, in front of both cameras.
        rig: the rig (its image size and projections).
        topology: the mesh (its face-edge nodes).
        slack: how far outside an image a node may project and still count as seen, px: 0 at
            the initialisation, the node patch's half size while tracking (:func:`loss_reason`).
    """
    shape = (rig.left.height, rig.left.width)
    edge = topology.group_mask(Group.EDGE)
    seen = [inside_image(camera.project(nodes), shape, -slack) for camera in (rig.left, rig.right)]
    missing = [
        (f'inner nodes outside the {name} image', ~inside & ~edge)
        for name, inside in zip(('left', 'right'), seen, strict=True)
    ]
    missing.append(('face-edge nodes outside both images', ~(seen[0] | seen[1])))
    for problem, mask in missing:
        if mask.any():
            names = ', '.join(topology.node_names[i] for i in np.flatnonzero(mask))
            return f'{problem} ({names})'
    return ''


def loss_reason(
    nodes: np.ndarray,
    statistics: GroupStatistics,
    rig: StereoRig,
    config: StereoTrackerConfig,
    after_gap: bool = False,
) -> str:
    """Why the solution is not a valid track ('' if it is).

    Args:
        nodes: (N, 3) the pair's solution, left camera frame, m.
        statistics: the residual summaries of its last accepted point, level 0.
        rig: the rig tracked with (its image size and projections).
        config: the tracker's tunables (the checks': ``lost_ratio``, ``min_texture_ratio``,
            ``gap_lost_ratio``).
        after_gap: whether the pair comes after dropped pairs or bad frames, or re-acquires a
            lost track: its residual is checked against the stricter of ``lost_ratio`` and
            ``gap_lost_ratio``.
    """
    if not np.all(np.isfinite(nodes)):
        return 'non-finite nodes'
    if np.any(nodes[:, 2] <= 0):
        return 'a node went behind the camera'
    # A node counts as seen while its patch reaches into the image: the initialisation asks for
    # its centre inside, so a node near the side does not flip the track between LOST and
    # TRACKING as its estimate moves a pixel (synth subject_00, both images cropped by 215
    # columns, 1 px clicks: right_brow_outer 0.4-3.6 px inside the right image and its estimate
    # 1.3 px further out, 19 of 60 pairs LOST with a centre-inside rule).
    problem = view_problem(nodes, rig, mesh_topology(len(nodes)), config.patch_half_size)
    if problem:
        return problem
    ratio = residual_ratio(statistics)
    limit = min(config.lost_ratio, config.gap_lost_ratio) if after_gap else config.lost_ratio
    if not ratio <= limit:
        return f'patch residual / contrast {ratio:.2f} exceeds {limit}'
    with np.errstate(invalid='ignore', divide='ignore'):
        texture = nanmedian(statistics.image_contrast / statistics.contrast)
    if not texture >= config.min_texture_ratio:
        return (
            f'the images show almost no texture where the face was (patch contrast '
            f'{texture:.2f} of the template contrast, below {config.min_texture_ratio})'
        )
    return ''


def patch_ratios(statistics: GroupStatistics) -> np.ndarray:
    """(C, N) r_i / c_i of every node patch in each image (NaN where it has no valid sample)."""
    with np.errstate(invalid='ignore', divide='ignore'):
        return statistics.rms[0] / statistics.contrast


def residual_ratio(statistics: GroupStatistics) -> float:
    """median_i r_i / c_i over the node patches of both images (see the module's docstring)."""
    return nanmedian(patch_ratios(statistics))


def residual_total(statistics: GroupStatistics) -> float:
    """sum_i (r_i / c_i)^2 over the node patches of both images: a few nodes' residual counts."""
    return float(np.nansum(patch_ratios(statistics) ** 2))
