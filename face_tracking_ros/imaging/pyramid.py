"""Gaussian image pyramids for coarse-to-fine tracking.

Level ``l`` is ``cv2.pyrDown`` applied ``l`` times to the float32 grey image. ``pyrDown``
centres output pixel ``i`` on input pixel ``2 i``, so a point at pixel ``x`` of level 0 lies at
``x / 2**l`` of level ``l`` (:meth:`ImagePyramid.to_level`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from face_tracking_ros.errors import InputError

MIN_LEVEL_SIZE = 8
# The 5-tap binomial kernel cv2.pyrDown smooths with before it drops every other pixel.
_BINOMIAL = np.array([1.0, 4.0, 6.0, 4.0, 1.0], dtype=np.float32) / 16.0


@dataclass(frozen=True)
class ImagePyramid:
    """A float32 Gaussian pyramid of one grey image.

    Attributes:
        levels: images of level 0 (full resolution) to L-1, each (H_l, W_l) float32 grey levels
            in [0, 255].
    """

    levels: tuple[np.ndarray, ...]

    @classmethod
    def build(cls, gray: np.ndarray, num_levels: int, smooth_base: bool = False) -> ImagePyramid:
        """Build a pyramid of ``num_levels`` levels.

        Args:
            gray: (H, W) uint8 or float grey image.
            num_levels: number of levels, >= 1.
            smooth_base: smooth level 0 with pyrDown's binomial kernel (sigma ~ 1 px). Bilinear
                sampling of a sharp image is biased towards whole-pixel positions; smoothing
                removes most of that bias at the cost of one filter pass. Level 1 is then level 0
                decimated, identical to ``pyrDown`` of the unsmoothed image.

        Raises:
            InputError: if the image is not 2-D, not finite, or too small for the levels asked
                (the coarsest level must keep at least 8x8 pixels).
        """
        gray = np.asarray(gray)
        if gray.ndim != 2:
            msg = f'pyramid input must be a (H, W) grey image, got shape {gray.shape}'
            raise InputError(msg)
        if num_levels < 1 or min(gray.shape) >> (num_levels - 1) < MIN_LEVEL_SIZE:
            msg = f'cannot build {num_levels} pyramid levels from a {gray.shape} image'
            raise InputError(msg)
        base = gray.astype(np.float32)
        if not np.all(np.isfinite(base)):
            msg = 'pyramid input holds NaN or Inf'
            raise InputError(msg)
        levels = [base]
        if smooth_base:
            levels[0] = cv2.sepFilter2D(
                base, -1, _BINOMIAL, _BINOMIAL, borderType=cv2.BORDER_REFLECT_101
            )
            if num_levels > 1:
                levels.append(np.ascontiguousarray(levels[0][::2, ::2]))
        while len(levels) < num_levels:
            levels.append(cv2.pyrDown(levels[-1]))
        return cls(levels=tuple(levels))

    @property
    def num_levels(self) -> int:
        """Number of levels L."""
        return len(self.levels)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of level 0."""
        height, width = self.levels[0].shape
        return height, width

    @staticmethod
    def to_level(points: np.ndarray, level: int) -> np.ndarray:
        """Level-0 pixel coordinates (..., 2) mapped to level ``level``."""
        return np.asarray(points) / float(1 << level)
