"""The checks that declare the stereo track lost (§3.3; the mono tracker's are :mod:`.mono_loss`).

Loss of track gives status LOST with the last valid nodes. A pair's solution is declared lost
when a node is not finite, lies behind the camera or projects outside both images, when fewer
than half the nodes project inside both images, or when the node patches
(:class:`~.stereo_data.GroupStatistics` of level 0, both cameras) tell that the images no longer
show the face tracked:

    median_i r_i / c_i > ``lost_ratio``            the patches do not match their templates
                                                   (``gap_lost_ratio`` if lower, for a pair
                                                   after a gap or re-acquiring a lost track)
    median_i t_i / c_i < ``min_texture_ratio``     the images show almost no texture there

medians over the node patches i of both images, with r_i the RMS of patch i's residual against
its frame n - 1 template in the same camera (brightness ramp or, face-edge nodes, mean removed;
about c_i for an unrelated image), c_i the template's contrast (the standard deviation of its
grey levels) and t_i the image's. A blank or dark pair passes the first test (its residual is
the template's own contrast less the ramp), hence the second.

A node that one camera does not see is carried by the other camera's terms of eq. 4, eq. 5 and
the face-model term (its samples outside an image are not used): a face near the side of the
frame, whose nearer edge the other camera sees beyond its image (f B / z px further: 100 px at
0.65 m on a 0.11 m, 600 px rig), is tracked, not lost on its first pair. On the synthetic
training sequences whose right image cut off up to 14 of the 34 nodes (the subject's right
half), the tracker kept 2.9-4.2 mm node RMS against 2.7-3.8 mm for faces in full view.
"""

from __future__ import annotations

import numpy as np

from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.imaging import inside_image
from face_tracking_ros.tracking.robust import nanmedian
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_data import GroupStatistics

MIN_SEEN_BY_BOTH = 0.5  # share of the nodes that must project inside both images


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
    shape = (rig.left.height, rig.left.width)
    inside = np.stack(
        [inside_image(camera.project(nodes), shape) for camera in (rig.left, rig.right)]
    )
    if not np.all(inside.any(axis=0)):
        return 'a node left both images'
    if np.count_nonzero(inside.all(axis=0)) < MIN_SEEN_BY_BOTH * len(nodes):
        return 'fewer than half the nodes are inside both images'
    with np.errstate(invalid='ignore', divide='ignore'):
        ratios = statistics.rms[0] / statistics.contrast
    ratio = nanmedian(ratios)
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
