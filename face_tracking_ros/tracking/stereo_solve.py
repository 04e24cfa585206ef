"""One stereo pair's E(n) and its damped Gauss-Newton solve on a pyramid level (§3.3, eq. 4, 5).

E(n), over all 3N node coordinates X_c of pair n (:class:`PairEnergy`), is eq. 4's image terms
over the node patches (deformed with the mesh, :class:`~.surface_patches.PatchDeformation`) and
the §4.2 face texture, with Huber weights and each split (1 - epsilon) : epsilon between frame
n - 1 and frame 1 (the drift term of eq. 6), plus eq. 5's regularisation (:mod:`.regularisation`)
and the face-model term (eq. 1 and 3, :mod:`.action_prior`). :class:`LevelSolver` minimises it
by Levenberg-Marquardt on one pyramid level of the pair (:class:`Level`), with the Gauss-Newton
normal equations of every term. The tracker (:class:`~.stereo.StereoTracker`) builds the energy
from its state and runs the levels coarse to fine.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.linalg import LinAlgError
from scipy.linalg.lapack import dpotrf, dpotrs

from face_tracking_ros.imaging import PyramidLevel
from face_tracking_ros.tracking.action_prior import ActionPrior, ModelPoint, PriorEvaluation
from face_tracking_ros.tracking.regularisation import Regulariser
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_data import (
    Huber,
    Residuals,
    Sampled,
    SampleSet,
    node_blocks,
    robust_residuals,
    sample_images,
)
from face_tracking_ros.tracking.stereo_kernels import largest_motion
from face_tracking_ros.tracking.surface_patches import PatchDeformation, patch_field


class Level(NamedTuple):
    """One pyramid level of the current pair, with everything its iterations share."""

    index: int
    images: tuple[PyramidLevel, PyramidLevel]  # made where sampled
    projections: np.ndarray  # (2, 3, 4) P of eq. 2 onto this level
    offsets: np.ndarray  # (3, S) sample offsets at this level
    templates: np.ndarray  # (2, K, S) float32 T_k of each image


class Point(NamedTuple):
    """E(n) of eq. 4 + texture + eq. 5 + face-model term at some nodes."""

    nodes: np.ndarray
    cost: float
    sampled: Sampled
    residuals: Residuals
    prior: PriorEvaluation | None


class System(NamedTuple):
    """Gauss-Newton normal equations (node-major) at a point."""

    hessian: np.ndarray  # (3N, 3N)
    gradient: np.ndarray  # (3N,)


@dataclass
class PairEnergy:
    """E(n) of eq. 4 + texture + eq. 5 + face-model term on one stereo pair.

    Its terms stay as given while the pair's levels are solved, but for the face-model term's
    fit ``theta``: each linearisation keeps the fit it made there.

    Attributes:
        samples: the sample set (node patches, then the face texture).
        coefficients: (4, S) a_k of every sample, weighing the templates T_k of a :class:`Level`.
        huber: the Huber thresholds of the image residuals.
        regulariser: the eq. 5 terms.
        previous: (N, 3) the nodes eq. 5 measures the motion from, m: pair n - 1's (after
            dropped pairs, moved rigidly over the gap).
        prior: the face-model term (None: off).
        theta: the face-model term's last fit (None: off).
        deformation: moves the node-patch samples with the mesh (None: rigid patches).
        first_nodes: (N, 3) the frame-1 nodes, m (of the deformation).
        rotation: (3, 3) the head's rotation since frame 1 (of the deformation).
    """

    samples: SampleSet
    coefficients: np.ndarray
    huber: Huber
    regulariser: Regulariser
    previous: np.ndarray
    prior: ActionPrior | None
    theta: ModelPoint | None
    deformation: PatchDeformation | None
    first_nodes: np.ndarray
    rotation: np.ndarray

    def evaluate(self, level: Level, nodes: np.ndarray) -> Point:
        """E(n) of eq. 4 + texture + eq. 5 + face-model term at ``nodes``.

        The images are sampled with their gradients, for a linearisation there.
        """
        samples = self.samples
        field = patch_field(self.deformation, nodes, self.first_nodes, self.rotation)
        points = samples.points(nodes, level.offsets, field, float(1 << level.index))
        sampled = sample_images(level.images, level.projections, points, samples.mask)
        residuals = robust_residuals(
            samples, sampled, level.templates, self.coefficients, self.huber
        )
        cost = self.regulariser.cost(nodes, self.previous)
        prior = None
        if self.prior is not None and self.theta is not None:
            prior = self.prior.evaluate(nodes, self.theta)
            cost += prior.cost
        return Point(nodes, cost + residuals.cost, sampled, residuals, prior)

    def linearise(self, level: Level, point: Point) -> System:
        """Gauss-Newton normal equations at an evaluated point; the face-model fit is kept.

        The terms are summed into the arrays the face-model and image terms made for this
        point, so no (3N, 3N) matrix is allocated for a sum.
        """
        _, hessian, gradient = self.regulariser.normal_equations(point.nodes, self.previous)
        if self.prior is not None and point.prior is not None:
            prior_hessian, prior_gradient = self.prior.normal_equations(point.prior)
            prior_hessian += hessian
            prior_gradient += gradient
            hessian, gradient = prior_hessian, prior_gradient
            self.theta = point.prior.point
        blocks, vectors = node_blocks(
            self.samples, point.sampled, point.residuals, level.projections
        )
        image_hessian, image_gradient = self.samples.assemble(blocks, vectors)
        image_hessian += hessian
        image_gradient += gradient
        return System(image_hessian, image_gradient)


class LevelSolver:
    """Levenberg-Marquardt on a pair's E(n), one pyramid level at a time.

    Args:
        config: the tracker's tunables (the solve's: ``damping``, ``max_iterations``,
            ``step_tolerance``, ``coarse_step_tolerance``).
        projections: (2, 3, 4) P of eq. 2 onto level 0 of both images (a step's motion in px).
    """

    def __init__(self, config: StereoTrackerConfig, projections: np.ndarray) -> None:
        """Keep the tunables and the level-0 projections."""
        self._config = config
        self._projections = projections

    def solve(
        self,
        energy: PairEnergy,
        level: Level,
        nodes: np.ndarray,
        first_step_limit: float = np.inf,
    ) -> tuple[np.ndarray, int, list[float], Point] | None:
        """Levenberg-Marquardt at one pyramid level, from ``nodes``.

        Each trial point's evaluation samples the images with their gradients, so an accepted
        point is linearised from it without sampling again. The step that ends a level
        (smaller than its step tolerance) is taken without evaluating its cost, as the mono
        tracker takes its converged step: a coarse level's next level evaluates that point
        first anyway, and level 0's result keeps the statistics of its last accepted point.

        Returns:
            The nodes, the iterations spent, the accepted costs and the last accepted point
            (where the last linearisation was made); None when the first step would move a
            node more than ``first_step_limit`` px of this level.
        """
        config = self._config
        damping = config.damping
        tolerance = _step_tolerance(config, level.index)
        point = energy.evaluate(level, nodes)
        system = energy.linearise(level, point)
        history = [point.cost]
        iterations = 0
        while iterations < config.max_iterations:
            iterations += 1
            candidate = nodes + _damped_step(system, damping)
            motion = self._pixel_motion(nodes, candidate) / (1 << level.index)  # level px
            if motion > first_step_limit:
                return None
            first_step_limit = np.inf
            if motion < tolerance:
                nodes = candidate  # converged
                break
            trial = energy.evaluate(level, candidate)
            if trial.cost <= point.cost:
                nodes, point = candidate, trial
                history.append(trial.cost)
                damping = max(damping / 10.0, 1e-9)
                system = energy.linearise(level, point)
            else:
                damping *= 10.0
                if damping > 1e3:
                    break
        return nodes, iterations, history[1:], point

    def _pixel_motion(self, nodes: np.ndarray, moved: np.ndarray) -> float:
        """Largest image motion of a node between two estimates, in either camera, px."""
        return largest_motion(self._projections, nodes, moved)


def _step_tolerance(config: StereoTrackerConfig, index: int) -> float:
    """The step that ends a solve on level ``index``, px of that level.

    Level 0's is ``step_tolerance``, the other levels' of the pyramid ``coarse_step_tolerance``;
    the coarser levels a pair after a gap is solved from too (``gap_pyramid_levels``) end on a
    step no longer in level-0 px than the coarsest of the pyramid's: half as long in their own
    px a level down. Ended at ``coarse_step_tolerance`` in its own px (4 px of level 0), level 3
    left a rendered 10 fps pair after 3 dropped ones 9.0 px off after 3 iterations, and the
    pair 3.8 px off (the face-model term then held it, and the track went on there); ending at
    1 px of level 0, 5.1 px and 0.5 px.
    """
    if index == 0:
        return config.step_tolerance
    below_pyramid = max(0, index - config.pyramid_levels + 1)
    return config.coarse_step_tolerance / (1 << below_pyramid)


def _damped_step(system: System, damping: float) -> np.ndarray:
    """Levenberg-Marquardt step (N, 3): ``-(H + damping diag H)^-1 g``, by Cholesky.

    The normal equations are finite: images are finite and non-finite sample points raise.
    """
    augmented = np.array(system.hessian, order='F')  # LAPACK's layout: f2py copies no more
    diagonal = np.einsum('ii->i', augmented)  # a view
    diagonal += damping * diagonal
    # The routines of cho_factor and cho_solve.
    factor, info = dpotrf(augmented, lower=0, clean=0, overwrite_a=1)
    if info != 0:
        msg = f'damped normal matrix is not positive definite (LAPACK potrf info {info})'
        raise LinAlgError(msg)
    step, _ = dpotrs(factor, -system.gradient, lower=0)
    return step.reshape(-1, 3)
