"""Cluttered backgrounds: a textured room wall behind the subject, consistent across a stereo rig.

The backdrop is a fronto-parallel plane at depth ``depth`` (m) in the reference (left) camera
frame, painted with shelves, books, frames, a window, a plant and cables. A camera whose
projection matrix has ``P[0, 3] = -fx B`` sees it shifted by ``P[0, 3] / depth`` pixels, so the
stereo pair of a synthetic scene has a true background disparity.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.geometry.camera import PinholeCamera

_MARGIN = 96  # extra backdrop columns on each side at the nominal scale (stereo shifts), px
_NOMINAL_HEIGHT = 480  # rows at which the clutter is painted


@dataclass(frozen=True)
class Backdrop:
    """A planar, cluttered wall behind the face.

    Attributes:
        image: (H, W + 2 margin, 3) float32 RGB in [0, 255], as seen by a camera with P[0, 3] = 0.
        depth: distance of the wall from the reference camera, m.
        margin: extra columns on each side of the image, px.
    """

    image: np.ndarray
    depth: float
    margin: int

    @classmethod
    def cluttered(cls, width: int, height: int, seed: int, depth: float = 2.5) -> Backdrop:
        """A random room wall for images of ``width`` x ``height`` px, deterministic from seed.

        Raises:
            ConfigError: for a non-positive size or depth.
        """
        if width <= 0 or height <= 0 or depth <= 0.0:
            msg = f'backdrop needs a positive size and depth, got {width}x{height} at {depth} m'
            raise ConfigError(msg)
        rng = np.random.default_rng(seed)
        # Painted at the nominal 480-row scale, then resized: clutter keeps its look at any size.
        scale = height / _NOMINAL_HEIGHT
        margin = int(np.ceil(_MARGIN * scale))
        nominal_width = round((width + 2 * margin) / scale)
        image = _wall(rng, nominal_width, _NOMINAL_HEIGHT)
        for paint in (_window, _shelves, _frames, _plant, _cable):
            paint(rng, image)
        image = cv2.GaussianBlur(image, (0, 0), 1.1)  # out of focus behind the subject
        image = cv2.resize(image, (width + 2 * margin, height), interpolation=cv2.INTER_AREA)
        return cls(image=image, depth=depth, margin=margin)

    def view(self, camera: PinholeCamera, encoding: str) -> np.ndarray:
        """The wall as ``camera`` sees it: (H, W) or (H, W, 3) float32 in [0, 255].

        Args:
            camera: a camera of the rig (its ``P[0, 3]`` sets the shift).
            encoding: 'mono8' or 'rgb8'.
        """
        shift = camera.p[0, 3] / self.depth - self.margin
        warp = np.array([[1.0, 0.0, shift], [0.0, 1.0, 0.0]])
        image = cv2.warpAffine(
            self.image, warp, (camera.width, camera.height), flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REFLECT,
        )  # fmt: skip
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if encoding == 'mono8' else image


def _colour(rng: np.random.Generator, low: float = 20.0, high: float = 235.0) -> tuple[float, ...]:
    """A random, muted RGB colour (indoor objects): brightness in [low, high], low saturation."""
    grey = rng.uniform(low, high)
    tint = rng.normal(0.0, 0.18, 3)
    return tuple(float(np.clip(grey * (1.0 + tint[k]), 0.0, 255.0)) for k in range(3))


def _wall(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """A painted wall lit from one side, with plaster texture."""
    base = np.array(_colour(rng, 110.0, 210.0), np.float32)
    ramp = np.linspace(rng.uniform(0.7, 1.0), rng.uniform(0.7, 1.0), width, dtype=np.float32)
    plaster = cv2.resize(
        rng.normal(1.0, 0.04, (height // 8 + 2, width // 8 + 2)).astype(np.float32),
        (width, height), interpolation=cv2.INTER_CUBIC,
    )  # fmt: skip
    return base[None, None, :] * (ramp[None, :] * plaster)[..., None]


def _window(rng: np.random.Generator, image: np.ndarray) -> None:
    """A bright window with mullions."""
    height, width = image.shape[:2]
    x0, y0 = int(rng.uniform(0, width * 0.7)), int(rng.uniform(0, height * 0.3))
    w, h = int(rng.uniform(120, 220)), int(rng.uniform(150, 260))
    cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), (245.0, 245.0, 240.0), -1)
    frame = _colour(rng, 30, 120)
    cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), frame, 8)
    cv2.line(image, (x0 + w // 2, y0), (x0 + w // 2, y0 + h), frame, 6)
    cv2.line(image, (x0, y0 + h // 2), (x0 + w, y0 + h // 2), frame, 6)


def _shelves(rng: np.random.Generator, image: np.ndarray) -> None:
    """Shelf boards with rows of books of random colours and widths."""
    height, width = image.shape[:2]
    x0 = int(rng.uniform(0, width * 0.6))
    shelf_width = int(rng.uniform(180, 320))
    for row in range(int(rng.integers(2, 4))):
        y = int(height * (0.35 + 0.22 * row) + rng.uniform(-20, 20))
        cv2.rectangle(image, (x0, y), (x0 + shelf_width, y + 10), _colour(rng, 60, 150), -1)
        x = x0 + 4
        while x < x0 + shelf_width - 12:
            book_w, book_h = int(rng.uniform(8, 22)), int(rng.uniform(50, 90))
            cv2.rectangle(image, (x, y - book_h), (x + book_w, y), _colour(rng), -1)
            cv2.line(image, (x, y - book_h + 8), (x + book_w, y - book_h + 8), _colour(rng), 2)
            x += book_w + int(rng.integers(0, 3))


def _frames(rng: np.random.Generator, image: np.ndarray) -> None:
    """Picture frames holding striped or blotchy pictures."""
    height, width = image.shape[:2]
    for _ in range(int(rng.integers(2, 5))):
        w, h = int(rng.uniform(50, 140)), int(rng.uniform(50, 140))
        x0, y0 = int(rng.uniform(0, width - w)), int(rng.uniform(0, height - h))
        picture = cv2.resize(
            np.array([_colour(rng, 40, 220) for _ in range(16)], np.float32).reshape(4, 4, 3),
            (w, h),
            interpolation=cv2.INTER_CUBIC,
        )  # fmt: skip
        image[y0 : y0 + h, x0 : x0 + w] = np.clip(picture, 0, 255)
        cv2.rectangle(image, (x0, y0), (x0 + w, y0 + h), _colour(rng, 10, 90), 5)


def _plant(rng: np.random.Generator, image: np.ndarray) -> None:
    """A pot plant: a pot and a cloud of leaves."""
    height, width = image.shape[:2]
    cx = int(rng.uniform(40, width - 40))
    cv2.rectangle(image, (cx - 30, height - 90), (cx + 30, height), _colour(rng, 60, 180), -1)
    green = np.array([40.0, 110.0, 50.0])
    for _ in range(60):
        centre = (int(cx + rng.normal(0, 45)), int(height - 120 + rng.normal(0, 45)))
        axes = (int(rng.uniform(6, 18)), int(rng.uniform(3, 7)))
        colour = tuple(float(c) for c in green * rng.uniform(0.5, 1.4))
        cv2.ellipse(image, centre, axes, rng.uniform(0, 180), 0, 360, colour, -1, cv2.LINE_AA)


def _cable(rng: np.random.Generator, image: np.ndarray) -> None:
    """A thin dark cable sagging across the wall."""
    height, width = image.shape[:2]
    x = np.linspace(0, width, 40)
    y = rng.uniform(0.1, 0.9) * height + rng.uniform(20, 60) * np.sin(np.pi * x / width)
    points = np.stack([x, y], 1).astype(np.int32)
    cv2.polylines(image, [points], False, _colour(rng, 10, 50), 2, cv2.LINE_AA)
