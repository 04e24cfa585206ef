"""Sub-pixel sampling of image patches and their gradients with one ``cv2.remap`` call.

Points are (x, y) = (column, row) pixel coordinates with pixel centres at integers, the convention
of eq. 2 and of ``cv2.remap``. Samples are bilinear; points outside the image take the value of the
nearest border pixel (use :func:`inside_image` to know which ones).
"""

from __future__ import annotations

import cv2
import numpy as np

from face_tracking_ros.errors import InputError

# cv2.remap needs maps smaller than 32767 in each dimension; other point sets are folded.
_MAP_LIMIT = 32767
_MAP_WIDTH = 4096

# Central-difference stencil: centre, +x, -x, +y, -y (one pixel each), as (5, 1, 2).
_STENCIL = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], dtype=np.float32)[:, None, :]


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
    if image.ndim != 2 or image.dtype != np.float32:
        msg = f'image must be (H, W) float32, got {image.shape} {image.dtype}'
        raise InputError(msg)
    points = np.asarray(points, dtype=np.float32)
    if points.ndim < 1 or points.shape[-1] != 2:
        msg = f'points must have shape (..., 2), got {points.shape}'
        raise InputError(msg)
    if not np.all(np.isfinite(points)):
        msg = 'points hold NaN or Inf'
        raise InputError(msg)
    lead = points.shape[:-1]
    if len(lead) == 2 and 0 < min(lead) and max(lead) < _MAP_LIMIT:
        return cv2.remap(image, points, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    flat = points.reshape(-1, 2)
    count = flat.shape[0]
    if count == 0:
        return np.zeros(lead, dtype=np.float32)
    width = min(count, _MAP_WIDTH)
    rows = -(-count // width)
    padded = np.zeros((rows * width, 2), dtype=np.float32)
    padded[:count] = flat
    maps = padded.reshape(rows, width, 2)
    samples = cv2.remap(image, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
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


def sample_with_gradient(image: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Samples and image gradients at arbitrary points, from one ``cv2.remap`` call.

    The gradient is the central difference of the bilinear image one pixel either side of each
    point, along the image x and y axes, so it is correct for warped (non-square) patches too. Only
    the samples needed are touched; no full-image derivative is computed.

    Args:
        image: (H, W) float32 image.
        points: (..., 2) pixel coordinates (x, y).

    Returns:
        ``(values, gradient)``: values (...) float32, gradient (..., 2) float32 (dI/dx, dI/dy) in
        grey levels per pixel.
    """
    points = np.asarray(points, dtype=np.float32)
    flat = points.reshape(-1, 2)
    stencil = sample_points(image, flat[None, :, :] + _STENCIL)  # (5, K), rows contiguous
    gradient = np.empty((flat.shape[0], 2), dtype=np.float32)
    np.subtract(stencil[1], stencil[2], out=gradient[:, 0])
    np.subtract(stencil[3], stencil[4], out=gradient[:, 1])
    gradient *= 0.5
    return stencil[0].reshape(points.shape[:-1]), gradient.reshape(points.shape)


def inside_image(points: np.ndarray, shape: tuple[int, int], margin: float = 0.0) -> np.ndarray:
    """Boolean mask (...) of points at least ``margin`` px inside an image of shape (H, W)."""
    points = np.asarray(points)
    height, width = shape
    x, y = points[..., 0], points[..., 1]
    return (x >= margin) & (y >= margin) & (x <= width - 1 - margin) & (y <= height - 1 - margin)
