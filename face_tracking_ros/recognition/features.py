"""Short-term dynamics of a parameter stream: the features the expression classifier sees.

For frame m, the window holds the frames with stamps in (t_m - window, t_m]. The feature vector
is ``[x_m, mean of the window, slope of a least-squares line through the window]`` for a stream
of d-dimensional parameters x (alpha for expressions, eq. 3), so it is (3d,): the current value,
its smoothed level and its rate of change (units of x and x per second). The window is causal, so
the same features are computed online (one frame at a time) and offline (a whole sequence).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from face_tracking_ros.errors import InputError


def window_features(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Features of the last frame of a window.

    Args:
        times: (W,) stamps of the window, s, increasing; W >= 1.
        values: (W, d) parameters at those stamps.

    Returns:
        (3d,) ``[values[-1], mean, slope]``; the slope is 0 for a single frame.
    """
    if len(times) < 2:
        slope = np.zeros(values.shape[1])
    else:
        slope = np.polyfit(times - times[-1], values, 1)[0]
    return np.concatenate([values[-1], values.mean(axis=0), slope])


def sequence_features(times: np.ndarray, values: np.ndarray, window: float) -> np.ndarray:
    """Causal features of every frame of a sequence.

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
    starts = np.searchsorted(times, times - window, side='right')
    return np.array(
        [window_features(times[s : m + 1], values[s : m + 1]) for m, s in enumerate(starts)]
    ).reshape(len(times), 3 * values.shape[1])


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

    def push(self, stamp: float, value: np.ndarray) -> None:
        """Add a sample and drop those older than ``stamp - length``.

        Args:
            stamp: s.
            value: (d,) finite vector.

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
        if self._start is None:
            self._start = stamp
        self._samples.append((stamp, value))
        while self._samples[0][0] <= stamp - self._length:
            self._samples.popleft()

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
