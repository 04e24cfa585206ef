"""Invariance of patch residuals to smooth brightness changes, by variable projection.

Shading on a turning head, a moving light or camera gain change a small patch's grey levels
approximately as ``I ~ g(u, v) T + b(u, v)``, with gain g and bias b constant (GAIN_BIAS) or
affine (GAIN_FIELD) over the patch coordinates (u, v). Instead of estimating g and b, the residual
is projected onto the orthogonal complement of the span of those brightness changes per patch:
with the template T fixed during a frame's solve, ``e = (1 - P) I`` is the residual at the optimal
g and b, and its Jacobian is exactly ``(1 - P) dI/dtheta``. A still image still gives exactly zero.

The projection runs at every iteration of the mono tracker's solve on a few thousand samples; it
is a compiled loop (numba), since numpy's per-call overhead on arrays this small costs more than
the arithmetic.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from face_tracking_ros.compiled import FAST
from face_tracking_ros.imaging.photometric_model import PhotometricModel


@dataclass(frozen=True)
class PhotometricProjection:
    """The projection ``1 - P`` for (N, M) patch templates.

    Attributes:
        basis: (N, M, K) orthonormal columns spanning each patch's brightness changes (K = 0
            for NONE); columns a template does not need (a flat template's gain) are zero.
        basis_rows: the same basis as contiguous (N, K, M) rows U', for the compiled kernels
            (:func:`project_out_row`); made from ``basis``.
    """

    basis: np.ndarray
    basis_rows: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        """Keep a contiguous (N, K, M) transpose of the basis for the compiled kernels."""
        rows = np.ascontiguousarray(self.basis.transpose(0, 2, 1))
        object.__setattr__(self, 'basis_rows', rows)

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
        return PhotometricInvariance.of(model, coordinates).projection(template)

    def split(self, parts: int) -> tuple[PhotometricProjection, ...]:
        """The projections of ``parts`` equal consecutive blocks of the patches.

        Several templates' projections are cheaper made at once (one call on all their patches)
        and split afterwards; each patch's projection depends on its own template alone.
        """
        blocks = np.split(self.basis_rows, parts)
        return tuple(PhotometricProjection(basis=block.transpose(0, 2, 1)) for block in blocks)

    def apply(self, values: np.ndarray) -> np.ndarray:
        """``(1 - P) values`` for (N, M) residuals or (J, N, M) stacks of them (Jacobian rows).

        float64 for every model, from float32 samples too: the compiled kernels take no other.
        """
        if self.basis.shape[-1] == 0:
            return np.asarray(values, dtype=float)
        stack = np.array(values if values.ndim == 3 else values[None], dtype=float, order='C')
        project_out(stack, self.basis_rows)
        return stack if values.ndim == 3 else stack[0]

    def residuals(self, samples: np.ndarray, template: np.ndarray) -> np.ndarray:
        """``(1 - P) (samples - template)``: :meth:`apply` of their difference, in one pass.

        Args:
            samples: (N, M) float32 or float64 samples.
            template: (N, M) float32 or float64 template; the difference is taken in the wider
                type of the two, as numpy takes it.

        Returns:
            (N, M) float64 projected residuals.
        """
        if self.basis.shape[-1] == 0:
            return np.asarray(samples - template, dtype=float)
        return projected_difference(
            np.ascontiguousarray(samples), np.ascontiguousarray(template), self.basis_rows
        )


@dataclass(frozen=True)
class PhotometricInvariance:
    """A photometric model on one patch layout: makes the projection of any template.

    The span of a patch's brightness changes is ``[1, u, v]`` (or ``[1]``), the same for every
    patch, plus ``[c, c u, c v]`` (or ``[c]``) of the template's contrast c = T - mean(T). The
    fixed part is orthonormalised once; per template only the contrast columns are
    orthogonalised against it (twice) and each other (modified Gram-Schmidt), so a projection
    costs a few (N, M) array operations instead of a QR of every patch.

    Attributes:
        model: the brightness changes to ignore.
        gains: (G, M) the gain fields ``[1, u, v]`` (``[1]`` for GAIN_BIAS, none below) that
            multiply the contrast, with (u, v) the patch coordinates minus their means.
        fixed: (M, F) orthonormal columns of the template-independent changes.
    """

    model: PhotometricModel
    gains: np.ndarray
    fixed: np.ndarray

    @classmethod
    def of(cls, model: PhotometricModel, coordinates: np.ndarray) -> PhotometricInvariance:
        """The invariance for patches with (M, 2) sample coordinates (u, v), any unit."""
        centred = np.stack([c - c.mean() for c in np.asarray(coordinates).T])
        size = centred.shape[1]
        columns = [np.ones(size)] if model != PhotometricModel.NONE else []
        if model == PhotometricModel.GAIN_FIELD:
            columns += list(centred)
        fixed = _orthonormal(np.stack(columns, axis=1)) if columns else np.zeros((size, 0))
        gains = np.stack(columns) if model >= PhotometricModel.GAIN_BIAS else np.zeros((0, size))
        return cls(model=model, gains=gains, fixed=fixed)

    def projection(self, template: np.ndarray) -> PhotometricProjection:
        """The projection for (N, M) templates (one patch of M samples per row)."""
        count, size = template.shape
        fixed, first = self.fixed.T, len(self.fixed.T)  # (F, M)
        rows = np.empty((count, first + len(self.gains), size))  # the basis, transposed
        rows[:, :first] = fixed
        if not len(self.gains):
            return PhotometricProjection(basis=rows.transpose(0, 2, 1))
        template = np.ascontiguousarray(template, dtype=float)
        _contrast_rows(template, self.gains, np.ascontiguousarray(fixed), rows)
        return PhotometricProjection(basis=rows.transpose(0, 2, 1))


@numba.njit(**FAST)
def project_out_row(row: np.ndarray, patch: np.ndarray, weights: np.ndarray) -> None:
    """``row - U U' row`` in place, for one (M,) row of a patch and its (K, M) rows U'.

    ``weights`` is a (K,) scratch buffer. The dot products may be reassociated (vectorised);
    infinities and NaNs propagate. Other kernels call it on their own rows.
    """
    columns, size = patch.shape
    for k in range(columns):
        total = 0.0
        for m in range(size):
            total += row[m] * patch[k, m]
        weights[k] = total
    for k in range(columns):
        weight = weights[k]
        for m in range(size):
            row[m] -= weight * patch[k, m]


@numba.njit('(f8[:, :, ::1], f8[:, :, ::1])', **FAST)
def project_out(values: np.ndarray, basis_rows: np.ndarray) -> None:
    """``values - (values U) U'`` in place per patch n: (J, N, M) rows, (N, K, M) orthonormal U'.

    A basis of one patch (N = 1) serves every patch. Other kernels call it on their own rows
    (the mono tracker's Jacobian, :func:`~face_tracking_ros.tracking.mono_kernels.linearised`).
    """
    weights = np.empty(basis_rows.shape[1])
    for n in range(values.shape[1]):
        patch = basis_rows[n if len(basis_rows) > 1 else 0]
        for j in range(values.shape[0]):
            project_out_row(values[j, n], patch, weights)


@numba.njit(**FAST)
def projected_difference(
    samples: np.ndarray, template: np.ndarray, basis_rows: np.ndarray
) -> np.ndarray:
    """(N, M) ``samples - template`` projected per patch by ``1 - U U'`` (:func:`project_out`).

    :meth:`PhotometricProjection.residuals`; other kernels call it on their own samples.
    Compiled (or loaded from numba's cache) at the first call with each pair of types, float32
    or float64: a mono replay calls two of the four from Python, whose loading took 4 ms each.
    """
    count, size = samples.shape
    projected = np.empty((1, count, size))
    for n in range(count):
        for m in range(size):
            projected[0, n, m] = samples[n, m] - template[n, m]
    project_out(projected, basis_rows)
    return projected[0]


@numba.njit(
    '(f8[:, ::1], f8[:, ::1], f8[:, ::1], f8[:, :, ::1])',
    **FAST,
)
def _contrast_rows(
    template: np.ndarray, gains: np.ndarray, fixed: np.ndarray, rows: np.ndarray
) -> None:
    """The template-dependent basis rows of each patch, into ``rows[:, F:]``.

    Column g of patch n is its contrast ``c = T - mean(T)`` times the gain field g, made
    orthogonal to the F fixed columns (twice: Gram-Schmidt keeps orthogonality so) and then to
    the patch's earlier contrast columns (modified Gram-Schmidt), and normalised. A column whose
    norm after that (QR's |R_jj|) is below 1e-6 sqrt(M) (|R_00| = sqrt(M)) is one the template
    does not need: it is zero.

    Args:
        template: (N, M) templates.
        gains: (G, M) gain fields.
        fixed: (F, M) orthonormal rows of the template-independent changes.
        rows: (N, F + G, M) the basis rows; rows[:, :F] are the fixed rows (read), rows[:, F:]
            are written.
    """
    count, size = template.shape
    first = fixed.shape[0]
    threshold = 1e-6 * np.sqrt(size)
    contrast = np.empty(size)
    weights = np.empty(first)
    for n in range(count):
        mean = np.mean(template[n])
        for m in range(size):
            contrast[m] = template[n, m] - mean
        for g in range(gains.shape[0]):
            column = rows[n, first + g]
            for m in range(size):
                column[m] = contrast[m] * gains[g, m]
            for _ in range(2):
                weights[:] = 0.0
                for f in range(first):
                    for m in range(size):
                        weights[f] += column[m] * fixed[f, m]
                for f in range(first):
                    for m in range(size):
                        column[m] -= weights[f] * fixed[f, m]
            for other in range(first, first + g):
                weight = 0.0
                for m in range(size):
                    weight += column[m] * rows[n, other, m]
                for m in range(size):
                    column[m] -= weight * rows[n, other, m]
            norm = np.sqrt(np.sum(column * column))
            scale = 0.0 if norm <= threshold else 1.0 / norm
            for m in range(size):
                column[m] *= scale


def _orthonormal(columns: np.ndarray) -> np.ndarray:
    """Orthonormal (M, K) basis of the span of (M, K) columns; dependent columns become zero."""
    basis, triangular = np.linalg.qr(columns)
    scale = np.abs(np.diagonal(triangular))
    return basis * (scale > 1e-6 * max(scale[0], 1e-12))
