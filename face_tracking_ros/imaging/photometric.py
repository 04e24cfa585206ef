"""Invariance of patch residuals to smooth brightness changes, by variable projection.

Shading on a turning head, a moving light or camera gain change a small patch's grey levels
approximately as ``I ~ g(u, v) T + b(u, v)``, with gain g and bias b constant (GAIN_BIAS) or
affine (GAIN_FIELD) over the patch coordinates (u, v). Instead of estimating g and b, the residual
is projected onto the orthogonal complement of the span of those brightness changes per patch:
with the template T fixed during a frame's solve, ``e = (1 - P) I`` is the residual at the optimal
g and b, and its Jacobian is exactly ``(1 - P) dI/dtheta``. A still image still gives exactly zero.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np


class PhotometricModel(IntEnum):
    """Which brightness change of a patch the residual ignores."""

    NONE = 0
    BIAS = 1
    GAIN_BIAS = 2
    GAIN_FIELD = 3


@dataclass(frozen=True)
class PhotometricProjection:
    """The projection ``1 - P`` for (N, M) patch templates.

    Attributes:
        basis: (N, M, K) orthonormal columns spanning each patch's brightness changes (K = 0
            for NONE).
    """

    basis: np.ndarray

    @classmethod
    def of(
        cls, template: np.ndarray, model: PhotometricModel, coordinates: np.ndarray
    ) -> PhotometricProjection:
        """The projection for (N, M) templates (one patch of M samples per row).

        Args:
            template: (N, M) template samples.
            model: the brightness changes to ignore.
            coordinates: (M, 2) patch coordinates (u, v) of the samples, any unit (GAIN_FIELD).
        """
        count, size = template.shape
        if model == PhotometricModel.NONE:
            return cls(basis=np.zeros((count, size, 0)))
        columns = [np.ones((count, size))]
        if model == PhotometricModel.GAIN_FIELD:
            u, v = (np.broadcast_to(c - c.mean(), (count, size)) for c in coordinates.T)
            columns += [u, v]
        if model in (PhotometricModel.GAIN_BIAS, PhotometricModel.GAIN_FIELD):
            contrast = template - template.mean(axis=1, keepdims=True)
            columns.append(contrast)
            if model == PhotometricModel.GAIN_FIELD:
                columns += [contrast * u, contrast * v]
        stacked = np.stack(columns, axis=-1)
        basis, triangular = np.linalg.qr(stacked)
        # Columns that add nothing (a flat template) are dropped by zeroing them.
        scale = np.abs(np.diagonal(triangular, axis1=1, axis2=2))
        keep = scale > 1e-6 * np.maximum(scale[:, :1], 1e-12)
        return cls(basis=basis * keep[:, None, :])

    def apply(self, values: np.ndarray) -> np.ndarray:
        """``(1 - P) values`` for (N, M) or (N, M, J) arrays (residuals or Jacobian columns)."""
        if self.basis.shape[-1] == 0:
            return values
        matrix = values if values.ndim == 3 else values[..., None]
        projected = matrix - self.basis @ (self.basis.transpose(0, 2, 1) @ matrix)
        return projected if values.ndim == 3 else projected[..., 0]
