"""Gaussian image pyramids for coarse-to-fine tracking.

Level ``l`` is ``cv2.pyrDown`` applied ``l`` times to the float32 grey image. ``pyrDown``
centres output pixel ``i`` on input pixel ``2 i``, so a point at pixel ``x`` of level 0 lies at
``x / 2**l`` of level ``l`` (:meth:`ImagePyramid.to_level`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from face_tracking_ros.errors import ConfigError, InputError

MIN_LEVEL_SIZE = 8
MIN_TRACKING_LEVEL_SIZE = 16  # a tracker's coarsest level keeps its node patches inside
# The 5-tap binomial kernel cv2.pyrDown smooths with before it drops every other pixel.
_BINOMIAL = np.array([1.0, 4.0, 6.0, 4.0, 1.0], dtype=np.float32) / 16.0


def _levels_that_fit(side: int, min_size: int) -> int:
    """How many pyramid levels a shorter side of ``side`` px allows, the coarsest >= ``min_size``.

    Level l has ``side >> l`` px.
    """
    return (side // min_size).bit_length()


def check_levels_fit(num_levels: int, width: int, height: int) -> None:
    """Check at set-up that a tracker's pyramid fits its images.

    The coarsest level must keep ``MIN_TRACKING_LEVEL_SIZE`` pixels on its shorter side. A
    deeper pyramid leaves it too small for the node patches, or cannot be built at all, and then
    every frame fails.

    Raises:
        ConfigError: naming ``pyramid_levels`` and how many levels fit.
    """
    fitting = _levels_that_fit(min(width, height), MIN_TRACKING_LEVEL_SIZE)
    if num_levels > fitting:
        msg = (
            f'pyramid_levels = {num_levels} is too deep for {width}x{height} images: at most '
            f'{fitting} leave the coarsest level {MIN_TRACKING_LEVEL_SIZE} px'
        )
        raise ConfigError(msg)


@dataclass(frozen=True)
class ImagePyramid:
    """A float32 Gaussian pyramid of one grey image.

    Attributes:
        levels: images of level 0 (full resolution) to L-1, each (H_l, W_l) float32 grey levels
            (in [0, 255] as built; :meth:`scale` may change that).
        scratch: the (H, W) float32 buffer of the unsmoothed level 0 when level 0 is smoothed
            (kept for ``reuse``; a uint8 image is filtered without it), else None.
    """

    levels: tuple[np.ndarray, ...]
    scratch: np.ndarray | None = field(default=None, repr=False, compare=False)

    @classmethod
    def build(
        cls,
        gray: np.ndarray,
        num_levels: int,
        smooth_base: bool = False,
        reuse: ImagePyramid | None = None,
    ) -> ImagePyramid:
        """Build a pyramid of ``num_levels`` levels.

        Args:
            gray: (H, W) uint8 or float grey image.
            num_levels: number of levels, >= 1.
            smooth_base: smooth level 0 with pyrDown's binomial kernel (sigma ~ 1 px). Bilinear
                sampling of a sharp image is biased towards whole-pixel positions; smoothing
                removes most of that bias at the cost of one filter pass. Level 1 is then level 0
                decimated, identical to ``pyrDown`` of the unsmoothed image.
            reuse: a pyramid no longer needed, built with the same image size, levels and
                ``smooth_base``; its arrays are overwritten and become this pyramid's. A tracker
                building one pyramid per frame so avoids allocating ~2 MB per 640x480 frame, which
                costs ~1 ms of page faults whenever the allocator has returned the previous
                frame's memory to the system. Ignored when it does not match.

        Raises:
            InputError: if the image is not 2-D, not finite, or too small for the levels asked
                (the coarsest level must keep at least 8x8 pixels).
        """
        gray = np.asarray(gray)
        if gray.ndim != 2:
            msg = f'pyramid input must be a (H, W) grey image, got shape {gray.shape}'
            raise InputError(msg)
        if not 1 <= num_levels <= _levels_that_fit(min(gray.shape), MIN_LEVEL_SIZE):
            msg = f'cannot build {num_levels} pyramid levels from a {gray.shape} image'
            raise InputError(msg)
        buffers = _Buffers.of(gray.shape, num_levels, smooth_base, reuse)
        levels = buffers.levels
        if smooth_base and gray.dtype == np.uint8:
            base = gray  # filtered to float32 directly: the same levels without a float copy
        else:
            base = buffers.base
            base[...] = gray
            if not np.issubdtype(gray.dtype, np.integer) and not np.all(np.isfinite(base)):
                msg = 'pyramid input holds NaN or Inf'
                raise InputError(msg)
        if smooth_base:
            cv2.sepFilter2D(
                base,
                cv2.CV_32F,
                _BINOMIAL,
                _BINOMIAL,
                dst=levels[0],
                borderType=cv2.BORDER_REFLECT_101,
            )
            if num_levels > 1:
                levels[1][...] = levels[0][::2, ::2]
        for level in range(2 if smooth_base else 1, num_levels):
            cv2.pyrDown(levels[level - 1], dst=levels[level])
        return cls(levels=levels, scratch=buffers.scratch)

    def scale(self, factor: float) -> None:
        """Multiply the grey levels of every level by ``factor``, in place.

        Every level is linear in the image, so this gives the pyramid of the scaled image
        without building it again: how the stereo tracker divides the right camera's gain
        relative to the left out of the right images
        (:mod:`~face_tracking_ros.tracking.camera_gain`).
        """
        for level in self.levels:
            level *= np.float32(factor)

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


class _Buffers(NamedTuple):
    """Arrays a pyramid is built into: the float32 copy of the image and the levels."""

    base: np.ndarray
    levels: tuple[np.ndarray, ...]
    scratch: np.ndarray | None

    @classmethod
    def of(
        cls,
        shape: tuple[int, int],
        num_levels: int,
        smooth_base: bool,
        reuse: ImagePyramid | None,
    ) -> _Buffers:
        """The arrays of ``reuse`` when they fit, otherwise new ones."""
        sizes = [
            ((shape[0] + (1 << k) - 1) >> k, (shape[1] + (1 << k) - 1) >> k)
            for k in range(num_levels)
        ]
        fits = (
            reuse is not None
            and [level.shape for level in reuse.levels] == sizes
            and (reuse.scratch is not None) == smooth_base
        )
        if fits:
            levels = reuse.levels
            scratch = reuse.scratch
        else:
            levels = tuple(np.empty(size, dtype=np.float32) for size in sizes)
            scratch = np.empty(shape, dtype=np.float32) if smooth_base else None
        return cls(base=levels[0] if scratch is None else scratch, levels=levels, scratch=scratch)
