"""The right camera's gain relative to the left, measured on the node patches (stereo, eq. 4).

Eq. 4's cross-camera terms compare a node patch in one camera with the same patch in the other.
Their ZSSD residual (:mod:`.stereo_data`) ignores a brightness offset and ramp between the views,
but not a difference of gain: two cameras of a rig rarely expose alike (auto exposure, another
sensor or aperture), and then the residual keeps the patch's texture times the gain difference,
which the solver partly reads as motion and depth. On issue 5's 380-frame training sequences
(19 nodes, 24 subjects of two synthetic populations) a right camera 15 % brighter than the left
raised node RMS from 0.82 to 1.09 mm and the drift from 0.32 to 0.45 mm, the subjects above 1 px
of reprojection error from 8 to 12; 13 % darker, node RMS 0.98 mm.

The stereo tracker therefore measures the gain when it initialises (the
:class:`~.stereo_config.StereoTrackerConfig` ``gain_compensation``) and divides it out of every
right image. Per node patch, the contrast (RMS about the patch's mean) of its samples in the right
image over that in the left is the gain: both sample the same skin, and a contrast hardly
depends on where the patch is sampled exactly, so the initial nodes, millimetres off in depth,
serve. The median over the textured patches ignores the few whose views differ (a highlight,
the rim). On those sequences it measured 1.15 as 1.11-1.20 and equal cameras as 0.98-1.03, and
with it (and the row-offset correction, :mod:`.row_offset`) a gain of 1.15 or 0.87 gave the
figures of equal cameras: node RMS 0.83 mm, drift 0.33 mm, 8-9 subjects above 1 px, largest
error 1.19-1.22 px (equal cameras 0.83 mm, 8, 1.20 px; with neither correction 0.82 mm, 8, 1.18
px). Measured once per initialisation, a gain that changes during a track is not followed.
Measured on every pair instead (smoothed over 20 pairs, in a first version that scaled the
cross-camera templates), it spread over 1.11-1.20 for a gain of 1.15 and the drift doubled.
"""

from __future__ import annotations

import numpy as np

from face_tracking_ros.tracking.stereo_data import group_contrast

MIN_PATCHES = 3  # textured patches below which the gain is taken as 1 (not measured)
GAIN_RESOLUTION = 0.03  # the measurement's spread: equal cameras measured 0.98-1.03


def relative_gain(values: np.ndarray, mask: np.ndarray, floor: float) -> float:
    """The right image's gain relative to the left from node patches sampled in both.

    Args:
        values: (2, N, M) grey levels of N node patches of M samples each, in the left image
            (row 0) and the right image (row 1), at the same surface points.
        mask: (N, M) the samples in use (a patch on the rim keeps one side).
        floor: grey levels; a patch whose contrast is not above this in both images (flat
            skin, within the sensor noise) does not count.

    Returns:
        The median over the counted patches of their contrast in the right image over that in
        the left, or 1.0 when fewer than :data:`MIN_PATCHES` count.
    """
    used = mask & np.all(np.isfinite(values), axis=0)
    contrast = group_contrast(values, np.broadcast_to(used, values.shape))  # (2, N)
    counted = np.all(contrast > floor, axis=0)  # NaN (no sample in use) is not above it
    if counted.sum() < MIN_PATCHES:
        return 1.0
    return float(np.median(contrast[1, counted] / contrast[0, counted]))
