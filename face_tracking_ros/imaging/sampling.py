"""Sub-pixel sampling of image patches and their gradients with one ``cv2.remap`` call.

Points are (x, y) = (column, row) pixel coordinates with pixel centres at integers, the convention
of eq. 2 and of ``cv2.remap``. Samples are bilinear; points outside the image take the value of the
nearest border pixel (use :func:`inside_image` to know which ones).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from face_tracking_ros.errors import InputError

# cv2.remap needs maps smaller than 32767 in each dimension; other point sets are folded.
_MAP_LIMIT = 32767
_MAP_WIDTH = 4096

# Central-difference stencil: the point, then +x, -x, +y, -y (one pixel each), as (5,) shifts.
STENCIL_X = np.array([0, 1, -1, 0, 0], dtype=np.float32)
STENCIL_Y = np.array([0, 0, 0, 1, -1], dtype=np.float32)


# The largest patch half size a tracker takes: (2 h + 1)^2 = 961 samples a node; at 1000 the
# mono tracker asked for 34 GiB and the stereo initialisation's matching for 69 GiB.
MAX_HALF_SIZE = 15
# px: a point nearer the border than this has central differences (one pixel either side, as
# sample_with_gradient_xy takes them) that read the replicated border, so it counts as outside.
GRADIENT_MARGIN = 1.0


def square_offsets(half_size: int, step: float = 1.0) -> np.ndarray:
    """Offsets of a square patch of (2 h + 1)^2 samples, row-major.

    Args:
        half_size: h, >= 0.
        step: spacing of the samples, px.

    Returns:
        (M, 2) float32 offsets (dx, dy), M = (2 h + 1)^2.
    """
    if half_size < 0 or step <= 0:
        msg = f'patch half size must be >= 0 and step > 0, got {half_size}, {step}'
        raise InputError(msg)
    axis = np.arange(-half_size, half_size + 1, dtype=np.float32) * np.float32(step)
    dy, dx = np.meshgrid(axis, axis, indexing='ij')
    return np.stack([dx.ravel(), dy.ravel()], axis=1)


def sample_points(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``image`` at arbitrary points, with one ``cv2.remap`` call.

    Args:
        image: (H, W) float32 image (a pyramid level).
        points: (..., 2) pixel coordinates (x, y).

    Returns:
        (...) float32 samples.

    Raises:
        InputError: if the image is not 2-D float32 or the points are not (..., 2) and finite.
    """
    points = np.asarray(points, dtype=np.float32)
    if points.ndim < 1 or points.shape[-1] != 2:
        msg = f'points must have shape (..., 2), got {points.shape}'
        raise InputError(msg)
    return sample_xy(image, points[..., 0], points[..., 1])


def sample_xy(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """:func:`sample_points` for points given as separate x and y coordinate arrays.

    ``cv2.remap`` takes the two coordinate maps separately, so points computed row by row (all
    x, then all y) need not be interleaved first.

    Args:
        image: (H, W) float32 image.
        x: (...) column coordinates, px.
        y: (...) row coordinates, px, of x's shape.

    Returns:
        (...) float32 samples.

    Raises:
        InputError: if the image is not 2-D float32, or x and y differ in shape or hold NaN or Inf.
    """
    return _remap(image, *_checked(image, x, y))


def _checked(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The coordinates x and y as float32 arrays, checked as :func:`sample_xy` documents."""
    _check_image(image)
    return _coordinates(x, y)


def _check_image(image: np.ndarray) -> None:
    """Raise InputError unless ``image`` is a (H, W) float32 array."""
    if image.ndim != 2 or image.dtype != np.float32:
        msg = f'image must be (H, W) float32, got {image.shape} {image.dtype}'
        raise InputError(msg)


def _coordinates(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The coordinates as float32 arrays of one shape, finite (else InputError)."""
    x = np.asarray(x, dtype=np.float32)
    y = np.asarray(y, dtype=np.float32)
    if x.shape != y.shape:
        msg = f'x and y coordinates differ in shape: {x.shape} and {y.shape}'
        raise InputError(msg)
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        msg = 'points hold NaN or Inf'
        raise InputError(msg)
    return x, y


def sample_maps(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """:func:`sample_xy` at coordinates known to be finite float32 arrays of one shape.

    Nothing is checked: for maps whose maker checked them
    (:meth:`~face_tracking_ros.tracking.mono_projection.FaceProjection.points`).
    """
    return _remap(image, x, y)


def _remap(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples (...) at float32 coordinates x, y (...) of one shape (not checked)."""
    lead = x.shape
    if len(lead) == 2 and 0 < min(lead) and max(lead) < _MAP_LIMIT:
        return cv2.remap(image, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    count = x.size
    if count == 0:
        return np.zeros(lead, dtype=np.float32)
    width = min(count, _MAP_WIDTH)
    rows = -(-count // width)
    maps = np.zeros((2, rows * width), dtype=np.float32)
    maps[0, :count] = x.ravel()
    maps[1, :count] = y.ravel()
    map_x, map_y = maps.reshape(2, rows, width)
    samples = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return samples.reshape(-1)[:count].reshape(lead)


def sample_patches(image: np.ndarray, centres: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Fronto-parallel patches: samples at ``centres[i] + offsets[j]``.

    Args:
        image: (H, W) float32 image.
        centres: (N, 2) patch centres, px.
        offsets: (M, 2) offsets, px (e.g. :func:`square_offsets`).

    Returns:
        (N, M) float32 samples.
    """
    centres = np.asarray(centres, dtype=np.float32)
    offsets = np.asarray(offsets, dtype=np.float32)
    return sample_points(image, centres[:, None, :] + offsets[None, :, :])


def sample_with_gradient_xy(
    image: np.ndarray, x: np.ndarray, y: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Samples and image gradients at points given by their x and y, from one ``cv2.remap`` call.

    The gradient is the central difference of the bilinear image one pixel either side of each
    point, along the image x and y axes, so it is correct for warped (non-square) patches too. Only
    the samples needed are touched; no full-image derivative is computed.

    Args:
        image: (H, W) float32 image.
        x: (...) column coordinates, px.
        y: (...) row coordinates, px, of x's shape.

    Returns:
        ``(values, gradient)``: values (...) float32 (equal to :func:`sample_xy`'s), gradient
        (2, ...) float32 (dI/dx, dI/dy), grey levels per pixel.
    """
    x, y = _checked(image, x, y)
    samples = _stencil_samples(image, x.ravel(), y.ravel())
    gradient = np.empty((2, x.size), dtype=np.float32)
    _central_differences(samples, gradient)
    return samples[0].reshape(x.shape), gradient.reshape(2, *x.shape)


def sample_stencils(
    images: Sequence[np.ndarray], maps_x: np.ndarray, maps_y: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sample_with_gradient_xy` of C images at once, from their points' stencil maps.

    Row c of the maps holds image c's K points shifted by the stencil, ``x + STENCIL_X[j]`` and
    ``y + STENCIL_Y[j]`` (float32 sums) in row j, as a caller that finds its points in a
    compiled pass of its own makes them (the stereo tracker's
    :func:`~face_tracking_ros.tracking.stereo_kernels.stencil_maps`).

    Args:
        images: C (H, W) float32 images.
        maps_x: (C, 5, K) float32 column coordinates, px.
        maps_y: (C, 5, K) float32 row coordinates, px.

    Returns:
        ``(values, gradient)``: (C, K) float32 values and (C, 2, K) float32 gradients (dI/dx,
        dI/dy), each row equal to :func:`sample_with_gradient_xy`'s in its image.

    Raises:
        InputError: if an image is not (H, W) float32, or the maps are not (C, 5, K).
    """
    if maps_x.shape != maps_y.shape or maps_x.shape[:2] != (len(images), len(STENCIL_X)):
        msg = f'stencil maps must be (C, 5, K) for {len(images)} images, got {maps_x.shape}'
        raise InputError(msg)
    samples = np.empty(maps_x.shape, dtype=np.float32)
    for row, image in enumerate(images):
        _check_image(image)
        samples[row] = _remap(image, maps_x[row], maps_y[row])
    gradient = np.empty((len(images), 2, maps_x.shape[2]), dtype=np.float32)
    _central_differences(samples, gradient)
    return samples[:, 0], gradient


def _stencil_samples(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(5, K) samples at (K,) checked float32 points and at the stencil's shifts of them."""
    return _remap(image, x + STENCIL_X[:, None], y + STENCIL_Y[:, None])  # rows contiguous


def _central_differences(samples: np.ndarray, gradient: np.ndarray) -> None:
    """Half the differences of the +-x and +-y stencil rows (..., 5, K) into the (..., 2, K)."""
    np.subtract(samples[..., -4, :], samples[..., -3, :], out=gradient[..., 0, :])
    np.subtract(samples[..., -2, :], samples[..., -1, :], out=gradient[..., 1, :])
    gradient *= 0.5


def inside_image(points: np.ndarray, shape: tuple[int, int], margin: float = 0.0) -> np.ndarray:
    """Boolean mask (...) of points at least ``margin`` px inside an image of shape (H, W)."""
    points = np.asarray(points)
    return inside_xy(points[..., 0], points[..., 1], shape, margin)


def inside_xy(
    x: np.ndarray, y: np.ndarray, shape: tuple[int, int], margin: float = 0.0
) -> np.ndarray:
    """:func:`inside_image` for points given as separate x and y coordinate arrays."""
    height, width = shape
    return (x >= margin) & (y >= margin) & (x <= width - 1 - margin) & (y <= height - 1 - margin)
