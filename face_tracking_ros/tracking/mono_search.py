"""Where a lost face is: a view of its inner face found in an image by correlation.

The monocular tracker re-acquires a lost face without a detector: it solves eq. 6 against the
keyframe templates from the initial pose translated parallel to the image plane onto the spot
where frame 1's inner face (the nodes off the face edge) correlates best with the image
(normalised cross-correlation, robust to a gain and bias). After dropped images it also solves
eq. 6 of a followed frame from where the last valid frame's inner face correlates best.
:class:`FaceView` is such a view.
"""

from __future__ import annotations

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

    def shift(self, pyramid: ImagePyramid) -> np.ndarray:
        """(2,) level-0 px from where the face was to where it correlates best in ``pyramid``."""
        level = _search_level(pyramid)
        scores = cv2.matchTemplate(pyramid.levels[level], self.image, cv2.TM_CCOEFF_NORMED)
        best = np.unravel_index(np.argmax(scores), scores.shape)[::-1]
        return (np.array(best) - self.corner) * float(1 << level)


def _search_level(pyramid: ImagePyramid) -> int:
    """The pyramid level the face is searched on."""
    return min(_SEARCH_LEVEL, pyramid.num_levels - 1)
