"""Short-term dynamics of a parameter stream: the features the expression classifier sees.

For frame m, the window holds the frames with stamps in (t_m - window, t_m], a frame exactly on the
open end (within :data:`STAMP_TOLERANCE`) left out, so a 1/6 s window at 30 fps always holds
five frames whatever the rounding of the stamps. The feature vector
is ``[x_m, mean of the window, slope of a least-squares line through the window]`` for a stream
of d-dimensional parameters x (alpha for expressions, eq. 3), so it is (3d,): the current value,
its smoothed level and its rate of change (units of x and x per second). The window is causal, so
the same features are computed online (one frame at a time) and offline (a whole sequence).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from face_tracking_ros.errors import InputError

STAMP_TOLERANCE = 1e-6  # s; stamps closer than this to the window's open end are outside


def window_features(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Features of the last frame of a window.

    Args:
        times: (W,) stamps of the window, s, increasing; W >= 1.
        values: (W, d) parameters at those stamps.

    Returns:
        (3d,) ``[values[-1], mean, slope]``; the slope is 0 for a single frame.
    """
    offsets = (np.asarray(times, dtype=float) - times[-1])[None, :]
    return _features(offsets, np.asarray(values, dtype=float)[None], np.ones_like(offsets))[0]


def sequence_features(times: np.ndarray, values: np.ndarray, window: float) -> np.ndarray:
    """Causal features of every frame of a sequence (vectorised :func:`window_features`).

    Args:
        times: (M,) stamps, s, strictly increasing.
        values: (M, d) parameters, e.g. alpha.
        window: window length, s, > 0.

    Returns:
        (M, 3d) features, row m from the frames in (t_m - window, t_m].

    Raises:
        InputError: on mismatched lengths, non-finite values or stamps that do not increase.
    """
    times = np.asarray(times, dtype=float)
    values = np.asarray(values, dtype=float)
    if values.ndim != 2 or times.shape != (len(values),):
        msg = f'need (M,) stamps and (M, d) values, got {times.shape} and {values.shape}'
        raise InputError(msg)
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(values))):
        msg = 'stamps or parameter values hold NaN or Inf'
        raise InputError(msg)
    if np.any(np.diff(times) <= 0.0):
        msg = 'stamps of a parameter sequence must increase strictly'
        raise InputError(msg)
    frames = np.arange(len(times))
    starts = np.searchsorted(times, times - window + STAMP_TOLERANCE, side='right')
    width = int(np.max(frames - starts, initial=0)) + 1
    # Window of frame m, right-aligned in `width` columns: frames m - width + 1 .. m.
    index = frames[:, None] - width + 1 + np.arange(width)[None, :]
    inside = (index >= starts[:, None]).astype(float)
    index = np.maximum(index, 0)
    offsets = (times[index] - times[:, None]) * inside
    return _features(offsets, values[index], inside)


def _features(offsets: np.ndarray, values: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Features of M right-aligned, masked windows.

    Args:
        offsets: (M, W) stamps minus the stamp of each window's last frame, s.
        values: (M, W, d) parameters; the last column is the current frame.
        inside: (M, W) 1 for frames in the window, 0 for padding.

    Returns:
        (M, 3d) ``[current, mean, least-squares slope]``.
    """
    count = inside.sum(axis=1)
    mean = np.einsum('mw,mwd->md', inside, values) / count[:, None]
    centred_t = (offsets - (inside * offsets).sum(axis=1, keepdims=True) / count[:, None]) * inside
    spread = np.einsum('mw,mw->m', centred_t, centred_t)
    covariance = np.einsum('mw,mwd->md', centred_t, values - mean[:, None, :])
    slope = covariance / np.where(spread > 0.0, spread, np.inf)[:, None]
    return np.hstack([values[:, -1], mean, slope])


def subtract_baselines(features: np.ndarray, baselines: np.ndarray) -> np.ndarray:
    """(M, 3d) features relative to (M, d) baselines (value and mean blocks; slopes unchanged)."""
    d = baselines.shape[1]
    relative = features.copy()
    relative[:, :d] -= baselines
    relative[:, d : 2 * d] -= baselines
    return relative


class SlidingWindow:
    """The last ``length`` seconds of a stream of (stamp, vector) samples, for online use.

    A stamp that is not later than the previous one starts a new stream (a restarted tracker or a
    looped bag replay): the window is cleared first.
    """

    def __init__(self, length: float, dim: int) -> None:
        """Create an empty window.

        Args:
            length: window length, s, > 0.
            dim: dimension d of the vectors.
        """
        self._length = length
        self._dim = dim
        self._samples: deque[tuple[float, np.ndarray]] = deque()
        self._start: float | None = None

    def clear(self) -> None:
        """Forget every sample."""
        self._samples.clear()
        self._start = None

    def push(self, stamp: float, value: np.ndarray) -> bool:
        """Add a sample and drop those older than ``stamp - length``.

        Args:
            stamp: s.
            value: (d,) finite vector.

        Returns:
            Whether this sample starts a new stream (first sample after creation, :meth:`clear`
            or a stamp not later than the previous one).

        Raises:
            InputError: if value is not a finite (d,) vector or stamp is not finite.
        """
        value = np.asarray(value, dtype=float)
        if value.shape != (self._dim,) or not np.all(np.isfinite(value)):
            msg = f'expected a finite ({self._dim},) parameter vector, got shape {value.shape}'
            raise InputError(msg)
        if not np.isfinite(stamp):
            msg = f'stamp must be finite, got {stamp}'
            raise InputError(msg)
        if self._samples and stamp <= self._samples[-1][0]:
            self.clear()
        started = self._start is None
        if started:
            self._start = stamp
        self._samples.append((stamp, value))
        while self._samples[0][0] <= stamp - self._length + STAMP_TOLERANCE:
            self._samples.popleft()
        return started

    @property
    def elapsed(self) -> float:
        """Seconds from the first sample since the last clear to the newest one (0 if empty)."""
        return self._samples[-1][0] - self._start if self._start is not None else 0.0

    @property
    def times(self) -> np.ndarray:
        """(W,) stamps in the window."""
        return np.array([stamp for stamp, _ in self._samples])

    @property
    def values(self) -> np.ndarray:
        """(W, d) vectors in the window."""
        return np.array([value for _, value in self._samples]).reshape(-1, self._dim)

    def features(self) -> np.ndarray:
        """(3d,) :func:`window_features` of the window; requires at least one sample."""
        return window_features(self.times, self.values)
