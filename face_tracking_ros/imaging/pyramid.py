"""Gaussian image pyramids for coarse-to-fine tracking.

Level ``l`` is ``cv2.pyrDown`` applied ``l`` times to the float32 grey image. ``pyrDown``
centres output pixel ``i`` on input pixel ``2 i``, so a point at pixel ``x`` of level 0 lies at
``x / 2**l`` of level ``l`` (:meth:`ImagePyramid.to_level`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
import math
from typing import NamedTuple

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
# them made. A frame's solve moves its points by well under this after its first read: on the
# benchmark's 900-frame 640x480 bags, 16, 8, 4 and 2 px all made level 0 in 1.05 boxes a mono
# frame (2.0 a stereo pair), 0 px in 1.28; 4 px smooths 30 % (mono) and 26 % (stereo) fewer
# pixels than 16 (thirtieth session).
_BOX_MARGIN = 4
# A coarser level added by ``deepen`` is made by boxes as ``pyrDown`` of the float level above,
# which is not exact: OpenCV's vector path (multiply-adds) and its scalar one (a row's last few
# columns, where the vectors do not fit) round differently. A box is so reduced from columns
# starting at a multiple of _VECTOR_ALIGN and reaching _VECTOR_PAD columns beyond the ones it
# keeps (or the level's edge), so that each kept column takes the path it takes in the whole
# level: the same bits (8 float lanes here; 32 allows 16, and the vectors unrolled twice).
_VECTOR_ALIGN = 32
_VECTOR_PAD = 32


def _levels_that_fit(side: int, min_size: int) -> int:
    """How many pyramid levels a shorter side of ``side`` px allows, the coarsest >= ``min_size``.

    Level l has ``side >> l`` px.
    """
    return (side // min_size).bit_length()


def tracking_levels(width: int, height: int) -> int:
    """How many levels a tracker's pyramid of ``width`` x ``height`` images can have.

    The coarsest level must keep ``MIN_TRACKING_LEVEL_SIZE`` pixels on its shorter side. A
    deeper pyramid leaves it too small for the node patches, or cannot be built at all.
    """
    return _levels_that_fit(min(width, height), MIN_TRACKING_LEVEL_SIZE)


def check_levels_fit(num_levels: int, width: int, height: int) -> None:
    """Check at set-up that a tracker's pyramid fits its images (:func:`tracking_levels`).

    A pyramid too deep would fail on every frame.

    Raises:
        ConfigError: naming ``pyramid_levels`` and how many levels fit.
    """
    fitting = tracking_levels(width, height)
    if num_levels > fitting:
        msg = (
            f'pyramid_levels = {num_levels} is too deep for {width}x{height} images: at most '
            f'{fitting} leave the coarsest level {MIN_TRACKING_LEVEL_SIZE} px'
        )
        raise ConfigError(msg)


class ImagePyramid:
    """A float32 Gaussian pyramid of one grey image, made as it is read.

    :attr:`levels` gives every level in full. A tracker that samples a few patches of a frame
    reads them through :meth:`level` or :meth:`level_reaching` instead, which make a level only
    over the box its samples reach, a face's patches being a tenth or so of a 640x480 frame:
    level 0, level 1 too for an 8-bit image, and the levels :meth:`deepen` adds; the other
    levels are made in full when first asked for. Every value read either way is the full
    build's: smoothing a box of the image (``smooth_base``) with a 2-px border of it gives the
    values of smoothing the whole image, whose reflected border lies at its own edges, and
    ``pyrDown`` of a box with a 2-px border the values of ``pyrDown`` of the whole level (a
    smoothed level 1 is level 0 decimated); to the bit for an 8-bit image (its weighted sums are
    exact in float32) and for an added level (``_VECTOR_ALIGN``), within float32 rounding for a
    smoothed float one (the filter's vector and scalar paths meet at other columns).
    """

    def __init__(
        self,
        levels: Sequence[np.ndarray],
        source: np.ndarray | None = None,
        coarse_made: bool = True,
        smoothed: bool = True,
        factor: float = 1.0,
        owned: bool = True,
        spare: np.ndarray | None = None,
    ) -> None:
        """A pyramid of ``levels`` (level 0 first, float32), complete unless told otherwise.

        Args:
            levels: the levels, or buffers for those still to be made (:meth:`build`).
            source: the (H, W) grey image (uint8 or float32, owned by the pyramid) that level 0
                is still to be made from; None if level 0 is made.
            coarse_made: whether the coarser levels are made.
            smoothed: whether level 0 is ``source`` smoothed (else ``source`` itself).
            factor: the factor the levels made from ``source`` multiply their grey levels by
                (:meth:`build`'s).
            owned: whether ``source`` is the pyramid's own (else the caller's image, read until
                the pyramid is complete, and never written).
            spare: an array of a borrowed ``source``'s shape and type, for :meth:`own` to copy
                it into (else it allocates one).
        """
        self._levels = list(levels)
        self._built = len(self._levels)  # the levels below these are deepen()'s
        self._source = source
        self._owned = owned
        self._spare = spare
        self._smoothed = smoothed and source is not None
        # Level 1 made by boxes: the binomial sums of 8-bit values are exact, so any box's are
        # the full level's.
        self._coarse_boxed = source is not None and source.dtype == np.uint8
        self._factor = np.float32(factor)
        height, width = self._levels[0].shape
        # The box of each level made so far, (x0, y0, x1, y1) exclusive (used for level 0, for
        # level 1 of an 8-bit image and for deepen()'s levels), and whether all built levels are.
        self._boxes = [(0, 0, width, height) if source is None else (0, 0, 0, 0)]
        self._boxes += [(0, 0, 0, 0)] * (self._built - 1)
        self._complete = source is None and (coarse_made or self._built == 1)

    @classmethod
    def build(
        cls,
        gray: np.ndarray,
        num_levels: int,
        smooth_base: bool = False,
        reuse: ImagePyramid | None = None,
        factor: float = 1.0,
        borrow: bool = False,
    ) -> ImagePyramid:
        """The pyramid of ``num_levels`` levels of ``gray``, made as it is read.

        Args:
            gray: (H, W) uint8 or float grey image, copied (the caller may reuse its buffer)
                unless borrowed.
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
            factor: multiply every level's grey levels by this (as float32), as :meth:`scale`
                does after a build, but only where the levels are made. (A level is still made
                from the unscaled one before it, so the values are :meth:`scale`'s to the bit.)
            borrow: read a uint8 or float32 ``gray`` itself rather than a copy, until every
                level is made (:attr:`levels`): the caller keeps it unchanged meanwhile. A
                tracker that reads a tenth of each frame so saves copying the rest.

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
        dtype = np.uint8 if gray.dtype == np.uint8 else np.float32
        buffer, levels = cls._buffers(gray.shape, dtype, num_levels, smooth_base, reuse)
        borrowed = borrow and gray.dtype == dtype
        if borrowed:
            source = gray
        else:
            source = np.empty(gray.shape, dtype) if buffer is None else buffer
            source[...] = gray
        if not np.issubdtype(gray.dtype, np.integer) and not np.all(np.isfinite(source)):
            msg = 'pyramid input holds NaN or Inf'
            raise InputError(msg)
        return cls(
            levels,
            source,
            coarse_made=False,
            smoothed=smooth_base,
            factor=factor,
            owned=not borrowed,
            spare=buffer if borrowed else None,
        )

    @property
    def levels(self) -> tuple[np.ndarray, ...]:
        """Images of level 0 (full resolution) to L-1, each (H_l, W_l) float32 grey levels.

        In [0, 255] as built (:meth:`scale` may change that); every level made in full.
        """
        self.make_all()
        for index in range(self._built, len(self._levels)):
            height, width = self.level_shape(index)
            self._made_over(index, (0, 0, width, height))
        return tuple(self._levels)

    def level(self, index: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Level ``index``, made at least where samples at points (x, y) of it read it.

        The samples: bilinear ones at the points (``cv2.remap``) and one pixel either side
        (central differences, :func:`~.sampling.sample_with_gradient_xy`). A level made by
        boxes (see the class) is made over the box they reach and a margin (``_BOX_MARGIN``), so
        that a solve's later steps near the same points find it made; another is made in full.

        Raises:
            InputError: if the points hold NaN or Inf while their level is still being made
                (the samplers refuse such points in any case).
        """
        if (self._complete and index < self._built) or not np.size(x):
            return self.level_reaching(index, (0.0, -1.0, 0.0, -1.0))  # nothing to make there
        x, y = np.asarray(x), np.asarray(y)
        return self.level_reaching(index, (x.min(), x.max(), y.min(), y.max()))  # methods: faster

    def level_reaching(self, index: int, box: Sequence[float]) -> np.ndarray:
        """:meth:`level` for points spanning ``box``: their least and greatest x, then y.

        An empty box (least above greatest) reads nothing.

        Raises:
            InputError: if the box is not finite while its level is still being made.
        """
        if self._make_whole_unless_boxed(index):
            return self._levels[index]
        low_x, high_x, low_y, high_y = box
        if not math.isfinite(low_x + high_x + low_y + high_y):
            msg = 'points hold NaN or Inf'
            raise InputError(msg)
        if low_x > high_x:
            return self._levels[index]
        # Clipped to the level, keeping its border pixel: points beyond it read that.
        height, width = self._levels[index].shape
        reach = (
            min(max(math.floor(low_x) - _SAMPLE_REACH, 0), width - 1),
            min(max(math.floor(low_y) - _SAMPLE_REACH, 0), height - 1),
            min(max(math.floor(high_x) + _SAMPLE_REACH + 1, 1), width),
            min(max(math.floor(high_y) + _SAMPLE_REACH + 1, 1), height),
        )
        self._made_over(index, reach)
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

    def level_shape(self, index: int) -> tuple[int, int]:
        """(H, W) of level ``index``."""
        height, width = self._levels[index].shape
        return height, width

    def deepen(self, num_levels: int) -> None:
        """Add coarser levels below the built ones, to ``num_levels`` in all, made as read.

        Each added level is ``pyrDown`` of the one above, as :meth:`build` would have made it,
        made over the boxes its samples reach (:meth:`level_reaching`) from a box of the level
        above, itself so made: the same bits as ``pyrDown`` of the whole level above. It so
        carries the factor the levels above were multiplied by (:meth:`build`'s,
        :meth:`scale`'s), within float32 rounding of a deeper build's levels multiplied by it.
        A tracker that needs a deeper pyramid for an occasional frame so makes what it reads
        of the levels it lacks, and each part once: the pyramid keeps them (a stereo pair's
        deepened pyramids are the last pair's on the next pair, frame 1's on every pair). A
        pyramid with as many levels already is left as it is.

        Raises:
            InputError: if the coarsest level would keep fewer than 8 pixels on a side.
        """
        if num_levels > _levels_that_fit(min(self.shape), MIN_LEVEL_SIZE):
            msg = f'cannot build {num_levels} pyramid levels from a {self.shape} image'
            raise InputError(msg)
        while len(self._levels) < num_levels:
            height, width = self._levels[-1].shape
            self._levels.append(np.empty(((height + 1) // 2, (width + 1) // 2), np.float32))
            self._boxes.append((0, 0, 0, 0))

    def own(self) -> None:
        """Copy a borrowed image (:meth:`build`), for the caller to change its own meanwhile.

        A tracker keeping a frame's pyramid past the frame so leaves its levels to be made as
        they are read, for a copy of the 8-bit image (~0.3 MB for 640x480) rather than making
        every level (~1.5 MB of float32 written). The copy goes into the image buffer of the
        pyramid :meth:`build` reused, if that owned one (no memory allocated frame after frame).
        """
        if not self._owned and not self._complete:
            assert self._source is not None
            copy = np.empty_like(self._source) if self._spare is None else self._spare
            copy[...] = self._source
            self._source, self._owned, self._spare = copy, True, None

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

    @staticmethod
    def _make_box(
        made: tuple[int, int, int, int],
        reach: tuple[int, int, int, int],
        shape: tuple[int, int],
        make: Callable[[slice, slice], None],
    ) -> tuple[int, int, int, int]:
        """The box of a level made once ``reach`` is: ``made`` if it holds it, else made anew.

        Boxes are (x0, y0, x1, y1), exclusive, inside the level of (H, W) ``shape``; the new one
        holds ``made`` and ``reach`` with a margin of ``_BOX_MARGIN`` and is made whole by
        ``make(rows, cols)``.
        """
        x0, y0, x1, y1 = made
        if x0 <= reach[0] and y0 <= reach[1] and reach[2] <= x1 and reach[3] <= y1:
            return made
        height, width = shape
        if x1 > x0:  # grow the box made to one holding it and the reach
            reach = (min(x0, reach[0]), min(y0, reach[1]), max(x1, reach[2]), max(y1, reach[3]))
        x0, y0 = max(reach[0] - _BOX_MARGIN, 0), max(reach[1] - _BOX_MARGIN, 0)
        x1, y1 = min(reach[2] + _BOX_MARGIN, width), min(reach[3] + _BOX_MARGIN, height)
        make(slice(y0, y1), slice(x0, x1))
        return x0, y0, x1, y1

    def _make_whole_unless_boxed(self, index: int) -> bool:
        """Make level ``index`` in full unless it is made by boxes; whether it is whole now.

        Level 0, level 1 of an 8-bit image and the levels :meth:`deepen` added are made by boxes
        (whole only once the pyramid is complete, or level 0 given made); the other levels are
        made in full (every level, :meth:`make_all`) when first read.
        """
        if index >= self._built:
            return False
        if not (index == 0 or (index == 1 and self._coarse_boxed)):
            self.make_all()
        return self._complete or (index == 0 and self._source is None)

    def _made_over(self, index: int, reach: tuple[int, int, int, int]) -> None:
        """Make level ``index`` over at least the pixel box ``reach``, (x0, y0, x1, y1)."""
        if self._make_whole_unless_boxed(index):
            return
        if index >= self._built:
            make = partial(self._make_deeper, index)
        else:
            make = self._make_base if index == 0 else self._make_coarse
        self._boxes[index] = self._make_box(
            self._boxes[index], reach, self.level_shape(index), make
        )

    def _make_base(self, rows: slice, cols: slice) -> None:
        """Make level 0 over ``rows`` and ``cols`` (inside the image)."""
        assert self._source is not None
        if self._smoothed:
            # The box with the 2 px of image around it that the kernel reaches; the filter
            # writes that border too, outside the box made so far (it only grows).
            height, width = self.shape
            rows = slice(max(rows.start - 2, 0), min(rows.stop + 2, height))
            cols = slice(max(cols.start - 2, 0), min(cols.stop + 2, width))
            cv2.sepFilter2D(
                self._source[rows, cols],
                cv2.CV_32F,
                _BINOMIAL,
                _BINOMIAL,
                dst=self._levels[0][rows, cols],
                borderType=cv2.BORDER_REFLECT_101,
            )
        else:
            self._levels[0][rows, cols] = self._source[rows, cols]
        self._scale_box(self._levels[0][rows, cols])

    def _make_coarse(self, rows: slice, cols: slice) -> None:
        """Make level 1 of an 8-bit image over ``rows`` and ``cols`` (inside it).

        Smoothed: level 0 decimated, made first over the box that holds pixel 2 i of each
        pixel i. Else ``pyrDown`` of the level-0 box that holds the 5-px reach of each pixel,
        unscaled; exact, hence the full level's values.
        """
        assert self._source is not None
        height, width = self.shape
        if self._smoothed:
            below, right = min(2 * rows.stop - 1, height), min(2 * cols.stop - 1, width)
            self._made_over(0, (2 * cols.start, 2 * rows.start, right, below))
            self._levels[1][rows, cols] = self._levels[0][
                2 * rows.start : below : 2, 2 * cols.start : right : 2
            ]
            return
        top, left = max(2 * rows.start - 2, 0), max(2 * cols.start - 2, 0)
        bottom, right = min(2 * rows.stop + 1, height), min(2 * cols.stop + 1, width)
        reduced = cv2.pyrDown(self._source[top:bottom, left:right].astype(np.float32))
        made = self._levels[1][rows, cols]
        made[...] = reduced[
            rows.start - top // 2 : rows.stop - top // 2,
            cols.start - left // 2 : cols.stop - left // 2,
        ]
        self._scale_box(made)

    def _make_deeper(self, index: int, rows: slice, cols: slice) -> None:
        """Make level ``index``, one that :meth:`deepen` added, over ``rows`` and ``cols``.

        ``pyrDown`` of the level above over the box holding the 5-px reach of each pixel, made
        first; the box reduced reaches from a column that is a multiple of ``_VECTOR_ALIGN`` to
        ``_VECTOR_PAD`` columns beyond the last kept one (see there), the pixels outside the
        reach, made or not, reading only into columns not kept.
        """
        height, width = self.level_shape(index - 1)
        top, bottom = max(2 * rows.start - 2, 0), min(2 * rows.stop + 1, height)
        left, right = max(2 * cols.start - 2, 0), min(2 * cols.stop + 1, width)
        self._made_over(index - 1, (left, top, right, bottom))
        start = (max(cols.start - 1, 0) // _VECTOR_ALIGN) * _VECTOR_ALIGN
        stop = min(2 * (cols.stop + _VECTOR_PAD) + 1, width)
        reduced = cv2.pyrDown(self._levels[index - 1][top:bottom, 2 * start : stop])
        self._levels[index][rows, cols] = reduced[
            rows.start - top // 2 : rows.stop - top // 2, cols.start - start : cols.stop - start
        ]

    def _scale_box(self, values: np.ndarray) -> None:
        """Multiply ``values`` (a view of a level) by the pyramid's factor, in place."""
        if self._factor != 1.0:
            values *= self._factor

    def make_all(self) -> None:
        """Make every level in full (level 0 first), each from the unscaled one before it.

        A pyramid built from a borrowed image no longer reads it then.
        """
        if self._complete:
            return
        levels = self._levels[: self._built]
        if self._smoothed:
            cv2.sepFilter2D(
                self._source,
                cv2.CV_32F,
                _BINOMIAL,
                _BINOMIAL,
                dst=levels[0],
                borderType=cv2.BORDER_REFLECT_101,
            )
        elif self._source is not None:
            levels[0][...] = self._source
        if self._smoothed and len(levels) > 1:
            levels[1][...] = levels[0][::2, ::2]
        for level in range(2 if self._smoothed else 1, len(levels)):
            cv2.pyrDown(levels[level - 1], dst=levels[level])
        for level in levels:
            self._scale_box(level)
        self._complete = True

    @staticmethod
    def _buffers(
        shape: tuple[int, ...],
        dtype: type,
        num_levels: int,
        smooth_base: bool,
        reuse: ImagePyramid | None,
    ) -> tuple[np.ndarray | None, tuple[np.ndarray, ...]]:
        """``reuse``'s buffer for a copy of the (H, W) image (or None) and levels, if they fit.

        Its image buffer only if its own and of ``dtype``; new levels if they do not fit.
        """
        sizes = [
            ((shape[0] + (1 << k) - 1) >> k, (shape[1] + (1 << k) - 1) >> k)
            for k in range(num_levels)
        ]
        if (
            reuse is None
            or [level.shape for level in reuse._levels[: reuse._built]] != sizes
            or reuse._smoothed != smooth_base
            or reuse._source is None
        ):
            return None, tuple(np.empty(size, np.float32) for size in sizes)
        fits = reuse._owned and reuse._source.dtype == dtype
        return reuse._source if fits else None, tuple(reuse._levels[: reuse._built])


class PyramidLevel(NamedTuple):
    """Level ``index`` of ``pyramid``, for a sampler to make where it reads it."""

    pyramid: ImagePyramid
    index: int

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the level."""
        return self.pyramid.level_shape(self.index)

    def reaching(self, box: Sequence[float]) -> np.ndarray:
        """The level, made at least over ``box`` (:meth:`ImagePyramid.level_reaching`)."""
        return self.pyramid.level_reaching(self.index, box)

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The level, made where samples at (x, y) read it (:meth:`ImagePyramid.level`)."""
        return self.pyramid.level(self.index, x, y)
