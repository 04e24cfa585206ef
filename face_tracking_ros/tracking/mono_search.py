"""Where a lost face is: a view of its inner face found in an image by correlation.

The monocular tracker re-acquires a lost face without a detector: it solves eq. 6 against the
keyframe templates from the initial pose translated parallel to the image plane onto the spot
where frame 1's inner face (the nodes off the face edge) correlates best with the image
(normalised cross-correlation, robust to a gain and bias), and while LOST also against the
templates of the bundle adjustment's views nearest the last valid pose, from where each view's
inner face correlates best near where the face was. After dropped images it also solves eq. 6 of
a followed frame from where the last valid frame's inner face correlates best.
:class:`FaceView` is such a view.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from face_tracking_ros.imaging import ImagePyramid

# Pyramid level of the search for a lost face (or the coarsest, if coarser): on the coarsest level
# of a 320x240 image the inner face is 11x12 px and correlates as well with clutter.
_SEARCH_LEVEL = 1


class FaceView(NamedTuple):
    """A frame's inner face on the search's pyramid level.

    Attributes:
        image: (h, w) crop of that level around the inner nodes.
        corner: (2,) pixel (x, y) of the crop's top-left sample on that level.
    """

    image: np.ndarray
    corner: np.ndarray

    @classmethod
    def of(cls, pyramid: ImagePyramid, nodes_px: np.ndarray, inner: np.ndarray) -> FaceView:
        """The crop of the search level spanned by the inner nodes.

        Args:
            pyramid: the frame's pyramid.
            nodes_px: (N, 2) level-0 pixels of the nodes.
            inner: (N,) the nodes off the face edge.
        """
        level = _search_level(pyramid)
        image = pyramid.levels[level]
        size = np.array(image.shape[::-1])
        points = ImagePyramid.to_level(nodes_px[inner], level)
        low = np.clip(np.floor(points.min(axis=0)), 0, size - 1).astype(int)
        high = np.clip(np.ceil(points.max(axis=0)) + 1, low + 1, size).astype(int)
        return cls(image[low[1] : high[1], low[0] : high[0]].copy(), low)

    def shift(
        self, pyramid: ImagePyramid, expected: np.ndarray | None = None, reach: float = math.inf
    ) -> np.ndarray:
        """(2,) level-0 px from where the face was to where it correlates best in ``pyramid``.

        Args:
            pyramid: the image's pyramid.
            expected: (2,) level-0 px, the shift the search is centred on (0 if None).
            reach: the farthest searched from ``expected`` in x and in y, in the view's larger
                side (the whole image if inf).
        """
        level = _search_level(pyramid)
        image = pyramid.levels[level]
        size = np.array(image.shape[::-1])
        scale = float(1 << level)
        centre = self.corner if expected is None else self.corner + expected / scale
        steps, view = reach * max(self.image.shape), np.array(self.image.shape[::-1])
        low = np.clip(np.round(centre - steps), 0, size - view).astype(int)
        high = np.clip(np.round(centre + steps) + view, low + view, size).astype(int)
        window = image[low[1] : high[1], low[0] : high[0]]
        scores = cv2.matchTemplate(window, self.image, cv2.TM_CCOEFF_NORMED)
        best = np.unravel_index(np.argmax(scores), scores.shape)[::-1]
        return (np.array(best) + low - self.corner) * scale


def _search_level(pyramid: ImagePyramid) -> int:
    """The pyramid level the face is searched on."""
    return min(_SEARCH_LEVEL, pyramid.num_levels - 1)


class PendingView:
    """A frame's :class:`FaceView`, cropped when first asked for or before its pyramid is reused.

    The tracker keeps the last valid frame's view for the search after dropped images, which
    few frames need: a crop on every tracked frame cost some 66 us (640x480). The pyramid is a
    buffer the tracker rebuilds in place for a later image; it crops the view first
    (:meth:`reads`, :meth:`view`).

    Args:
        pyramid: the frame's pyramid.
        nodes_px: (N, 2) level-0 pixels of the nodes.
        inner: (N,) the nodes off the face edge.
    """

    def __init__(self, pyramid: ImagePyramid, nodes_px: np.ndarray, inner: np.ndarray) -> None:
        """Keep what the crop needs."""
        self._pyramid: ImagePyramid | None = pyramid
        self._nodes = (nodes_px, inner)
        self._view: FaceView | None = None

    def reads(self, pyramid: ImagePyramid) -> bool:
        """Whether the view is still to be cropped from ``pyramid``."""
        return self._pyramid is pyramid

    def view(self) -> FaceView:
        """The view, cropped now if it was not yet."""
        if self._view is None:
            self._view = FaceView.of(self._pyramid, *self._nodes)
            self._pyramid = None
        return self._view
