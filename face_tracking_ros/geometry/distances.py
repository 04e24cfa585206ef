"""RMS distances of point sets: between two of them, and of one about its centroid.

The trackers bound node moves in the image by them (px), the model file check and the accuracy
and learning evaluations measure meshes with them (m).
"""

from __future__ import annotations

import numpy as np


def rms_length(vectors: np.ndarray) -> float:
    """Root mean square length of (N, D) vectors: the RMS distance of ``a`` and ``b`` for a - b."""
    return float(np.sqrt(np.mean(np.sum(vectors**2, axis=1))))


def rms_spread(points: np.ndarray) -> float:
    """RMS distance of (N, D) points from their centroid."""
    return rms_length(points - points.mean(axis=0))
