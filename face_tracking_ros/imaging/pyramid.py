"""Gaussian image pyramids for coarse-to-fine tracking.

Level ``l`` is ``cv2.pyrDown`` applied ``l`` times to the float32 grey image. ``pyrDown``
centres output pixel ``i`` on input pixel ``2 i``, so a point at pixel ``x`` of level 0 lies at
``x / 2**l`` of level ``l`` (:meth:`ImagePyramid.to_level`).
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import cv2
import numpy as np

from face_tracking_ros.errors import ConfigError, InputError

MIN_LEVEL_SIZE = 8
MIN_TRACKING_LEVEL_SIZE = 16  # a tracker's coarsest level keeps its node patches inside
# The 5-tap binomial kernel cv2.pyrDown smooths with before it drops every other pixel.
_BINOMIAL = np.array([1.0, 4.0, 6.0, 4.0, 1.0], dtype=np.float32) / 16.0
# The samples at a point x read pixels floor(x) - 1 to floor(x) + 3: bilinear ones (+1) at x and
# one pixel either side (central differences), each point rounded to 1/32 px by cv2.remap.
_SAMPLE_REACH = 3
# Pixels of level 0 made around the box that a read reaches, so that a solve's next steps find
# them made.
_BOX_MARGIN = 16


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


class ImagePyramid:
    """A float32 Gaussian pyramid of one grey image, made as it is read.

    :attr:`levels` gives every level in full. A tracker that samples a few patches of a frame
    reads them through :meth:`level` instead: the coarser levels, which need all of level 0,
    are made when first asked for, and a smoothed level 0 (``smooth_base``) only over the box
    its samples reach, a face's patches being a tenth or so of a 640x480 frame. Every value
    read either way is the full build's: smoothing a box of the image with a 2-px border of it
    gives the values of smoothing the whole image, whose reflected border lies at its own
    edges; to the bit for an 8-bit image (its weighted sums are exact in float32), within
    float32 rounding for a float one (the filter's vector and scalar paths meet at other
    columns).
    """

    def __init__(
        self,
        levels: Sequence[np.ndarray],
        source: np.ndarray | None = None,
        coarse_made: bool = True,
    ) -> None:
        """A pyramid of ``levels`` (level 0 first, float32), complete unless told otherwise.

        Args:
            levels: the levels, or buffers for those still to be made (:meth:`build`).
            source: the (H, W) grey image (uint8 or float32, owned by the pyramid) that level 0
                is still to be made from, smoothed; None if level 0 is made.
            coarse_made: whether the coarser levels are made.
        """
        self._levels = tuple(levels)
        self._source = source
        self._smoothed = source is not None
        height, width = self._levels[0].shape
        # The box of level 0 made so far, (x0, y0, x1, y1) exclusive, and whether all is.
        self._box = (0, 0, width, height) if source is None else (0, 0, 0, 0)
        self._complete = source is None and (coarse_made or len(self._levels) == 1)

    @classmethod
    def build(
        cls,
        gray: np.ndarray,
        num_levels: int,
        smooth_base: bool = False,
        reuse: ImagePyramid | None = None,
    ) -> ImagePyramid:
        """The pyramid of ``num_levels`` levels of ``gray``, made as it is read.

        Args:
            gray: (H, W) uint8 or float grey image, copied (the caller may reuse its buffer).
            num_levels: number of levels, >= 1.
            smooth_base: smooth level 0 with pyrDown's binomial kernel (sigma ~ 1 px). Bilinear
                sampling of a sharp image is biased towards whole-pixel positions; smoothing
                removes most of that bias at the cost of one filter pass. Level 1 is then level 0
                decimated, identical to ``pyrDown`` of the unsmoothed image.
            reuse: a pyramid no longer needed, built from an image of the same size and type
                with the same levels and smoothing; its arrays are overwritten and become this
                pyramid's. A tracker building one pyramid per frame so avoids allocating ~2 MB
                per 640x480 frame, which costs ~1 ms of page faults whenever the allocator has
                returned the previous frame's memory to the system. Ignored when it does not
                match.

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
        source, levels = cls._buffers(gray, num_levels, smooth_base, reuse)
        copy = levels[0] if source is None else source
        copy[...] = gray
        if not np.issubdtype(gray.dtype, np.integer) and not np.all(np.isfinite(copy)):
            msg = 'pyramid input holds NaN or Inf'
            raise InputError(msg)
        return cls(levels, source, coarse_made=False)

    @property
    def levels(self) -> tuple[np.ndarray, ...]:
        """Images of level 0 (full resolution) to L-1, each (H_l, W_l) float32 grey levels.

        In [0, 255] as built (:meth:`scale` may change that); every level made in full.
        """
        self._make_all()
        return self._levels

    def level(self, index: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Level ``index``, made at least where samples at points (x, y) of it read it.

        The samples: bilinear ones at the points (``cv2.remap``) and one pixel either side
        (central differences, :func:`~.sampling.sample_with_gradient_xy`). Level 0 is made over
        the box they reach and a margin (``_BOX_MARGIN``), so that a solve's later steps near
        the same points find it made; a coarser level is made in full.

        Raises:
            InputError: if the points hold NaN or Inf while level 0 is still being made (the
                samplers refuse such points in any case).
        """
        if index > 0 or self._source is None or self._complete or not np.size(x):
            return self.level_reaching(index, (0.0, -1.0, 0.0, -1.0))  # nothing to make there
        x, y = np.asarray(x), np.asarray(y)
        return self.level_reaching(index, (x.min(), x.max(), y.min(), y.max()))  # methods: faster

    def level_reaching(self, index: int, box: Sequence[float]) -> np.ndarray:
        """:meth:`level` for points spanning ``box``: their least and greatest x, then y.

        An empty box (least above greatest) reads nothing.

        Raises:
            InputError: if the box is not finite while level 0 is still being made.
        """
        if index > 0:
            self._make_all()
            return self._levels[index]
        low_x, high_x, low_y, high_y = box
        if self._source is not None and not self._complete:
            if not math.isfinite(low_x + high_x + low_y + high_y):
                msg = 'points hold NaN or Inf'
                raise InputError(msg)
            if low_x > high_x:
                return self._levels[0]
            # Clipped to the image, keeping its border pixel: points beyond it read that.
            height, width = self.shape
            self._make_base(
                (
                    min(max(math.floor(low_x) - _SAMPLE_REACH, 0), width - 1),
                    min(max(math.floor(low_y) - _SAMPLE_REACH, 0), height - 1),
                    min(max(math.floor(high_x) + _SAMPLE_REACH + 1, 1), width),
                    min(max(math.floor(high_y) + _SAMPLE_REACH + 1, 1), height),
                )
            )
        return self._levels[index]

    def scale(self, factor: float) -> None:
        """Multiply the grey levels of every level by ``factor``, in place.

        Every level is linear in the image, so this gives the pyramid of the scaled image
        without building it again: how the stereo tracker divides the right camera's gain
        relative to the left out of the right images
        (:mod:`~face_tracking_ros.tracking.camera_gain`). Every level is made first.
        """
        for level in self.levels:
            level *= np.float32(factor)

    @property
    def num_levels(self) -> int:
        """Number of levels L."""
        return len(self._levels)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of level 0."""
        height, width = self._levels[0].shape
        return height, width

    @staticmethod
    def to_level(points: np.ndarray, level: int) -> np.ndarray:
        """Level-0 pixel coordinates (..., 2) mapped to level ``level``."""
        return np.asarray(points) / float(1 << level)

    def _make_base(self, reach: tuple[int, int, int, int]) -> None:
        """Make level 0 over the box ``reach`` (x0, y0, x1, y1, exclusive, inside the image)."""
        x0, y0, x1, y1 = self._box
        if x0 <= reach[0] and y0 <= reach[1] and reach[2] <= x1 and reach[3] <= y1:
            return
        height, width = self.shape
        if x1 > x0:  # grow the box made to one holding it and the reach
            reach = (min(x0, reach[0]), min(y0, reach[1]), max(x1, reach[2]), max(y1, reach[3]))
        x0, y0 = max(reach[0] - _BOX_MARGIN, 0), max(reach[1] - _BOX_MARGIN, 0)
        x1, y1 = min(reach[2] + _BOX_MARGIN, width), min(reach[3] + _BOX_MARGIN, height)
        # The box with the 2 px of image around it that the kernel reaches; the filter writes
        # that border too, outside the box made so far (it only grows).
        rows = slice(max(y0 - 2, 0), min(y1 + 2, height))
        cols = slice(max(x0 - 2, 0), min(x1 + 2, width))
        cv2.sepFilter2D(
            self._source[rows, cols],
            cv2.CV_32F,
            _BINOMIAL,
            _BINOMIAL,
            dst=self._levels[0][rows, cols],
            borderType=cv2.BORDER_REFLECT_101,
        )
        self._box = (x0, y0, x1, y1)

    def _make_all(self) -> None:
        """Make every level in full (level 0 first)."""
        if self._complete:
            return
        height, width = self.shape
        self._make_base((0, 0, width, height))
        levels = self._levels
        if self._smoothed and len(levels) > 1:
            levels[1][...] = levels[0][::2, ::2]
        for level in range(2 if self._smoothed else 1, len(levels)):
            cv2.pyrDown(levels[level - 1], dst=levels[level])
        self._complete = True

    @staticmethod
    def _buffers(
        gray: np.ndarray, num_levels: int, smooth_base: bool, reuse: ImagePyramid | None
    ) -> tuple[np.ndarray | None, tuple[np.ndarray, ...]]:
        """The levels to build into, and a buffer for the image to smooth level 0 from (or None).

        ``reuse``'s when they fit.
        """
        shape = gray.shape
        dtype = np.uint8 if gray.dtype == np.uint8 else np.float32
        sizes = [
            ((shape[0] + (1 << k) - 1) >> k, (shape[1] + (1 << k) - 1) >> k)
            for k in range(num_levels)
        ]
        if (
            reuse is not None
            and [level.shape for level in reuse._levels] == sizes
            and reuse._smoothed == smooth_base
            and (reuse._source is None or reuse._source.dtype == dtype)
        ):
            return reuse._source, reuse._levels
        source = np.empty(shape, dtype) if smooth_base else None
        return source, tuple(np.empty(size, dtype=np.float32) for size in sizes)
