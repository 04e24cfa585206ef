"""The box a tracker's sample pixels span, compiled: the pyramid makes level 0 over it.

Both trackers' compiled map makers (the mono tracker's
:func:`~.mono_kernels.roi_maps`, the stereo tracker's :func:`~.stereo_kernels.stencil_maps`)
return, beside the ``cv2.remap`` maps of their samples, the least and greatest x and y of the
pixels, over which :meth:`~face_tracking_ros.imaging.ImagePyramid.level_reaching` makes a
pyramid level; :func:`span` finds them in the same pass.
"""

from __future__ import annotations

import numba
import numpy as np

from face_tracking_ros.compiled import FAST


@numba.njit(**FAST)
def span(values: np.ndarray) -> tuple[float, float]:
    """The least and greatest of (K,) values (K > 0) with no NaN; 8 running extremes at once."""
    lanes = 8
    low, high = np.full(lanes, values[0]), np.full(lanes, values[0])
    whole = values.size - values.size % lanes
    for i in range(0, whole, lanes):
        for j in range(lanes):
            value = values[i + j]
            low[j] = value if value < low[j] else low[j]
            high[j] = value if value > high[j] else high[j]
    least, greatest = low.min(), high.max()
    for i in range(whole, values.size):
        least, greatest = min(least, values[i]), max(greatest, values[i])
    return least, greatest
