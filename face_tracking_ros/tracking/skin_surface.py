"""The skin around each node, measured in the first stereo pair (eq. 4's cross term at frame 1).

The stereo tracker's node patches (the ROI of eq. 4) lie on the thin-plate surface through the
nodes (:mod:`.surface_patches`). Nineteen or thirty-four nodes cannot carry the shape of a nose
tip or a lip: that surface is smoother than the skin by millimetres within a patch. The
same-camera terms of eq. 4 hardly mind; the cross-camera terms do, since a patch sample off the
skin is seen at different skin points by the two cameras. The solver then moves the node in
depth until the patch matches on average, a bias that stays for the whole track (measured on
synthetic faces: the nose tip 1.9-2.2 mm too far, from frame 1 on; with patches on the true
skin the 19-node RMS error fell from 0.84 / 0.79 to 0.46 / 0.54 mm on two subjects).

The first pair measures the skin. Each sample of node i's patch moves along its left viewing
ray by

    delta_i(u, v) = d_i + sum_k c_ik phi_k(u, v),   phi = (u, v, u^2, u v, v^2)

over patch coordinates (u, v) (camera x and y off the node, in units of the patch's half-width
r_i): a quadratic skin about the thin-plate surface, and the node's own depth d_i. Moving along
the left rays leaves every sample's left pixel, and so the left template, as it is; the right
image measures delta. Gauss-Newton on

    sum_m (I_R(pi_R(P_m)) - I_L(pi_L(P_m)) - b_0 - b_1 u - b_2 v)^2 / s^2 + sum_k (c_ik / tau)^2

per node, with the patch's brightness ramp b (as the tracker removes it, :mod:`.stereo_data`)
solved alongside. Where a patch has little texture the prior ``tau`` keeps it on the thin-plate
surface. The node moves to ``d_i`` on its ray, and :class:`SkinSurface` keeps the patch's skin
as a quadratic about it; the tracker lays its own (smaller) patch on that quadratic.

The thin-plate surface the fit starts from runs through the measured nodes alone: the others'
depths may be guesses (the reference face's), centimetres off on a face that is not the
reference.

Measured over issue 5's 19-node protocol (exact clicks, six subjects of 380 frames each), node
RMS error, mean over the subjects, thin-plate patches -> skin (tau 1 mm): default population
seed 1 0.774 -> 0.736 mm (tau 0.5 mm 0.758, 2 mm 0.753), realistic population seed 2 0.948 ->
0.906 mm; seed 3, with an earlier form of the fit, 0.729 -> 0.702 mm. The largest reprojection
error moved little but for one subject: 1.09 -> 1.11, 1.18 -> 1.30 and 1.18 -> 1.19 px.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.imaging import (
    inside_xy,
    sample_points,
    sample_with_gradient,
    square_offsets,
)
from face_tracking_ros.tracking.surface_patches import surface_patch_offsets

SKIN_TERMS = 5  # u, v, u^2, u v, v^2
_BRIGHTNESS = 3  # b_0 + b_1 u + b_2 v
_MAX_DEPTH_STEP = 0.02  # m: a larger step of a node's depth is a wrong basin; the node stops
_NOISE = 2.0  # s, grey levels: the image noise the skin prior is weighed against
_TOKEN_PRIOR = 1e-6  # squared grey levels per squared brightness coefficient
_MIN_SURFACE_NODES = 3  # a thin-plate surface needs three nodes not on one line


@dataclass(frozen=True)
class SkinSurface:
    """Each measured node's skin: its depth off the node, quadratic in camera x and y.

        z_i(x, y) - z_i = sum_k c_ik phi_k(x / r_i, y / r_i),   phi = (u, v, u^2, u v, v^2)

    with (x, y) off the node. A node not measured keeps its patch on the thin-plate surface.

    Attributes:
        measured: (N,) bool, the nodes whose skin was measured.
        coefficients: (N, SKIN_TERMS) c_ik, m (zero where not measured).
        radius: (N,) r_i, m: the half-width that scales x and y into (u, v).
    """

    measured: np.ndarray
    coefficients: np.ndarray
    radius: np.ndarray

    @classmethod
    def flat(cls, count: int) -> SkinSurface:
        """No skin measured for ``count`` nodes."""
        return cls(np.zeros(count, dtype=bool), np.zeros((count, SKIN_TERMS)), np.ones(count))

    def offsets(self, thin_plate: np.ndarray, grid: np.ndarray) -> np.ndarray:
        """(N, M, 3) patch offsets: on the skin where measured, else on the thin-plate surface.

        Args:
            thin_plate: (N, M, 3) offsets on the thin-plate surface, m.
            grid: (N, M, 2) the samples' camera x and y off their nodes, m.
        """
        depth = np.einsum(
            'nmk,nk->nm', skin_terms(grid / self.radius[:, None, None]), self.coefficients
        )
        skin = np.concatenate([grid, depth[..., None]], axis=-1)
        return np.where(self.measured[:, None, None], skin, thin_plate)


def skin_terms(uv: np.ndarray) -> np.ndarray:
    """(..., SKIN_TERMS) ``u, v, u^2, u v, v^2`` of (..., 2) patch coordinates."""
    u, v = uv[..., 0], uv[..., 1]
    return np.stack([u, v, u * u, u * v, v * v], axis=-1)


def fit_skin(
    rig: StereoRig,
    left: np.ndarray,
    right: np.ndarray,
    nodes: np.ndarray,
    fitted: np.ndarray,
    half_size: int,
    iterations: int,
    prior: float,
) -> tuple[np.ndarray, SkinSurface]:
    """Measure each fitted node's depth and skin in one rectified pair.

    Args:
        rig: the rectified rig.
        left: (H, W) float32 left image.
        right: (H, W) float32 right image.
        nodes: (N, 3) nodes, left camera frame, m.
        fitted: (N,) bool, the nodes measured; they alone shape the thin-plate surface the fit
            starts from (the others' depths may be guesses). Fewer than three: none is.
        half_size: the fitted patch is (2 h + 1)^2 samples, about a pixel apart.
        iterations: Gauss-Newton iterations.
        prior: tau > 0, m: the spread of each skin coefficient the prior allows.

    Returns:
        ``(nodes, skin)``: the nodes, the fitted ones moved along their left rays, and the skin
        (each patch's samples refitted as a quadratic about its moved node).
    """
    count = nodes.shape[0]
    index = np.flatnonzero(fitted)
    if index.size < _MIN_SURFACE_NODES:
        return nodes, SkinSurface.flat(count)
    square = square_offsets(half_size).astype(float)
    spacing = nodes[index, 2] / rig.left.focal
    grid = spacing[:, None, None] * square[None]
    points = nodes[index, None, :] + surface_patch_offsets(nodes[index], grid)
    uv = np.broadcast_to(square / max(half_size, 1), points.shape[:2] + (2,))
    rays = points / np.linalg.norm(points, axis=-1, keepdims=True)
    template = sample_points(left, rig.left.project(points.reshape(-1, 3)).reshape(*uv.shape))
    design = np.concatenate(
        [np.ones(uv.shape[:2] + (1,)), skin_terms(uv), -_brightness(uv)], axis=-1
    )
    # The node's depth and the brightness get a token prior, so a patch without texture, or
    # outside the right image, keeps them where they are instead of making the system singular.
    weights = np.full(design.shape[-1], _TOKEN_PRIOR)
    weights[0] = (_NOISE / _MAX_DEPTH_STEP) ** 2
    weights[1 : 1 + SKIN_TERMS] = (_NOISE / prior) ** 2
    theta = np.zeros((index.size, design.shape[-1]))
    for _ in range(iterations):
        step = _skin_step(rig, right, points, rays, template, design, theta, weights)
        wrong = np.abs(step[:, 0]) > _MAX_DEPTH_STEP
        theta = theta + np.where(wrong[:, None], 0.0, step)
    depth = np.einsum('kmp,kp->km', design[..., : 1 + SKIN_TERMS], theta[:, : 1 + SKIN_TERMS])
    skin_points = points + rays * depth[..., None]
    moved = nodes.copy()
    moved[index] = skin_points[:, (square.shape[0] - 1) // 2]
    measured = np.zeros(count, dtype=bool)
    measured[index] = True
    radius = np.ones(count)
    radius[index] = spacing * max(half_size, 1)
    coefficients = np.zeros((count, SKIN_TERMS))
    coefficients[index] = _quadratic(skin_points - moved[index, None, :], radius[index])
    return moved, SkinSurface(measured, coefficients, radius)


def _quadratic(offsets: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(K, SKIN_TERMS) least-squares c of ``z = sum_k c_k phi_k(x / r, y / r)`` per patch.

    Args:
        offsets: (K, M, 3) the skin's samples off their nodes, m.
        radius: (K,) r, m.
    """
    terms = skin_terms(offsets[..., :2] / radius[:, None, None])
    normal = np.einsum('kmp,kmq->kpq', terms, terms)
    return np.linalg.solve(normal, np.einsum('kmp,km->kp', terms, offsets[..., 2])[..., None])[
        ..., 0
    ]


def _brightness(uv: np.ndarray) -> np.ndarray:
    """(..., 3) ``1, u, v``: a patch's brightness ramp."""
    return np.concatenate([np.ones(uv.shape[:-1] + (1,)), uv], axis=-1)


def _skin_step(
    rig: StereoRig,
    right: np.ndarray,
    points: np.ndarray,
    rays: np.ndarray,
    template: np.ndarray,
    design: np.ndarray,
    theta: np.ndarray,
    prior: np.ndarray,
) -> np.ndarray:
    """One Gauss-Newton step (K, 1 + SKIN_TERMS + 3) of every fitted node's parameters.

    Args:
        rig: the rectified rig.
        right: (H, W) float32 right image.
        points: (K, M, 3) the patch samples on the thin-plate surface, m.
        rays: (K, M, 3) their unit left rays.
        template: (K, M) the left image at the samples.
        design: (K, M, P) d(delta)/d(theta) for the depth part, -(1, u, v) for the brightness.
        theta: (K, P) current parameters: depth d_i, skin c_i, brightness b_i.
        prior: (P,) the prior's weight on each parameter (in units of squared residuals).
    """
    depth_part = 1 + SKIN_TERMS
    delta = np.einsum('kmp,kp->km', design[..., :depth_part], theta[:, :depth_part])
    moved = (points + rays * delta[..., None]).reshape(-1, 3)
    pixels, projection = rig.right.project_with_jacobian(moved)
    values, gradient = sample_with_gradient(right, pixels)
    slope = np.einsum('sa,sab,sb->s', gradient, projection, rays.reshape(-1, 3))
    residual = (
        values.reshape(template.shape)
        - template
        + np.einsum('kmp,kp->km', design[..., depth_part:], theta[:, depth_part:])
    )
    jacobian = design.copy()
    jacobian[..., :depth_part] *= slope.reshape(template.shape)[..., None]
    use = inside_xy(pixels[:, 0], pixels[:, 1], right.shape, 1.0).reshape(template.shape)
    jacobian *= use[..., None]
    residual = np.where(use, residual, 0.0)
    hessian = np.einsum('kmp,kmq->kpq', jacobian, jacobian) + np.diag(prior)
    gradient_vector = np.einsum('kmp,km->kp', jacobian, residual) + prior * theta
    return -np.linalg.solve(hessian, gradient_vector[..., None])[..., 0]
