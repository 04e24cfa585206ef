"""The vertical offset between the rows of a rectified pair, measured at the nodes (stereo).

A rectified rig puts every point on the same row in both images, and the stereo tracker relies
on it: a node moves in 3-D, so its two projections move along the same rows, and eq. 4's
cross-camera terms cannot take a vertical offset between the images. Calibration leaves one
(a few tenths of a pixel are common); the terms then read it, on every sloping edge of the
texture, as horizontal disparity, which is depth. On issue 5's 380-frame training sequences
(19 nodes, 24 subjects of two synthetic populations) the right image 0.2 px lower than the
calibration says raised node RMS from 0.82 to 1.32 mm, 0.5 px to 3.06 mm with every subject
above 1 px of reprojection error (8 of 24 without).

So the tracker measures the offset when it initialises (the
:class:`~.stereo_config.StereoTrackerConfig` ``row_offset_correction``) and moves the right
camera's principal point by it. Each matched inner node is followed from its left-image
position into the right image by pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``), starting
where the rig projects the initial node; the median of how far it ends up below that is the offset.
The face-edge nodes do not count: their windows hold background, which the two cameras see
differently. Nodes matched on rows a few pixels off are themselves off (a test plane's 3 px
measured 4.5 px), so while an offset exceeds what the measurement resolves the tracker matches
the nodes again on the corrected pair and measures what is left (:data:`ROW_OFFSET_RESOLUTION_PX`,
up to three rounds; the plane's 3 px then measured 3.02 px). On those sequences it measured 0.5
px as 0.39-0.59 px (0.50 on average) and 0 as -0.05-0.05 px, and with the correction node RMS
was 0.86 mm at 0.2 px and 0.89 mm at 0.5 px (0.86 with the offset known exactly; the shifted
images are resampled); with no offset, 0.83 mm against 0.82 without the correction (largest
reprojection error 1.20 against 1.18 px). On the 34-node mesh (seeds 1 and 3) 0.4 px took node
RMS from 2.76 to 3.27 mm, and with the correction to 2.71 mm. Lucas-Kanade on up to 300 corners
of the face instead of the nodes measured as well (0.025 px standard deviation against
0.027-0.036).
"""

from __future__ import annotations

import cv2
import numpy as np

WINDOW_PX = 21  # Lucas-Kanade window; 11 px spread the per-node offsets three times wider
MIN_NODES = 3  # nodes below which the offset is taken as 0 (not measured)
ROW_OFFSET_RESOLUTION_PX = 0.1  # about twice the measurement's spread (0 measured -0.05-0.05 px)
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.001)


def row_offset(
    left: np.ndarray, right: np.ndarray, left_px: np.ndarray, right_px: np.ndarray
) -> float:
    """How far the right image shows the nodes below where the rig projects them, px.

    Args:
        left: (H, W) left image, grey levels.
        right: (H, W) right image.
        left_px: (K, 2) the nodes' left-image positions.
        right_px: (K, 2) where the rig projects them in the right image.

    Returns:
        The median vertical offset of the nodes Lucas-Kanade follows, or 0.0 when fewer than
        :data:`MIN_NODES` are followed.
    """
    start = np.ascontiguousarray(right_px, dtype=np.float32).reshape(-1, 1, 2)
    found, status, _ = cv2.calcOpticalFlowPyrLK(
        _grey8(left),
        _grey8(right),
        np.ascontiguousarray(left_px, dtype=np.float32).reshape(-1, 1, 2),
        start.copy(),
        winSize=(WINDOW_PX, WINDOW_PX),
        maxLevel=1,
        criteria=_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    followed = status.ravel() == 1
    if followed.sum() < MIN_NODES:
        return 0.0
    return float(np.median(found[followed, 0, 1] - start[followed, 0, 1]))


def _grey8(image: np.ndarray) -> np.ndarray:
    """An 8-bit copy of a grey image (what cv2.calcOpticalFlowPyrLK takes)."""
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
