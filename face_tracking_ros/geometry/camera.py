"""Pinhole and rectified stereo cameras described the way sensor_msgs/CameraInfo describes them.

Projection (eq. 2) uses the 3x4 projection matrix P of CameraInfo, which maps points in the
camera's optical frame (x right, y down, z forward, metres) to pixels of the rectified image. For
the right camera of a rectified stereo rig, ``P[0, 3] = -fx * B`` with baseline B in metres, and
points are expressed in the left (reference) camera frame, as ROS specifies.

This module has no ROS imports: :meth:`PinholeCamera.from_camera_info` reads any object with the
CameraInfo fields (an rclpy message, a rosbags message or a simple namespace).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from face_tracking_ros.errors import InputError

SAME_CALIBRATION_RTOL = 1e-4  # relative difference of K, D, R, P within one calibration
# Shared by both views of a rectified pair. (cy may differ: a row offset the tracker measures
# and corrects, StereoRig.with_right_rows_shifted; cx may too, as stereoRectify leaves it.)
RECTIFIED_SHARED = {(0, 0): 'fx', (1, 1): 'fy'}
RECTIFIED_TOLERANCE = 1e-4  # relative
LAST_ROW_TOLERANCE = 1e-2  # of K's and P's last rows from (0, 0, 1[, 0]), which eq. 2 assumes
ROTATION_TOLERANCE = 1e-3  # of R^T R from I: a calibration file's R printed to 4 decimals


@dataclass(frozen=True)
class PinholeCamera:
    """A calibrated camera: image size, intrinsics K, distortion D, projection P.

    Attributes:
        width: image width, px.
        height: image height, px.
        k: (3, 3) intrinsic matrix of the raw image.
        p: (3, 4) projection matrix of the rectified image (eq. 2).
        d: distortion coefficients of ``distortion_model`` (empty or zeros for none).
        distortion_model: 'plumb_bob', 'rational_polynomial', 'equidistant' (OpenCV's fisheye
            model) or '' (none).
        r: (3, 3) rectification rotation.
    """

    width: int
    height: int
    k: np.ndarray
    p: np.ndarray
    d: np.ndarray = field(default_factory=lambda: np.zeros(5))
    distortion_model: str = 'plumb_bob'
    r: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        """Validate shapes and values."""
        _require(self.width > 0 and self.height > 0, f'image size {self.width}x{self.height}')
        _require(np.shape(self.k) == (3, 3), f'K has shape {np.shape(self.k)}, not (3, 3)')
        _require(np.shape(self.p) == (3, 4), f'P has shape {np.shape(self.p)}, not (3, 4)')
        arrays = (self.k, self.p, self.d, self.r)
        _require(all(np.all(np.isfinite(a)) for a in arrays), 'K, P, D or R holds NaN or Inf')
        _require(self.p[0, 0] > 0 and self.p[1, 1] > 0, 'P has a focal length <= 0 (uncalibrated)')
        _require(self.k[0, 0] > 0 and self.k[1, 1] > 0, 'K has a focal length <= 0 (uncalibrated)')
        for name, matrix in (('K', self.k), ('P', self.p)):
            _require_last_row(name, matrix)
        rotation_error = np.abs(self.r.T @ self.r - np.eye(3)).max()
        _require(
            rotation_error < ROTATION_TOLERANCE and np.linalg.det(self.r) > 0,
            f'R is not a rotation (max |R^T R - I| = {rotation_error:.2g}, det R = '
            f'{np.linalg.det(self.r):.3g})',
        )

    @classmethod
    def from_camera_info(cls, info: Any) -> PinholeCamera:
        """Build from a sensor_msgs/CameraInfo-like object (fields width, height, k, d, p, r).

        A camera that bins pixels (``binning_x``, ``binning_y`` > 1) sends images that much
        smaller than the calibration's size: K, P and the size are scaled to them, as
        image_geometry does (the distortion, in normalised coordinates, is unchanged).

        Raises:
            InputError: for a zero (uncalibrated) or malformed CameraInfo, or one with a region
                of interest (not supported).
        """
        k = np.asarray(info.k, dtype=float).reshape(3, 3)
        p = np.asarray(info.p, dtype=float).reshape(3, 4)
        if not np.any(p):
            p = np.hstack([k, np.zeros((3, 1))])
        roi = getattr(info, 'roi', None)
        full = (0, 0, 0, 0), (0, 0, int(info.width), int(info.height))  # both mean the whole image
        if roi is not None and (roi.x_offset, roi.y_offset, roi.width, roi.height) not in full:
            msg = (
                f'camera_info has a region of interest ({roi.width}x{roi.height} at '
                f'{roi.x_offset}, {roi.y_offset}): not supported; send full images'
            )
            raise InputError(msg)
        binning_x = max(int(getattr(info, 'binning_x', 0)), 1)  # (0 means 1, as in the message)
        binning_y = max(int(getattr(info, 'binning_y', 0)), 1)
        rows = np.array([[binning_x], [binning_y], [1.0]])  # each row of K and P divided
        return cls(
            width=int(info.width) // binning_x,
            height=int(info.height) // binning_y,
            k=k / rows,
            p=p / rows,
            d=np.asarray(info.d, dtype=float),
            distortion_model=str(info.distortion_model),
            r=np.asarray(info.r, dtype=float).reshape(3, 3) if np.any(info.r) else np.eye(3),
        )

    @classmethod
    def ideal(
        cls, width: int = 640, height: int = 480, focal: float = 600.0, tx: float = 0.0
    ) -> PinholeCamera:
        """A distortion-free camera with the principal point at the image centre.

        Args:
            width: image width, px.
            height: image height, px.
            focal: focal length fx = fy, px.
            tx: ``P[0, 3]``, i.e. ``-fx * B`` for the right camera of a stereo rig, px*m.
        """
        k = np.array(
            [[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0, 0, 1]]
        )
        p = np.hstack([k, np.array([[tx], [0.0], [0.0]])])
        return cls(width=width, height=height, k=k, p=p, d=np.zeros(5))

    @property
    def focal(self) -> float:
        """Mean rectified focal length (fx + fy) / 2, px."""
        return float(0.5 * (self.p[0, 0] + self.p[1, 1]))

    def same_calibration(self, other: PinholeCamera) -> bool:
        """True if ``other`` has the same image size, K, D, R and P (to a relative 1e-4).

        A driver that recomputes its camera_info leaves differences of that order, a thousandth
        of a pixel at the image's edge; treated as a new calibration, each would restart the
        track.
        """
        if other is self:  # a repeated CameraInfo (conversions.CameraInfoReader): no comparison
            return True
        return (self.width, self.height, self.distortion_model) == (
            other.width,
            other.height,
            other.distortion_model,
        ) and all(
            np.shape(mine) == np.shape(theirs)
            and np.allclose(mine, theirs, rtol=SAME_CALIBRATION_RTOL)
            for mine, theirs in zip(
                (self.k, self.d, self.r, self.p), (other.k, other.d, other.r, other.p), strict=True
            )
        )

    @property
    def needs_rectification(self) -> bool:
        """True if the raw image differs from the rectified image of P (eq. 2).

        That is: D is non-zero, R is not the identity, or P's left 3x3 differs from K. A camera
        whose raw image already is its rectified one (an ideal camera, or the camera_info of an
        image_rect topic) needs nothing.
        """
        return bool(
            np.any(self.d)
            or not np.allclose(self.r, np.eye(3), rtol=0.0, atol=1e-12)
            or not np.allclose(self.p[:, :3], self.k, rtol=0.0, atol=1e-9)
        )

    def project(self, points: np.ndarray) -> np.ndarray:
        """Project (N, 3) camera-frame points (m) to (N, 2) rectified pixels (eq. 2)."""
        homogeneous = points @ self.p[:, :3].T + self.p[:, 3]
        return homogeneous[:, :2] / homogeneous[:, 2:3]

    def project_with_jacobian(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project points and differentiate: returns (N, 2) pixels and (N, 2, 3) d(u, v)/dX."""
        homogeneous = points @ self.p[:, :3].T + self.p[:, 3]
        depth = homogeneous[:, 2:3]
        pixels = homogeneous[:, :2] / depth
        jacobian = (self.p[None, :2, :3] - pixels[:, :, None] * self.p[None, 2:3, :3]) / depth[
            :, :, None
        ]
        return pixels, jacobian

    def rectify_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap float maps taking the raw (distorted) image to the rectified image of P.

        What image_proc's rectify does.

        Raises:
            InputError: for a distortion model OpenCV does not implement.
        """
        size = (self.width, self.height)
        if self._distortion_kind() == 'equidistant':
            return cv2.fisheye.initUndistortRectifyMap(
                self.k, self.d[:4], self.r, self.p[:, :3], size, cv2.CV_32FC1
            )
        return cv2.initUndistortRectifyMap(
            self.k, self.d, self.r, self.p[:, :3], size, cv2.CV_32FC1
        )

    def rectified_pixels(self, raw: np.ndarray) -> np.ndarray:
        """(N, 2) pixels of the rectified image (eq. 2) that show the raw-image pixels ``raw``.

        The inverse of :meth:`raw_pixels`; the identity for a camera that needs no
        rectification.

        Raises:
            InputError: for a distortion model OpenCV does not implement.
        """
        raw = np.asarray(raw, dtype=float).reshape(-1, 2)
        if not self.needs_rectification or len(raw) == 0:
            return raw.copy()
        raw = raw.reshape(-1, 1, 2)
        if self._distortion_kind() == 'equidistant':
            rectified = cv2.fisheye.undistortPoints(
                raw, self.k, self.d[:4], R=self.r, P=self.p[:, :3]
            )
        else:
            rectified = cv2.undistortPoints(raw, self.k, self.d, R=self.r, P=self.p[:, :3])
        return rectified.reshape(-1, 2)

    def raw_pixels(self, points: np.ndarray) -> np.ndarray:
        """Project (N, 3) points (m, in the frame of P) to (N, 2) pixels of the raw image.

        Where the camera itself shows them: rotated back by R, through K and the distortion D.
        :meth:`project` for a camera that needs no rectification.

        Raises:
            InputError: for a distortion model OpenCV does not implement.
        """
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        if not self.needs_rectification or len(points) == 0:
            return self.project(points)
        offset = np.linalg.solve(self.p[:, :3], self.p[:, 3])  # P = K' [I | offset]
        in_camera = ((points + offset) @ self.r).reshape(-1, 1, 3)  # R^T (X + offset), row-wise
        zero = np.zeros(3)
        if self._distortion_kind() == 'equidistant':
            raw, _ = cv2.fisheye.projectPoints(in_camera, zero, zero, self.k, self.d[:4])
        else:
            raw, _ = cv2.projectPoints(in_camera, zero, zero, self.k, self.d)
        return raw.reshape(-1, 2)

    def _distortion_kind(self) -> str:
        """'equidistant' (OpenCV's fisheye model) or 'pinhole' (plumb_bob, rational_polynomial).

        Raises:
            InputError: for another distortion model with non-zero D.
        """
        if not np.any(self.d):
            return 'pinhole'
        model = self.distortion_model
        sizes = {'plumb_bob': (4, 5), 'rational_polynomial': (8,), 'equidistant': (4,)}
        if model not in sizes or len(self.d) not in sizes[model]:
            msg = (
                f'cannot rectify distortion model {model!r} with {len(self.d)} coefficients; '
                'supported: plumb_bob (4 or 5), rational_polynomial (8), equidistant (4)'
            )
            raise InputError(msg)
        return 'equidistant' if model == 'equidistant' else 'pinhole'

    def camera_info_fields(self) -> dict[str, Any]:
        """The CameraInfo fields of this camera (lists, row-major), for message conversion."""
        return {
            'width': self.width,
            'height': self.height,
            'distortion_model': self.distortion_model,
            'd': [float(v) for v in self.d],
            'k': [float(v) for v in self.k.ravel()],
            'r': [float(v) for v in self.r.ravel()],
            'p': [float(v) for v in self.p.ravel()],
        }


def _baseline_problem(left_tx: float, right_tx: float) -> str:
    """Why a right camera whose P[0,3] (-fx B) is not negative cannot be a rectified pair's.

    A left camera with the negative one is the right camera: the topics are exchanged.
    """
    swapped = f"; the left camera's is {left_tx:g}: are left and right swapped?"
    return (
        'right P[0,3] must be -fx*B < 0 for a rectified stereo pair '
        f'(it is {right_tx:g}{swapped if left_tx < 0 else ""})'
    )


@dataclass(frozen=True)
class StereoRig:
    """A rectified stereo pair: both cameras share R and intrinsics; the right one has Tx != 0.

    Points are in the left camera's optical frame, metres.
    """

    left: PinholeCamera
    right: PinholeCamera

    def __post_init__(self) -> None:
        """Check that the pair is rectified and sizes match."""
        left, right = self.left, self.right
        same_size = (left.width, left.height) == (right.width, right.height)
        _require(
            same_size, f'left {left.width}x{left.height} != right {right.width}x{right.height}'
        )
        _require(right.p[0, 3] < 0, _baseline_problem(left.p[0, 3], right.p[0, 3]))
        for (row, col), name in RECTIFIED_SHARED.items():
            mine, theirs = left.p[row, col], right.p[row, col]
            _require(
                abs(mine - theirs) <= RECTIFIED_TOLERANCE * abs(mine),
                f'left and right P differ in {name} ({mine:g} and {theirs:g}): not a rectified '
                'stereo pair',
            )
        _require(
            right.p[1, 3] == 0.0 and left.p[1, 3] == 0.0,
            'P[1,3] must be 0 (a horizontal baseline) for a rectified stereo pair',
        )

    @property
    def baseline(self) -> float:
        """Baseline B = -P_right[0, 3] / fx, metres."""
        return float(-self.right.p[0, 3] / self.right.p[0, 0])

    @classmethod
    def ideal(
        cls, width: int = 640, height: int = 480, focal: float = 600.0, baseline: float = 0.11
    ) -> StereoRig:
        """An ideal rectified rig with the given baseline (m)."""
        return cls(
            left=PinholeCamera.ideal(width, height, focal),
            right=PinholeCamera.ideal(width, height, focal, tx=-focal * baseline),
        )

    def with_right_rows_shifted(self, offset: float) -> StereoRig:
        """The rig whose right camera projects every point ``offset`` px lower (its rows moved).

        What a calibration error of the rectification leaves: the right image showing the
        scene on other rows than the left (see :mod:`~face_tracking_ros.tracking.row_offset`).
        """
        p = self.right.p.copy()
        p[1, 2] += offset  # P = K [I | t] with t = (-B, 0, 0): only the principal point's y moves
        return StereoRig(self.left, replace(self.right, p=p))

    def triangulate(self, left_px: np.ndarray, right_px: np.ndarray) -> np.ndarray:
        """Triangulate (N, 2) left and right rectified pixels into (N, 3) left-frame points."""
        if len(left_px) == 0:  # cv2.triangulatePoints returns None for no points
            return np.zeros((0, 3))
        homogeneous = cv2.triangulatePoints(
            self.left.p, self.right.p, left_px.T.astype(float), right_px.T.astype(float)
        )
        return (homogeneous[:3] / homogeneous[3]).T


def _require_last_row(name: str, matrix: np.ndarray) -> None:
    """Raise InputError unless K's or P's last row is CameraInfo's (0, 0, 1[, 0]), as eq. 2 needs.

    Any other row gives no depth (a zero row projects every point to infinity).
    """
    expected = np.eye(3, matrix.shape[1])[2]
    shown = ', '.join(f'{value:g}' for value in matrix[2])
    wanted = ', '.join(f'{value:g}' for value in expected)
    _require(
        bool(np.allclose(matrix[2], expected, rtol=0.0, atol=LAST_ROW_TOLERANCE)),
        f"{name}'s last row is [{shown}], expected [{wanted}]",
    )


def _require(condition: bool, problem: str) -> None:
    """Raise InputError naming the camera problem unless condition holds."""
    if not condition:
        msg = f'invalid camera: {problem}'
        raise InputError(msg)
