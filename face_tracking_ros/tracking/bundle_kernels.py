"""Compiled (numba) normal equations of the bundle adjustment's views (:mod:`.bundle`).

Each iteration of an adjustment forms ``J' W J`` and ``J' W r`` of every view's ROI samples: a
dozen dense rows (the view's omega, t and alpha) and six rows per node (its skin depth terms,
which act on that node's samples alone), all photometrically projected. As numpy expressions
that was the projection of a stacked (17, N, M) Jacobian (a 0.5 MB temporary with 34 nodes),
then batched products per node and the transposes feeding them. Here one pass per node projects
its rows in a small buffer and adds its blocks straight into the adjustment's normal equations:
with the bases made once per adjustment, the adjustments of a 300-frame 34-node track took x0.69
of their time. The sums may be reassociated (vectorised), so they agree with numpy's to
rounding.
"""

from __future__ import annotations

import numba
import numpy as np

from face_tracking_ros.compiled import FAST
from face_tracking_ros.imaging.photometric import project_out_row


@numba.njit(
    '(f8[:, :, ::1], f8[:, :, ::1], f8[:, :, ::1], f8[:, ::1], f8[:, ::1], i8, i8, f8[:, ::1], '
    'f8[::1])',
    **FAST,
)
def add_view_normal_equations(
    jacobian: np.ndarray,
    surface: np.ndarray,
    basis_rows: np.ndarray,
    irls: np.ndarray,
    residuals: np.ndarray,
    local: int,
    depth: int,
    hessian: np.ndarray,
    gradient: np.ndarray,
) -> None:
    """Add one view's ``J' W J`` to ``hessian`` and ``J' W r`` to ``gradient``, in place.

    Node n's rows of J are the projected derivatives of its samples with respect to the view's
    D unknowns, then its S skin depth terms: ``surface[s]`` times the derivative along the
    sample's ray (zero off node n's samples, so only node n's are formed).

    Args:
        jacobian: (D + 1, N, M) unprojected derivatives of the samples with respect to the
            view's unknowns, and to a move along the sample's ray (last).
        surface: (S, N, M) the skin depth basis at the samples.
        basis_rows: (N, K, M) the photometric projection's rows U' (one patch's rows serve all
            patches when N = 1), :class:`~face_tracking_ros.imaging.PhotometricProjection`.
        irls: (N, M) the IRLS weights W (over s^2).
        residuals: (N, M) the projected residuals r.
        local: index of the view's first unknown.
        depth: index of node 0's first skin depth term; node n's are at ``depth + n S``.
        hessian: (P, P) the normal matrix to add to.
        gradient: (P,) the gradient to add to.
    """
    dense = jacobian.shape[0] - 1
    terms, nodes, size = surface.shape
    count = dense + terms
    rows = np.empty((count, size))
    weighted = np.empty((count, size))
    index = np.empty(count, dtype=np.int64)
    scratch = np.empty(basis_rows.shape[1])
    for n in range(nodes):
        patch = basis_rows[n if len(basis_rows) > 1 else 0]
        for a in range(count):
            if a < dense:
                index[a] = local + a
                rows[a] = jacobian[a, n]
            else:
                index[a] = depth + n * terms + a - dense
                for m in range(size):
                    rows[a, m] = surface[a - dense, n, m] * jacobian[dense, n, m]
            project_out_row(rows[a], patch, scratch)
            for m in range(size):
                weighted[a, m] = rows[a, m] * irls[n, m]
        for a in range(count):
            total = 0.0
            for m in range(size):
                total += weighted[a, m] * residuals[n, m]
            gradient[index[a]] += total
            for b in range(a, count):
                total = 0.0
                for m in range(size):
                    total += weighted[a, m] * rows[b, m]
                hessian[index[a], index[b]] += total
                if b != a:
                    hessian[index[b], index[a]] += total
