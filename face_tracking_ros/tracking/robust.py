"""The median of residuals, as the trackers' robust scale and loss checks take it, cheaply.

``np.median`` of a 1-D array costs two selections and a few numpy calls more than it needs: on
a followed mono frame, its residual scale (2754 samples) took 43 us and its drift check (34
nodes) as much again. :func:`median` gives the same value from one partial sort, and
:func:`nanmedian` ``np.nanmedian``'s (the stereo tracker's four a pair: 12 us each, 4 us so).
:func:`nanmedian_columns` is ``np.nanmedian(values, axis=0)``, which takes a slow path along the
axis for any NaN: 0.9 ms for 30 pairs of 19 patch ratios (:mod:`.residual_spikes`), 0.08 ms so.
"""

from __future__ import annotations

import math

import numpy as np


def median(values: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D array of finite or infinite values (no NaN), cheaply.

    The upper middle value is selected (``np.partition``); for an even count the lower one is
    the largest value below it, and the two are averaged as ``np.median`` does.
    """
    half = values.size // 2
    part = np.partition(values, half)
    if values.size % 2:
        return float(part[half])
    return float((part[:half].max() + part[half]) / 2)


def nanmedian(values: np.ndarray) -> float:
    """``np.nanmedian`` of an array (of any shape) of values that are finite, +inf or NaN.

    :func:`median` of the values that are not NaN, as ``np.nanmedian`` takes it; NaN (without
    ``np.nanmedian``'s warning) if all are.
    """
    kept = values[~np.isnan(values)]
    return median(kept) if kept.size else math.nan


def nanmedian_columns(values: np.ndarray) -> np.ndarray:
    """``np.nanmedian(values, axis=0)`` of a 2-D array, from one sort (NaN sorts last).

    NaN (without ``np.nanmedian``'s warning) for a column of NaN alone.
    """
    ordered = np.sort(values, axis=0)
    count = np.count_nonzero(~np.isnan(values), axis=0)
    lower = np.take_along_axis(ordered, (np.maximum(count - 1, 0) // 2)[None], axis=0)[0]
    upper = np.take_along_axis(ordered, (count // 2)[None], axis=0)[0]
    with np.errstate(invalid='ignore'):
        return np.where(count > 0, (lower + upper) / 2, np.nan)
