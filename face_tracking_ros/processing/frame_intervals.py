"""How many frame intervals passed between two tracked images, from their stamps.

A tracker predicts each frame's motion from the last ones and limits the rotation per frame, so
it must know when images were dropped: a bag with missing frames, or a live node whose depth-1
image queue keeps only the newest image while the tracker is busy. The stamps tell: an image
that follows the one before by n frame intervals came after n - 1 dropped ones.

The stream's frame interval is estimated as a low quantile (:data:`QUANTILE`) of the last
:data:`WINDOW` stamp differences: dropped images only lengthen differences, so the quantile
stays the interval while up to three quarters of the images follow a gap, and it stays
within the stamps' jitter of it (a median would take the interval of a tracker that drops every
other image to be two frames).
"""

from __future__ import annotations

from collections import deque

import numpy as np

WINDOW = 32  # stamp differences kept
QUANTILE = 0.25  # of the differences kept: the frame interval


class FrameIntervals:
    """The frame intervals of a stream's stamps (see the module's docstring)."""

    def __init__(self) -> None:
        """No stamp difference yet."""
        self._differences: deque[int] = deque(maxlen=WINDOW)

    def since(self, previous_ns: int | None, stamp_ns: int) -> int:
        """Frame intervals from ``previous_ns`` to ``stamp_ns``: ``max(1, round(dt / interval))``.

        Args:
            previous_ns: the stamp of the image tracked before, ns; None for the first image of
                a track's stream (after a restart): 1, and no difference is kept.
            stamp_ns: this image's stamp, ns (later than ``previous_ns``).
        """
        if previous_ns is None:
            return 1
        difference = stamp_ns - previous_ns
        self._differences.append(difference)
        interval = float(np.quantile(np.array(self._differences), QUANTILE))
        return max(1, round(difference / interval))
