"""Monocular model-based tracking of pose and expression (seed §3.5, eq. 6, §4.4).

For each new image I_n the tracker estimates the pose (omega, t) of eq. 1 and the expression alpha
of eq. 3, with the identity sigma held fixed, by minimising eq. 6::

    C_n = sum_(i, ROI) (1 - epsilon) (I_n(x_i(n)) - I_(n-1)(x_i(n-1)))^2
                       + epsilon (I_n(x_i(n)) - I_1(x_i(1)))^2

plus the §4.1/§4.4 Gaussian prior on alpha, ``lambda alpha' Sigma_alpha^-1 alpha``.

Design, in the seed's terms:

- Regions of interest are small 3-D surface patches in the face frame around each node, on
  the thin-plate surface through the nodes (:mod:`.surface_patches`), projected through eq. 1-2
  at frames n, n-1 and 1: they foreshorten with out-of-plane rotation, so the templates of frames
  n-1 and 1 stay comparable as the head turns (the seed's §4.4 weak point). The samples deform
  with eq. 3 like the skin between the nodes (the node bases carried to them by thin-plate
  interpolation, :func:`~.surface_patches.patch_basis`), so an expression stretches the patches
  instead of being read as a head rotation (§4.4's x-axis error): measured on a 1000-frame
  synthetic sequence with an exact model and initialisation, pitch error 0.96 -> 0.37 degrees
  and alpha error 7.3 -> 2.6 % (flat lighting); under moving light 1.18 -> 0.81 degrees.
- Face-edge nodes weigh ``edge_weight`` (0.1) in eq. 6: the skin there turns away from the
  camera, so its shading and outline change most with pose and light (measured on another
  sequence with an exact model, initialisation and surface under moving light: pitch error 1.67
  -> 0.36 degrees without them). They still enter the initial fit, which needs their 2-D
  positions most.
- Both terms of eq. 6 share ``I_n(x_i(n))``, so eq. 6 equals ``sum (I_n(x_i(n)) - T)^2`` plus a
  constant, with the blended template ``T = (1 - epsilon) I_(n-1)(x(n-1)) + epsilon I_1(x(1))``:
  one residual per sample, and the exact Gauss-Newton step of eq. 6.
- Residuals ignore a brightness gain and bias varying linearly across each ROI
  (:mod:`~face_tracking_ros.imaging.photometric`): the shading of a turning head under a fixed
  light changes far more than eq. 6's brightness constancy allows.
- Levenberg-Marquardt over (omega, t, alpha) (and sigma during the first ``sigma_frames`` frames),
  coarse to fine on a Gaussian pyramid (made where the ROIs read it,
  :meth:`~face_tracking_ros.imaging.pyramid.ImagePyramid.level`), with Huber IRLS weights,
  per-node visibility (nodes whose normal turns away from the camera lose their weight) and
  analytic Jacobians: the image gradient sampled on the patches times d pixel / d X_c (eq. 2)
  times d X_c / d(omega, t, alpha) (eq. 1, 3), evaluated where a pyramid level starts and
  refreshed after half a pixel of motion. A level
  ends when the nodes stop moving or a step raises the cost. Each frame starts from the
  constant-velocity prediction of the last two estimates, and a coarser level runs only when
  the first step on a finer one shows the face is too far for it. The loops over the ROI samples
  are compiled (:mod:`.mono_kernels`).
- Frame 1's estimate and the skin under the ROIs are refined from the first views: frames that
  show the head at new rotations (``bundle.view_spacing`` apart, up to ``bundle.views``) are
  kept, and a photometric bundle adjustment (:mod:`.bundle`) of frame 1's pose, alpha and
  sigma, the skin depth under every ROI and the views' poses runs over every view so far; the
  track then continues from its result (frame 1's templates re-sampled, the ROIs on the
  measured skin). Measured on the benchmark's 1000-frame sequences, 3 seeds x 3 draws of 1 px
  click noise: rotation error 1.21 / 1.20 -> 0.62 / 0.77 degrees (x / y). An adjustment costs
  about ten times a frame's solve, so it runs two stages per frame (``bundle.stages_per_frame``,
  :mod:`.stages`) and is applied about five frames after its newest view, the head's motion
  since then carried over; no frame pays for all of it. Those stages run after the frame's
  result is out (:meth:`MonoTracker.track`, then :meth:`MonoTracker.adjust`; ``step`` does
  both), so a live node publishes the pose before it spends time on them, and an adjustment
  takes effect from the frame after its last stage.
- Optionally (``max_keyframes`` > 1) the drift term compares with the keyframe nearest in
  rotation instead of frame 1. Measured on synthetic sequences it does worse than I_1 alone
  (keyframes inherit the error of the pose they were taken at), so it is off by default.
- Loss of track gives status LOST with the last valid estimate. It is declared when most
  textured nodes' ROIs do not match their templates, when they match the previous frame but no
  longer the first one (the median residual against the keyframe's templates alone, a drifted
  track), when too few nodes are visible, the rotation jumps, or the solve is ill-conditioned or
  non-finite. A node matches when its residual (the
  brightness change projected out) is small against its ROI's texture in the image: what is
  left of the ROI after removing the brightness change that needs no template (its mean and, for
  GAIN_FIELD, its linear ramp, which alone fit a smooth backdrop or hand). An image ROI with no
  texture above ``residual_scale_floor`` cannot confirm a textured template.
- Recovery needs no detector. While LOST, each image is solved as the frame after the last
  valid one (eq. 6 from its estimate and templates); if that fails, as when tracking fails,
  it is solved against the keyframe templates alone from the initial pose translated onto the
  best normalised cross-correlation of frame 1's inner face over the image, and from a fresh
  detection when a detector was given. The keyframe-only solves, and every solve while LOST,
  pass only at the stricter ``reacquire_residual_ratio``: they can settle a few pixels off.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cache
import math
from typing import NamedTuple

import cv2
import numpy as np
from numpy.linalg import LinAlgError
from scipy.linalg import inv

from face_tracking_ros.errors import ConfigError, InputError, check_fields
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import matrix_to_omega, rodrigues
from face_tracking_ros.imaging import (
    ImagePyramid,
    PhotometricInvariance,
    PhotometricModel,
    PhotometricProjection,
    check_levels_fit,
    inside_image,
    inside_xy,
    sample_with_gradient_xy,
    sample_xy,
    square_offsets,
)
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import Group
from face_tracking_ros.tracking.bundle import (
    SURFACE_TERMS,
    BundleConfig,
    Estimate,
    Patches,
    Problem,
    adjustment_stages,
    ray_directions,
    skin_offsets,
    surface_basis,
)
from face_tracking_ros.tracking.coarse_to_fine import coarse_to_fine
from face_tracking_ros.tracking.initialisation import (
    FitConfig,
    Initialisation,
    fit_model_to_points,
)
from face_tracking_ros.tracking.mono_kernels import (
    damped_step,
    huber_irls,
    normal_equations,
    roi_jacobian,
    roi_points,
    weighted_gram,
)
from face_tracking_ros.tracking.projection import POSE_DIM
from face_tracking_ros.tracking.result import TrackResult, TrackStatus
from face_tracking_ros.tracking.stages import Stages, run_stages
from face_tracking_ros.tracking.surface_patches import (
    node_frames,
    patch_basis,
    patch_interpolation,
    surface_patch_interpolation,
    surface_patch_offsets,
)

Detector = Callable[[np.ndarray], Initialisation | None]
"""A landmark detector: (H, W) uint8 grey image -> 2-D node positions, or None if no face."""

_MIN_DEPTH = 0.05  # m; a face nearer the camera than this has diverged
# Pyramid level of the search for a lost face (or the coarsest, if coarser): on the coarsest level
# of a 320x240 image the inner face is 11x12 px and correlates as well with clutter.
_SEARCH_LEVEL = 1
# The level a solve starts on unless the motion prediction is small (fine_start_px).
_START_LEVEL = 1
_MAD_TO_STD = 1.4826  # robust standard deviation from the median absolute deviation


@dataclass(frozen=True)
class MonoTrackerConfig:
    """Tunables of the monocular tracker, each tied to its symbol.

    Attributes:
        epsilon: drift-monitoring weight epsilon of eq. 6, in [0, 1] (seed: 0.2).
        pyramid_levels: number of Gaussian pyramid levels, coarse to fine (>= 1; the coarsest
            at least 16 px). The coarsest is solved on demand (``coarsest_level_px``), so a
            deeper pyramid costs little but takes faster motion. Measured on issue 6's three
            sequences with every 4th frame (true model, raw pose), 3 -> 4 levels: rotation MAE
            1.95 / 2.68 / 21.5 -> 0.86 / 0.88 / 0.77 degrees about x, LOST frames 0 / 83 / 0
            -> 0 (seed 2 had locked onto a pose 21-27 degrees off, reported as TRACKING); every
            5th frame LOST 24 / 49 / 5 -> 0; every frame and every 2nd frame within 0.03
            degrees. Tracking time +6 % in one process, alternating on the live benchmark's
            stream (p50 2.44 -> 2.58 ms), when every level's templates were sampled on every
            frame; they are now sampled only for the levels solved.
        smooth_base: smooth the full-resolution level (sigma ~ 1 px) against the bias of bilinear
            sampling towards whole pixels (see :meth:`ImagePyramid.build`). It holds the
            jitter down and the track on: measured off on issue 6's protocol, the rotation error
            moved both ways (0.81 / 0.83 / 0.21 -> 0.67 / 0.89 / 0.24 deg) but the published
            jitter on a still head went 0.034 -> 0.064 deg (worst seed 0.104, against the 0.05
            target) and the track without the drift term was lost on 492 frames; with the face
            half as large (the small-face row), 2.58 / 3.46 -> 1.88 / 2.57 deg where it tracked,
            but one seed lost 446 of its 1000 frames.
        max_iterations: Levenberg-Marquardt iterations per pyramid level (>= 1).
        patch_half_size: h; each node's ROI has (2 h + 1)^2 samples (>= 1).
        patch_spacing_px: ROI sample spacing at level 0 and the initial depth, px (> 0); the ROI
            is a 3-D patch, so its image size follows the face's distance and orientation.
        edge_weight: weight of the face-edge nodes' ROIs in eq. 6 relative to the inner nodes'
            (in [0, 1]). Their skin turns away from the camera, so its shading and outline change
            most with pose and light; the edge nodes still enter the initial fit and the mesh.
        edge_patch_shift: face-edge nodes' ROIs are shifted inwards by this fraction of h, so
            they hold face texture rather than background (in [0, 1]).
        photometric: brightness change of each ROI that eq. 6's residuals ignore: GAIN_FIELD
            (gain and bias varying linearly across the ROI: shading of a turning head, light
            and exposure changes), GAIN_BIAS, BIAS or NONE (the seed).
        huber_k: Huber threshold of the IRLS weights, in robust standard deviations (> 0).
        residual_scale_floor: smallest robust residual scale s, grey levels (> 0).
        prior_weight: lambda of the alpha prior ``lambda alpha' Sigma_alpha^-1 alpha`` (and of
            the sigma prior while sigma is estimated), in units of squared residuals / s^2
            (>= 0; 0 switches the prior off). Neighbouring ROI samples are far from
            independent (1.5 px apart in a smooth image), so the data term overstates its
            evidence by about an order of magnitude and lambda ~ 10 weighs the prior as a
            posterior would (measured: alpha error 14.5 -> 11.7 % and rotation 2.27 -> 1.80
            degrees in x on one 1000-frame sequence, lambda 1 -> 10).
        max_keyframes: most keyframes kept (>= 1). Eq. 6's drift term compares I_n with I_1; with
            more than one, it compares with the keyframe whose pose is nearest the current one,
            so templates are never seen from far off their own viewpoint (1: the seed's I_1).
        keyframe_spacing: a successful frame becomes a keyframe when its rotation differs from
            every keyframe's by more than this, rad (> 0).
        sigma_frames: frames after an initialisation during which sigma is estimated with the
            pose by eq. 6, then held fixed (>= 0; 0 keeps the sigma of the initial fit, which
            the bundle adjustment of the first views refines, or of the enrolment).
            Against templates sampled at the initial sigma this is poorly posed: on a
            1000-frame synthetic sequence 30 frames gave 7.5 degrees of pitch error and 100
            frames 1.4 / 2.1 degrees (x / y) against 2.4 / 1.1 with 0, so 0 is the default.
        damping: Levenberg-Marquardt damping, relative to diag(H), divided by 10 before each
            step of a level (its first step uses a tenth of it; at least 1e-9) (> 0).
        convergence_px: level 0 stops when no node moves more than this, level px (> 0).
            Measured at 0.05 against 0.01 on issue 6's three 1000-frame sequences (34 nodes,
            true model): the rotation errors the same to 0.001 degrees, z and node RMS to 0.01
            mm, and one evaluation fewer per frame (level 0: 3.0 -> 2.1 on the speed
            benchmark's sequence).
        coarse_convergence_px: a coarser level stops when no node moves more than this, level
            px (> 0); it only has to bring the next level within its reach.
        jacobian_refresh_px: the Jacobian is re-evaluated after the nodes have moved this far
            since it was last evaluated, level px (> 0).
        predict_motion: start a followed frame's solve from the constant-velocity prediction
            (the head's turn and shift between the last two estimates, repeated) instead of
            the last estimate. Measured on issue 6's three 1000-frame sequences: the same
            errors to 0.01 degrees with 34 nodes, and 18 % fewer Jacobians per frame.
        fine_start_px: a followed frame's solve starts on level 0 when the motion prediction
            moves every node less than this from the last estimate, px (>= 0; 0 never starts
            there); otherwise, and without a prediction, on level 1. Slow motion leaves level 1
            nothing that level 0 cannot do from the prediction; a solve from level 0 that fails
            (a sudden stop or reversal) is made again from the last estimate on levels 1 and 0,
            then if need be from the coarsest level. Measured on issue 6's three 1000-frame
            sequences (34 nodes, true model; before that first retry): 81-96 % of the frames
            start on level 0 at 3 px, the tracking time per frame falls by about a third,
            restarts on the coarsest level 7-11 -> 7-8 %, and the errors move both ways
            (rotation MAE 0.80 / 0.82 / 0.20 -> 0.82 / 0.83 / 0.21 degrees, z 3.40 -> 3.29 mm,
            node RMS 4.39 -> 4.30 mm). With every 2nd frame (motion twice as fast) they move
            both ways too (yaw 0.86 / 0.91 / 0.71 -> 0.86 / 0.84 / 0.71 degrees, z 4.6 / 3.0 /
            2.0 -> 4.6 / 3.5 / 2.0 mm); with every 3rd or 5th frame few frames start on level
            0 and the errors are the same to 0.001 degrees.
        coarsest_level_px: the coarser pyramid levels are solved only when the first step on
            the level the solve starts on moves a node more than this, px of level 0 (>= 0; 0
            always solves the coarsest); the solve then starts over, from level 1 if it started on
            level 0 (whose first step may move a node this far in px of level 1), else from the
            coarsest (:func:`.coarse_to_fine`). Level 1 before the coarsest
            (against the coarsest at once): on the live benchmark's stream 23 of 28 such frames
            need no coarser level, tracking p99 6.2 / 5.6 / 6.3 -> 5.6 / 5.1 / 4.7 ms in three
            alternating runs, the errors on issue 6's sequences the same within 0.002 degrees
            with every 1st, 2nd, 3rd and 5th frame. Measured with the prediction,
            starting on level 1, on issue 6's sequences: Jacobians per frame 3.0-3.7 ->
            2.1-2.5 at 1 px, errors within 0.01 degrees with 34 nodes. On every 5th frame
            (motion 5 times faster), 5 of 6 tracks were unchanged to 0.01 degrees at 1 px; at
            2 px, 3 of 6 lost frames.
        visibility_cos: a node's weight ramps from 0 to 1 as the cosine between its outward
            normal and the ray to the camera goes from this value to twice it (in [0, 0.5)).
        lost_residual_ratio: a node fails when its RMS residual exceeds this multiple of its
            ROI's texture in the image (the RMS left after removing its mean and, for
            GAIN_FIELD, its linear ramp), i.e. when sqrt(1 - R^2) of the template's fit to that
            texture exceeds it, or when that texture is below ``residual_scale_floor`` (> 0).
        reacquire_residual_ratio: the same ratio for the solves that may resume a lost track
            and for the keyframe-only solves tried when tracking fails (> 0). Stricter: such a
            solve can settle a few px off the face, which later frames do not correct.
        drift_residual_ratio: LOST when the median, over the visible textured nodes, of a
            node's RMS residual against the nearest keyframe's templates alone (frame 1's by
            default; no blend with frame n-1) exceeds this multiple of its ROI's texture: the
            track has drifted away from what the face looked like (> 0). Measured on the
            1000-frame benchmark sequences: at most 0.65 on the 34-node tracks (true and learned
            models, errors up to 15 degrees), 0.68 median and 0.84 95th percentile on a 19-node
            track that had drifted 15 to 55 degrees; at 0.75 that track is re-acquired when it
            drifts (rotation MAE in x 18.0 -> 6.8 degrees) and the others are unchanged.
        lost_node_fraction: LOST when more than this fraction of the visible nodes that show
            texture (in the image or the template) fail (in (0, 1]).
        min_visible_fraction: LOST when fewer nodes are visible and inside the image (in [0, 1]).
        max_rotation_step: LOST when the rotation is more than this per frame from the last
            valid estimate, rad (> 0).
        max_condition: LOST when the Jacobi-scaled normal matrix has a larger condition number
            (> 1).
        fit: the model fit to initialisation points (:class:`FitConfig`).
        bundle: the bundle adjustment of the first views (:class:`~.bundle.BundleConfig`).
    """

    epsilon: float = 0.2
    pyramid_levels: int = 4
    smooth_base: bool = True
    max_iterations: int = 4
    patch_half_size: int = 4
    patch_spacing_px: float = 1.5
    edge_weight: float = 0.1
    edge_patch_shift: float = 1.0
    photometric: PhotometricModel = PhotometricModel.GAIN_FIELD
    huber_k: float = 2.0
    residual_scale_floor: float = 2.0
    prior_weight: float = 10.0
    max_keyframes: int = 1
    keyframe_spacing: float = 0.14
    sigma_frames: int = 0
    damping: float = 1e-4
    convergence_px: float = 0.05
    coarse_convergence_px: float = 0.1
    jacobian_refresh_px: float = 0.5
    predict_motion: bool = True
    fine_start_px: float = 3.0
    coarsest_level_px: float = 1.0
    visibility_cos: float = 0.1
    lost_residual_ratio: float = 0.65
    reacquire_residual_ratio: float = 0.3
    drift_residual_ratio: float = 0.75
    lost_node_fraction: float = 0.5
    min_visible_fraction: float = 0.5
    max_rotation_step: float = 0.35
    max_condition: float = 1e10
    fit: FitConfig = field(default_factory=FitConfig)
    bundle: BundleConfig = field(default_factory=BundleConfig)

    def __post_init__(self) -> None:
        """Validate every field; the error names the field and its value."""
        checks = {
            'epsilon': 0.0 <= self.epsilon <= 1.0,
            'pyramid_levels': self.pyramid_levels >= 1,
            'max_iterations': self.max_iterations >= 1,
            'patch_half_size': self.patch_half_size >= 1,
            'patch_spacing_px': self.patch_spacing_px > 0,
            'edge_weight': 0.0 <= self.edge_weight <= 1.0,
            'edge_patch_shift': 0.0 <= self.edge_patch_shift <= 1.0,
            'huber_k': self.huber_k > 0,
            'residual_scale_floor': self.residual_scale_floor > 0,
            'prior_weight': self.prior_weight >= 0,
            'max_keyframes': self.max_keyframes >= 1,
            'keyframe_spacing': self.keyframe_spacing > 0,
            'sigma_frames': self.sigma_frames >= 0,
            'damping': self.damping > 0,
            'convergence_px': self.convergence_px > 0,
            'coarse_convergence_px': self.coarse_convergence_px > 0,
            'jacobian_refresh_px': self.jacobian_refresh_px > 0,
            'fine_start_px': self.fine_start_px >= 0,
            'coarsest_level_px': self.coarsest_level_px >= 0,
            'visibility_cos': 0.0 <= self.visibility_cos < 0.5,
            'lost_residual_ratio': self.lost_residual_ratio > 0,
            'reacquire_residual_ratio': self.reacquire_residual_ratio > 0,
            'drift_residual_ratio': self.drift_residual_ratio > 0,
            'lost_node_fraction': 0.0 < self.lost_node_fraction <= 1.0,
            'min_visible_fraction': 0.0 <= self.min_visible_fraction <= 1.0,
            'max_rotation_step': self.max_rotation_step > 0,
            'max_condition': self.max_condition > 1,
        }
        check_fields(self, checks)


class _Params(NamedTuple):
    """The estimated quantities of eq. 1 and 3."""

    omega: np.ndarray
    t: np.ndarray
    alpha: np.ndarray
    sigma: np.ndarray

    def updated(self, step: np.ndarray, q: int) -> _Params:
        """Parameters after a solver step over (omega, t, alpha[, sigma])."""
        sigma_step = step[POSE_DIM + q :]
        return _Params(
            omega=self.omega + step[:3],
            t=self.t + step[3:6],
            alpha=self.alpha + step[POSE_DIM : POSE_DIM + q],
            sigma=self.sigma + sigma_step if sigma_step.size else self.sigma,
        )


class _Roi(NamedTuple):
    """One pyramid level's ROI samples relative to their nodes, deforming with eq. 3.

    Attributes:
        offsets: (3, N, M) offsets from each node to its samples at alpha = 0 and the track's
            initial sigma, face frame, component-major, m.
        action: (q, 3, N, M) their derivative with respect to alpha (:func:`patch_basis`).
        identity: (p, 3, N, M) their derivative with respect to sigma.
        sigma: (p,) the sigma of ``offsets``.
    """

    offsets: np.ndarray
    action: np.ndarray
    identity: np.ndarray
    sigma: np.ndarray

    def basis(self, free_sigma: bool) -> np.ndarray:
        """(c, 3, N, M) derivative of the offsets with respect to alpha (then sigma)."""
        if not free_sigma:
            return self.action
        return np.concatenate([self.action, self.identity])


class _Level(NamedTuple):
    """One pyramid level of a frame's solve: what stays fixed while it runs.

    Attributes:
        index: the level l.
        pyramid: I_n's pyramid, read through :meth:`ImagePyramid.level`.
        camera: (3, 4) projection matrix P of level pixels (its first two rows times 2^-l).
        roi: the level's ROI samples.
        template: (N, M) blended template T of the level.
        projection: the photometric invariance of the residuals for ``template``.
        visibility: (N, M) the node visibility weight of every sample.
    """

    index: int
    pyramid: ImagePyramid
    camera: np.ndarray
    roi: _Roi
    template: np.ndarray
    projection: PhotometricProjection
    visibility: np.ndarray


class _Sampled(NamedTuple):
    """One level's samples of the ROIs at a pose, and which lie inside the image."""

    samples: np.ndarray  # (N, M) float32
    inside: np.ndarray  # (N, M) bool, at least 1 px inside


class _Linearisation(NamedTuple):
    """Jacobians at a linearisation point on one pyramid level.

    Attributes:
        params: the linearisation point.
        sampled: the level's samples at ``params`` (taken with the gradient).
        jacobian_t: (P, N M) transposed derivative of the projected residuals, grey levels per
            parameter (rows contiguous, for the weighted products of the normal equations).
        hessian: (P, P) ``J' V J`` with the samples' visibility weights V alone; the normal
            equations of an iteration correct it for the samples whose weight differs.
        node_jacobian: (2 N, P) derivative of the node pixels, level px per parameter.
    """

    params: _Params
    sampled: _Sampled
    jacobian_t: np.ndarray
    hessian: np.ndarray
    node_jacobian: np.ndarray


class _System(NamedTuple):
    """Eq. 6 normal equations at one parameter vector on one pyramid level."""

    cost: float
    hessian: np.ndarray
    gradient: np.ndarray
    scale: float
    sampled: _Sampled
    residuals: np.ndarray  # (N, M), photometrically projected


class _Solution(NamedTuple):
    """Outcome of the coarse-to-fine solve."""

    params: _Params
    fallback: _Params
    fallback_cost: float
    fallback_sampled: _Sampled  # level 0 at the fallback, and its residuals
    fallback_residuals: np.ndarray
    scale: float
    iterations: int
    costs: tuple[float, ...]
    condition: float
    projection: PhotometricProjection  # of the level-0 template, reused by the loss checks
    coarsest_solved: bool  # whether the coarsest pyramid level was solved


class _OnDemand(Sequence[np.ndarray]):
    """Per-level arrays, each made by ``make(level)`` when first asked for, then kept.

    The coarse pyramid levels of a frame's templates are solved on a small share of the next
    frames (a prediction beyond ``fine_start_px``, a solve that asks for them), so they are
    sampled only then (about a tenth of a followed 640x480 frame's time otherwise).
    """

    def __init__(
        self,
        count: int,
        make: Callable[[int], np.ndarray],
        source: object = None,
        first: np.ndarray | None = None,
    ) -> None:
        """``count`` levels of ``make``, level 0 ``first`` if given.

        ``source`` is what ``make`` reads (see :meth:`reads`).
        """
        self._levels: list[np.ndarray | None] = [first] + [None] * (count - 1)
        self._make = make
        self._source = source

    def __len__(self) -> int:
        """The number of levels."""
        return len(self._levels)

    def __getitem__(self, level: int) -> np.ndarray:  # type: ignore[override]
        """Level ``level``'s array, made now if it was not yet."""
        made = self._levels[level]
        if made is None:
            made = self._levels[level] = self._make(level)
        return made

    def reads(self, source: object) -> bool:
        """Whether a level not made yet would read ``source`` (never None: nothing to read)."""
        return (
            source is not None
            and self._source is source
            and any(level is None for level in self._levels)
        )

    def made(self) -> tuple[np.ndarray, ...]:
        """Every level, made now where it was not yet."""
        return tuple(self)


class _Templates(NamedTuple):
    """Samples of every pyramid level at a pose, with node visibility and level-0 inside mask.

    Attributes:
        levels: (N, M) samples per level; coarse levels may be sampled on first use
            (:class:`_OnDemand`).
        visibility: (N,) node visibility weights.
        inside: (N, M) level-0 samples inside the image.
    """

    levels: Sequence[np.ndarray]
    visibility: np.ndarray
    inside: np.ndarray

    def sampled(self) -> _Templates:
        """These templates with every level sampled (to keep past their pyramid)."""
        if isinstance(self.levels, _OnDemand):
            return self._replace(levels=self.levels.made())
        return self

    def reads(self, pyramid: ImagePyramid | None) -> bool:
        """Whether a level not sampled yet would be sampled from ``pyramid``."""
        return isinstance(self.levels, _OnDemand) and self.levels.reads(pyramid)


class _Keyframe(NamedTuple):
    """A keyframe: its templates, the rotation R(omega) they were sampled at, and a projection.

    ``projection`` is the photometric projection of the level-0 template, built once for the
    drift check.
    """

    rotation: np.ndarray
    templates: _Templates
    projection: PhotometricProjection


class _View(NamedTuple):
    """A frame kept for the bundle adjustment (:mod:`.bundle`).

    Attributes:
        image: (H, W) float32 level 0 of its pyramid.
        visibility: (N,) node visibility weights at ``params``.
        params: its estimate.
        frame: its frame number in the track (``_Track.frames``; 1 for frame 1).
        rotation: R(omega) of ``params``.
    """

    image: np.ndarray
    visibility: np.ndarray
    params: _Params
    frame: int
    rotation: np.ndarray

    @classmethod
    def of(cls, image: np.ndarray, visibility: np.ndarray, params: _Params, frame: int) -> _View:
        """A view of ``image`` at ``params``, the track's ``frame``-th frame."""
        return cls(image, visibility, params, frame, rodrigues(params.omega)[0])


class _Adjusted(NamedTuple):
    """An accepted bundle adjustment, ready to apply.

    Attributes:
        estimate: the adjustment's estimate (:func:`~.bundle.rebased`).
        rois: each pyramid level's ROIs at its sigma, on its skin depth.
    """

    estimate: Estimate
    rois: tuple[_Roi, ...]


class _FaceView(NamedTuple):
    """Frame 1's inner face (the nodes off the face edge) on the search's pyramid level.

    Attributes:
        image: (h, w) crop of that level around the inner nodes.
        corner: (2,) pixel (x, y) of the crop's top-left sample on that level.
    """

    image: np.ndarray
    corner: np.ndarray


@dataclass
class _Track:
    """State of a running track; ``keyframes[0]`` holds frame 1 (the seed's I_1).

    ``rois`` holds each level's ROI samples. For the bundle adjustment of the first views:
    ``first`` is frame 1's pyramid, ``views`` frame 1 and the views kept, ``clicks`` the
    initialisation's 2-D points, ``depth`` the (N, 6) skin depth of the last adjustment (None
    before one), ``adjusted_views`` how many of the views the adjustments started so far covered
    (frame 1 included) and ``adjustment`` the one under way. ``before`` is the estimate of the
    frame before ``current`` when the two are consecutive valid frames (followed, or the second
    re-acquired) in the same face frame (None otherwise): the motion prediction's other point.
    ``missed`` counts the images since ``current`` that gave no valid estimate (LOST).
    """

    rois: tuple[_Roi, ...]
    normals: np.ndarray
    keyframes: list[_Keyframe]
    first: ImagePyramid
    views: list[_View]
    clicks: Initialisation | None
    previous: _Templates
    start: _Params
    view: _FaceView
    current: _Params
    last_good: TrackResult
    frames: int = 1
    missed: int = 0
    depth: np.ndarray | None = None
    adjusted_views: int = 1
    adjustment: Stages[_Adjusted | None] | None = None
    before: _Params | None = None

    @property
    def lost(self) -> bool:
        """Whether the last image gave no valid estimate (the track is re-acquiring)."""
        return self.missed > 0


class MonoTracker:
    """Eq. 6 tracker of one face in a monocular image stream.

    Args:
        model: the face model (eq. 3) with its priors (§4.1).
        camera: the camera; images must be rectified to its ``p`` and have its size.
        config: tunables; defaults to :class:`MonoTrackerConfig()`.
        detector: optional landmark detector for automatic (re-)initialisation; after a loss,
            a face it finds that the track's keyframes do not match starts a new track.

    Raises:
        ConfigError: if the pyramid is too deep for the camera's image size.
    """

    def __init__(
        self,
        model: FaceModel,
        camera: PinholeCamera,
        config: MonoTrackerConfig | None = None,
        detector: Detector | None = None,
    ) -> None:
        """Store the collaborators and precompute what does not change between frames."""
        self._model = model
        self._camera = camera
        self._config = config or MonoTrackerConfig()
        self._detector = detector
        check_levels_fit(self._config.pyramid_levels, camera.width, camera.height)
        self._triangles = model.topology.triangles
        self._edge_nodes = model.topology.group_mask(Group.EDGE)
        self._roi_weights = np.where(self._edge_nodes, self._config.edge_weight, 1.0)
        self._action_basis = np.ascontiguousarray(model.action_basis_nodes())  # (N, 3, q)
        self._node_bases = (self._action_basis, model.shape_basis_nodes())
        self._identity_action_basis = np.concatenate(self._node_bases, axis=-1)
        weight = self._config.prior_weight
        self._alpha_precision = weight * inv(model.alpha_prior_covariance)
        self._sigma_precision = weight * inv(model.sigma_prior_covariance)
        self._grid = square_offsets(self._config.patch_half_size)
        # The brightness change of a ROI that needs no template (a flat template's projection):
        # its mean, and for GAIN_FIELD its linear ramp; what is left is the ROI's texture.
        self._untextured = PhotometricProjection.of(
            np.zeros((1, len(self._grid))),
            max(self._config.photometric, PhotometricModel.BIAS),
            self._grid,
        )
        self._invariance = PhotometricInvariance.of(self._config.photometric, self._grid)
        # P of each pyramid level: level l's pixels are level 0's times 2^-l.
        self._level_cameras = [
            camera.p * np.array([[1.0 / (1 << level)], [1.0 / (1 << level)], [1.0]])
            for level in range(self._config.pyramid_levels)
        ]
        self._prior_hessians = {free: self._prior_hessian(free) for free in (False, True)}
        # Two pyramids, each rebuilt in place every other frame: the previous frame's stays
        # while the next is tracked, for its templates' coarse levels (_templates).
        self._buffers: list[ImagePyramid | None] = [None, None]
        self._posed: tuple[_Params, tuple[np.ndarray, ...]] | None = None  # _posed_at's
        self._init: Initialisation | None = None
        self._use_init = False
        self._track: _Track | None = None
        self._followed: tuple[ImagePyramid, TrackResult] | None = None  # awaiting adjust()

    @property
    def config(self) -> MonoTrackerConfig:
        """The tracker's configuration."""
        return self._config

    @property
    def status(self) -> TrackStatus:
        """INITIALIZING before a fit, LOST while re-acquiring, TRACKING otherwise."""
        if self._track is None:
            return TrackStatus.INITIALIZING
        return TrackStatus.LOST if self._track.lost else TrackStatus.TRACKING

    def reset(self, init: Initialisation | None = None) -> None:
        """Drop the current track; the next image is initialised.

        Args:
            init: 2-D node positions in the next image (and optionally a fixed sigma). None
                detects the face when the tracker has a detector, or re-uses the last
                initialisation's points otherwise.
        """
        if init is not None:
            self._init = init
        self._use_init = init is not None or self._detector is None
        self._track = None
        self._followed = None

    def step(self, image: np.ndarray) -> TrackResult:
        """Track the face into a new image, then run its share of the bundle adjustment.

        :meth:`track` followed by :meth:`adjust`, for callers with nothing to do in between.

        Args:
            image: (H, W) grey image (uint8 or float, grey levels 0-255) of the camera's size.

        Returns:
            The :class:`TrackResult` of this image.
        """
        result = self.track(image)
        self.adjust()
        return result

    def track(self, image: np.ndarray) -> TrackResult:
        """Track the face into a new image, leaving the bundle adjustment to :meth:`adjust`.

        Call :meth:`adjust` before the next image (once this result is published, say): until
        then the frame is neither kept as a view nor does the adjustment under way advance.

        Never raises on a bad frame: a malformed image, a failed fit or a lost face give a result
        with status LOST (or INITIALIZING while no face has been found) and a ``reason``.

        Args:
            image: (H, W) grey image (uint8 or float, grey levels 0-255) of the camera's size.

        Returns:
            The :class:`TrackResult` of this image.
        """
        self._followed = None
        try:
            pyramid = self._pyramid(image)
            if self._track is None:
                return self._initialise(pyramid)
            return self._follow(pyramid)
        except (InputError, LinAlgError) as error:
            return self._failure(str(error))

    def adjust(self) -> None:
        """Run the last tracked frame's share of the bundle adjustment of the first views.

        Keeps the frame as a view if it shows a new rotation and runs ``bundle.stages_per_frame``
        stages of the adjustment (:meth:`_maybe_adjust`); nothing after a frame that was not
        followed (initialised, lost or re-acquiring). An adjustment that ends here replaces
        the track's estimate from the next frame on. One that fails (numerically, or on input
        it cannot use) is dropped, as a rejected one is: the track goes on as it was, and this
        never raises, as :meth:`track` does not.
        """
        if self._followed is None:
            return
        (pyramid, result), self._followed = self._followed, None
        try:
            self._maybe_adjust(pyramid, result)
        except (InputError, LinAlgError):
            self._track.adjustment = None

    # --- initialisation and recovery -----------------------------------------------------------

    def _initialise(self, pyramid: ImagePyramid) -> TrackResult:
        """Fit the model to the init points (or a detection) and start a track on this image."""
        init = self._init if self._use_init else self._detect(pyramid)
        if init is None:
            return self._failure('waiting for an initialisation (init points or a detection)')
        return self._start_track(pyramid, init, *self._fit(init))

    def _start_track(
        self, pyramid: ImagePyramid, init: Initialisation, params: _Params | None, error: str
    ) -> TrackResult:
        """Start a new track on this image from ``params``, the model's fit to ``init``.

        The fit gives the track's sigma, refined over its first ``sigma_frames`` images and by
        the bundle adjustment of its first views. A fit that failed (``params`` None, with its
        ``error``) gives a failure instead.
        """
        if params is None:
            return self._failure(f'initialisation failed: {error}')
        rois, normals = self._rois(params, pyramid.num_levels)
        templates = self._templates(pyramid, params, rois, normals)
        residuals = np.zeros(self._model.num_nodes)
        result = self._result(TrackStatus.TRACKING, params, residuals, 0, (), '')
        first = ImagePyramid(levels=tuple(level.copy() for level in pyramid.levels))
        self._track = _Track(
            rois=rois,
            normals=normals,
            keyframes=[self._keyframe(params.omega, templates)],
            first=first,
            views=[_View.of(first.levels[0], templates.visibility, params, 1)],
            clicks=init,
            previous=templates,
            start=params,
            view=self._face_view(pyramid, result.nodes_px),
            current=params,
            last_good=result,
        )
        return result

    def _detect(self, pyramid: ImagePyramid) -> Initialisation | None:
        """Run the detector, if any, on the full-resolution grey image."""
        if self._detector is None:
            return None
        return self._detector(np.clip(pyramid.levels[0], 0, 255).astype(np.uint8))

    def _rois(
        self, params: _Params, num_levels: int, depth: np.ndarray | None = None
    ) -> tuple[tuple[_Roi, ...], np.ndarray]:
        """Every level's ROI samples (:meth:`_roi`) and the (N, 3) node normals at ``params``."""
        rois = tuple(self._roi(params, level, depth) for level in range(num_levels))
        return rois, self._normals(params.sigma)

    def _normals(self, sigma: np.ndarray) -> np.ndarray:
        """(N, 3) node normals of the mesh at ``sigma`` (alpha = 0), face frame."""
        return node_frames(self._model.identity_shape(sigma), self._triangles)[:, 2]

    def _roi(self, params: _Params, level: int, depth: np.ndarray | None = None) -> _Roi:
        """One pyramid level's ROI samples at ``params``'s sigma.

        Each ROI is a square grid in the face frame's x-y directions lifted onto the thin-plate
        surface through the nodes, with the spacing that gives ``patch_spacing_px`` at the
        initial depth, doubled on every coarser level; face-edge nodes' grids are shifted towards
        the face centre so they cover skin rather than the background beyond the face edge. With
        a skin ``depth`` (a bundle adjustment's) the samples are moved onto that skin. The
        samples move with eq. 3's bases carried to them by :func:`patch_basis`.
        """
        shape = self._model.identity_shape(params.sigma)
        grid = self._roi_grid(shape)
        spacing = self._config.patch_spacing_px * params.t[2] / self._camera.focal
        steps = grid * (spacing * (1 << level))
        if depth is None:
            offsets, weights = surface_patch_interpolation(shape, steps)
        else:
            offsets = surface_patch_offsets(shape, steps)
            offsets = self._with_skin(params, shape, offsets, grid, level, depth)
            weights = patch_interpolation(shape, offsets)
        action, identity = (
            np.ascontiguousarray(patch_basis(weights, basis).transpose(3, 2, 0, 1))
            for basis in self._node_bases
        )
        offsets = np.ascontiguousarray(offsets.transpose(2, 0, 1))
        return _Roi(offsets, action, identity, params.sigma)

    def _with_skin(
        self,
        params: _Params,
        shape: np.ndarray,
        offsets: np.ndarray,
        grid: np.ndarray,
        level: int,
        depth: np.ndarray,
    ) -> np.ndarray:
        """(N, M, 3) ROI offsets moved by the skin depth along the rays of frame 1 (params)."""
        basis = surface_basis(self._level_patch_coordinates(grid, level))
        direction = ray_directions(shape[:, None, :] + offsets, params.omega, params.t)
        moved = skin_offsets(
            offsets.transpose(2, 0, 1), basis, direction.transpose(2, 0, 1), depth
        )
        return moved.transpose(1, 2, 0)

    def _roi_grid(self, shape: np.ndarray) -> np.ndarray:
        """(N, M, 2) ROI sample offsets in grid steps along the face frame's x and y.

        A square of ``(2 h + 1)^2`` steps per node; the face-edge nodes' grids shifted towards the
        face centre by ``edge_patch_shift`` h, so they cover skin rather than the background.
        """
        config = self._config
        inward = shape[:, :2].mean(axis=0) - shape[self._edge_nodes, :2]
        inward /= np.linalg.norm(inward, axis=1, keepdims=True)
        grid = np.repeat(self._grid[None], len(shape), axis=0)
        grid[self._edge_nodes] += inward[:, None, :] * (
            config.edge_patch_shift * config.patch_half_size
        )
        return grid

    def _level_patch_coordinates(self, grid: np.ndarray, level: int) -> np.ndarray:
        """(N, M, 2) patch coordinates of a level's samples for the skin depth basis.

        In units of the level-0 ROI's half-width h; a coarser level's samples reach further out
        and are held at the edge of the level-0 ROI, where the skin depth was measured.
        """
        level_zero = grid / self._config.patch_half_size
        low, high = level_zero.min(axis=1, keepdims=True), level_zero.max(axis=1, keepdims=True)
        return np.clip(level_zero * (1 << level), low, high)

    def _face_view(self, pyramid: ImagePyramid, nodes_px: np.ndarray) -> _FaceView:
        """The crop of the search level spanned by the inner nodes, given (N, 2) level-0 pixels."""
        level = min(_SEARCH_LEVEL, pyramid.num_levels - 1)
        image = pyramid.levels[level]
        size = np.array(image.shape[::-1])
        inner = ImagePyramid.to_level(nodes_px[~self._edge_nodes], level)
        low = np.clip(np.floor(inner.min(axis=0)), 0, size - 1).astype(int)
        high = np.clip(np.ceil(inner.max(axis=0)) + 1, low + 1, size).astype(int)
        return _FaceView(image[low[1] : high[1], low[0] : high[0]].copy(), low)

    def _reacquire(self, pyramid: ImagePyramid, reason: str) -> TrackResult:
        """When eq. 6 from the last valid estimate fails: solve against keyframe templates alone.

        Candidate starts are a fresh detection (if a detector was given) and the initial fit
        moved to where the face is found by :meth:`_search`, each compared with its nearest
        keyframe; the first that passes the loss checks at ``reacquire_residual_ratio`` resumes
        the track, else the image is LOST for ``reason``. A detection that resumes nothing on an
        image after a LOST one starts a new track (:meth:`_start_track`): the face found is
        another person, or this one beyond what its keyframes show (turned far, or lit anew),
        and a track of its own fits its sigma and samples its templates and keyframes. The
        image the face is first lost on stays LOST, so that a non-TRACKING state separates any
        two tracks (the identity recogniser starts over at one). A face re-acquired in the
        image right after a valid estimate keeps the motion prediction, as a followed one does:
        the head moved on from that estimate in one frame. Measured on fast motion (every 5th
        frame of issue 6's sequences, true model): dropping it, seed 1 was LOST on 160 of 200
        frames with rotation errors of 6.8 / 3.1 degrees; keeping it, 49 frames and 1.1 / 1.1
        degrees.
        """
        track = self._track
        detected = self._detect(pyramid)
        fit, error = self._fit(detected) if detected is not None else (None, '')
        # A detection resumes the track with the track's sigma, or starts a new one with its own.
        candidates = [fit._replace(sigma=track.current.sigma)] if fit is not None else []
        candidates.append(self._search(pyramid))
        for start in candidates:
            keyframe = self._nearest_keyframe(start.omega).templates
            weights = keyframe.visibility * self._visibility(start, track.normals)
            result, templates = self._solve_frame(
                pyramid, start, keyframe.levels, weights, self._config.reacquire_residual_ratio
            )
            if result.ok:
                self._accept(result, templates)
                return result
        if detected is not None and track.missed > 0:
            return self._start_track(pyramid, detected, fit, error)
        return self._failure(f'lost: {reason}')

    def _search(self, pyramid: ImagePyramid) -> _Params:
        """The initial fit translated parallel to the image plane onto frame 1's inner face.

        The face is where its view correlates best with the image (normalised cross-correlation,
        robust to a gain and bias), the shift of a pixel being ``t_z / f`` in x and y.
        """
        track = self._track
        level = min(_SEARCH_LEVEL, pyramid.num_levels - 1)
        scores = cv2.matchTemplate(pyramid.levels[level], track.view.image, cv2.TM_CCOEFF_NORMED)
        best = np.unravel_index(np.argmax(scores), scores.shape)[::-1]
        shift = (np.array(best) - track.view.corner) * float(1 << level)  # level-0 px
        t = track.start.t.copy()
        t[:2] += shift * t[2] / np.diag(self._camera.p)[:2]
        return track.start._replace(t=t)

    def _fit(self, init: Initialisation) -> tuple[_Params | None, str]:
        """The model's fit to 2-D node positions (its own sigma), or None and why it failed."""
        try:
            fit = fit_model_to_points(self._model, self._camera, init, self._config.fit)
        except (InputError, ConfigError) as error:
            return None, str(error)
        return _Params(fit.omega, fit.t, fit.alpha, fit.sigma), ''

    # --- tracking ------------------------------------------------------------------------------

    def _follow(self, pyramid: ImagePyramid) -> TrackResult:
        """Track one frame (eq. 6) from the last valid estimate; if that fails, re-acquire.

        While LOST this is the solve of the frame after the last valid one, checked at the
        stricter ``reacquire_residual_ratio``.
        """
        track = self._track
        keyframe = self._nearest_keyframe(track.current.omega).templates
        epsilon = self._config.epsilon * keyframe.visibility[:, None]
        previous = track.previous.levels
        blended = _OnDemand(
            len(previous),
            lambda level: previous[level] + epsilon * (keyframe.levels[level] - previous[level]),
        )
        # The node visibility at the last valid estimate: its templates were sampled there.
        weights = track.previous.visibility
        free_sigma = track.frames <= self._config.sigma_frames
        config = self._config
        ratio = config.reacquire_residual_ratio if track.lost else config.lost_residual_ratio
        start, first_level = track.current, _START_LEVEL
        if config.predict_motion and track.before is not None and not track.lost:
            start = _predicted(track.current, track.before)
            first_level = self._first_level(track.current, start)
        result, templates = self._solve_frame(
            pyramid, start, blended, weights, ratio, free_sigma, first_level, track.current
        )
        if not result.ok:
            return self._reacquire(pyramid, result.reason)
        self._accept(result, templates)
        self._followed = (pyramid, result)
        return result

    def _first_level(self, current: _Params, predicted: _Params) -> int:
        """The level a predicted frame's solve starts on: 0 for a small predicted motion.

        ``predicted`` is projected last, so the solve that starts there finds its pose kept.
        """
        at_current = self._project_nodes(current)[1]
        motion = self._project_nodes(predicted)[1] - at_current
        small = np.abs(motion).max(initial=0.0) < self._config.fine_start_px
        return 0 if small else _START_LEVEL

    # --- bundle adjustment of the first views ---------------------------------------------------

    def _maybe_adjust(self, pyramid: ImagePyramid, result: TrackResult) -> None:
        """Keep this frame as a view if it shows a new rotation; run the bundle adjustment.

        A frame whose rotation differs from every view's by ``bundle.view_spacing`` (once sigma
        is no longer estimated by eq. 6) becomes a view, up to ``bundle.views`` of them. When no
        adjustment is under way and some views are in none yet, one starts over frame 1 and
        every view so far (:meth:`_adjustment`). It runs ``bundle.stages_per_frame`` stages per
        followed frame (all on this frame if 0). When it ends, the track continues from it
        (:meth:`_apply_adjustment`), unless it was rejected.
        """
        track, bundle = self._track, self._config.bundle
        if self._is_new_view(result):
            image = pyramid.levels[0].copy()  # the pyramid's levels are reused
            view = _View.of(image, track.previous.visibility, track.current, track.frames)
            track.views.append(view)
        if track.adjustment is None:
            if track.adjusted_views == len(track.views):
                return
            track.adjustment = self._adjustment(pyramid.num_levels)
        done, adjusted = run_stages(track.adjustment, bundle.stages_per_frame or None)
        if done:
            track.adjustment = None
        if adjusted is not None:
            self._apply_adjustment(pyramid, adjusted, result)

    def _is_new_view(self, result: TrackResult) -> bool:
        """Whether a followed frame should become a view."""
        track, bundle = self._track, self._config.bundle
        if len(track.views) > bundle.views or track.frames <= self._config.sigma_frames:
            return False
        rotation = rodrigues(result.omega)[0]
        nearest = max(float(np.sum(view.rotation * rotation)) for view in track.views)
        return nearest <= 1.0 + 2.0 * np.cos(bundle.view_spacing)  # trace = 1 + 2 cos(angle)

    def _adjustment(self, num_levels: int) -> Stages[_Adjusted | None]:
        """The bundle adjustment of frame 1 and the views so far, staged (:mod:`.stages`).

        Stages: setting up the problem, :func:`~.bundle.adjustment_stages`, then the new ROIs
        one pyramid level at a time. An adjustment that lowers the bundle cost and turns frame 1
        and its newest view by less than ``bundle.max_change`` returns what replaces sigma, the
        skin depth and frame 1's estimate (and its templates); otherwise None, and the track
        goes on as it was. Either way its views stay views, so the next adjustment has more
        views to agree with and waits for the head to reach a new rotation. (Dropping a rejected
        view instead retried at once on the next frame: on the mono protocol's 19-node seed 1
        all eight adjustments then ran on consecutive frames with two views each, every one
        rejected, and the track kept the clicks' pose, 6.8 degrees of pitch error against 2.7.)
        """
        track = self._track
        views = list(track.views)
        track.adjusted_views = len(views)
        poses = [(v.params.omega, v.params.t, v.params.alpha) for v in views]
        depth = track.depth
        start = Estimate(
            sigma=views[-1].params.sigma,
            depth=np.zeros((self._model.num_nodes, SURFACE_TERMS)) if depth is None else depth,
            first=poses[0],
            views=tuple(poses[1:]),
        )
        problem = self._bundle_problem()
        yield
        adjustment = yield from adjustment_stages(
            problem, [v.image for v in views], [v.visibility for v in views], start
        )
        estimate = adjustment.estimate
        moved = max(
            _rotation_angle(poses[0][0], estimate.first[0]),
            _rotation_angle(poses[-1][0], estimate.views[-1][0]),
        )
        if not (
            adjustment.cost < adjustment.initial_cost and moved < self._config.bundle.max_change
        ):
            return None
        first = _Params(*estimate.first, estimate.sigma)
        rois = []
        for level in range(num_levels):
            yield
            rois.append(self._roi(first, level, estimate.depth))
        return _Adjusted(estimate, tuple(rois))

    def _bundle_problem(self) -> Problem:
        """The fixed part of the bundle adjustment of the current track."""
        track, model, config = self._track, self._model, self._config
        first = track.views[0].params
        roi = self._roi(first, 0)
        shape = model.identity_shape(first.sigma)
        grid = self._level_patch_coordinates(self._roi_grid(shape), 0)
        points = shape[:, None, :] + roi.offsets.transpose(1, 2, 0)
        clicks = track.clicks
        return Problem(
            camera=self._level_cameras[0],
            mean_shape=model.mean_shape.reshape(-1, 3),
            action_nodes=self._action_basis,
            shape_nodes=np.ascontiguousarray(model.shape_basis_nodes()),
            first=(first.omega, first.t, first.alpha),
            first_sigma=first.sigma,
            patches=Patches(
                roi.offsets,
                roi.action,
                surface_basis(grid),
                np.ascontiguousarray(
                    ray_directions(points, first.omega, first.t).transpose(2, 0, 1)
                ),
            ),
            node_weights=self._roi_weights,
            invariance=self._invariance,
            alpha_precision=self._alpha_precision,
            sigma_precision=None
            if clicks is not None and clicks.sigma is not None
            else self._sigma_precision,
            click_nodes=clicks.node_indices(model) if clicks is not None else np.zeros(0, int),
            clicks=clicks.points if clicks is not None else np.zeros((0, 2)),
            config=config.bundle,
            huber_k=config.huber_k,
            scale_floor=config.residual_scale_floor,
        )

    def _apply_adjustment(
        self, pyramid: ImagePyramid, adjusted: _Adjusted, result: TrackResult
    ) -> None:
        """Restart the track's state from an adjustment: the next frame starts from its estimate.

        ``result`` is this frame's (its residuals go into the last valid result, which a LOST
        frame reports). When the adjustment ended on a later frame than its newest view's, this
        frame's estimate is carried into the adjusted face frame by the head's motion since that
        view, in the scene scaled as the adjustment scaled it (:func:`_carried`); so are the
        views kept while it ran.
        """
        track, estimate = self._track, adjusted.estimate
        poses = (estimate.first, *estimate.views)
        params = [_Params(omega, t, alpha, estimate.sigma) for omega, t, alpha in poses]
        newest = track.views[len(params) - 1]
        scale = self._node_distance(params[-1]) / self._node_distance(newest.params)
        current = params[-1]
        if track.frames != newest.frame:
            current = _carried(track.current, newest.params, params[-1], scale)
        later = [
            _carried(view.params, newest.params, params[-1], scale)
            for view in track.views[len(params) :]
        ]
        # Everything is made before the track changes: a failure (InputError) leaves it as it was.
        normals = self._normals(estimate.sigma)
        views = [
            _View.of(view.image, self._visibility(p, normals), p, view.frame)
            for view, p in zip(track.views, params + later, strict=True)
        ]
        first = self._templates(track.first, params[0], adjusted.rois, normals)
        keyframe = self._keyframe(params[0].omega, first)
        previous = self._templates(pyramid, current, adjusted.rois, normals)
        track.rois, track.normals, track.depth = adjusted.rois, normals, estimate.depth
        track.views, track.start, track.keyframes = views, params[0], [keyframe]
        track.previous, track.current, track.before = previous, current, None
        track.last_good = self._result(
            TrackStatus.TRACKING,
            current,
            result.node_residuals,
            result.iterations,
            result.cost_history,
            '',
        )

    def _node_distance(self, params: _Params) -> float:
        """Mean distance of the nodes from the camera centre at ``params``, m."""
        return float(np.mean(np.linalg.norm(self._project_nodes(params)[0], axis=1)))

    def _keyframe(self, omega: np.ndarray, templates: _Templates) -> _Keyframe:
        """A keyframe of ``templates`` sampled at rotation R(omega), every level sampled now."""
        projection = self._invariance.projection(templates.levels[0])
        return _Keyframe(rodrigues(omega)[0], templates.sampled(), projection)

    def _nearest_keyframe(self, omega: np.ndarray) -> _Keyframe:
        """The keyframe whose rotation is nearest R(omega)."""
        return self._track.keyframes[int(np.argmax(self._keyframe_cosines(omega)))]

    def _keyframe_cosines(self, omega: np.ndarray) -> np.ndarray:
        """trace(R_k' R(omega)) of every keyframe k: larger means nearer (3 = same rotation)."""
        rotation, _ = rodrigues(omega)
        return np.array([np.sum(k.rotation * rotation) for k in self._track.keyframes])

    def _accept(self, result: TrackResult, templates: _Templates) -> None:
        """Make a successful frame the previous frame of the next one, and maybe a keyframe.

        The last valid estimate becomes ``before`` (the motion prediction's other point) if no
        image was LOST since it, however this frame was found (followed or re-acquired).
        """
        track = self._track
        track.before = None if track.lost else track.current
        config = self._config
        if len(track.keyframes) < config.max_keyframes:
            # trace(R) = 1 + 2 cos(angle)
            nearest = np.max(self._keyframe_cosines(result.omega))
            if nearest < 1.0 + 2.0 * np.cos(config.keyframe_spacing):
                track.keyframes.append(self._keyframe(result.omega, templates))
        track.current = _params_of(result)
        track.previous = templates
        track.last_good = result
        track.frames += 1
        track.missed = 0

    def _solve_frame(
        self,
        pyramid: ImagePyramid,
        start: _Params,
        templates: Sequence[np.ndarray],
        node_weights: np.ndarray,
        residual_ratio: float,
        free_sigma: bool = False,
        first_level: int = _START_LEVEL,
        still: _Params | None = None,
    ) -> tuple[TrackResult, _Templates]:
        """Solve eq. 6 coarse to fine from ``start``; check the outcome for loss of track.

        ``residual_ratio`` is the loss checks' ratio of a node's residual to its texture;
        ``first_level`` is the level the solve starts on (the coarsest on demand). A solve that
        started on level 0 (a small predicted motion) and fails the checks without having
        solved the coarsest level is made again: from a start beyond level 0's reach the first
        step need not be large (the fine texture no longer correlates), so level 0 can settle in
        a wrong minimum without the coarsest level being called for. A sudden stop or reversal
        of the head does that: on the live benchmark's stream, whose head reverses at its ends,
        the prediction is then 5 px off and the frame was LOST. It is made again first from
        ``still``, the last estimate (a head that stopped or turned back is nearer to where it
        was than to where it was heading), on level 1 then 0, and if that fails the checks too,
        from ``start`` on the coarsest level. At the stream's reversals the first of these
        settles it in 9 iterations where the coarsest took 13 (with 30 ms between frames: 8.6-8.9
        against 9.7-12 ms). Solves started on level 1 (re-acquisition among them) are not made
        again: that doubled the time of a LOST frame (10 -> 18 ms).

        Returns:
            The frame's result (TRACKING or LOST with a reason; its iterations those of every
            solve made) and the templates sampled at its solution (the next frame's I_(n-1)
            samples).
        """
        node_weights = node_weights * self._roi_weights
        checks = (pyramid, templates, node_weights, free_sigma, residual_ratio)

        def attempt(
            begin: _Params, level: int, restart_px: float
        ) -> tuple[_Solution, TrackResult, _Templates]:
            solution = self._solve(
                pyramid, begin, templates, node_weights, free_sigma, level, restart_px
            )
            return (solution, *self._checked(solution, *checks))

        solution, result, sampled = attempt(start, first_level, self._config.coarsest_level_px)
        if result.ok or solution.coarsest_solved or first_level > 0:
            return result, sampled
        retries = [(start, pyramid.num_levels - 1, self._config.coarsest_level_px)]
        if still is not None and pyramid.num_levels > 1:
            retries.insert(0, (still, 1, math.inf))  # level 1 solved whatever its first step
        total = result
        for begin, level, restart_px in retries:
            _, result, sampled = attempt(begin, level, restart_px)
            total = replace(
                result,
                iterations=total.iterations + result.iterations,
                cost_history=total.cost_history + result.cost_history,
            )
            if result.ok:
                break
        return total, sampled

    def _checked(
        self,
        solution: _Solution,
        pyramid: ImagePyramid,
        templates: Sequence[np.ndarray],
        node_weights: np.ndarray,
        free_sigma: bool,
        residual_ratio: float,
    ) -> tuple[TrackResult, _Templates]:
        """The result of a solution that passes the loss checks (TRACKING) or not (LOST).

        The solution's last step is undone if it raised the cost (it was not checked).

        Returns:
            The result and the templates sampled at its estimate.
        """
        track = self._track
        params = solution.params
        first = self._sample(pyramid, params, 0, track.rois[0])
        projection = solution.projection
        residuals = projection.apply(first.samples - templates[0])
        weights = node_weights[:, None] * first.inside
        cost = self._data_cost(residuals, weights, solution.scale) + self._prior_cost(
            params, free_sigma
        )
        if cost > solution.fallback_cost:  # the last, unchecked step made things worse
            params = solution.fallback
            first, residuals = solution.fallback_sampled, solution.fallback_residuals
        sampled = self._templates(pyramid, params, track.rois, track.normals, first)
        node_rms = np.sqrt(np.mean(residuals**2, axis=1))
        reason = self._loss_reason(
            params,
            node_rms,
            sampled.levels[0],
            templates[0],
            sampled.visibility,
            solution,
            residual_ratio,
        )
        status = TrackStatus.LOST if reason else TrackStatus.TRACKING
        costs = (*solution.costs, min(cost, solution.fallback_cost))
        result = self._result(status, params, node_rms, solution.iterations, costs, reason)
        return result, sampled

    def _solve(
        self,
        pyramid: ImagePyramid,
        start: _Params,
        templates: Sequence[np.ndarray],
        node_weights: np.ndarray,
        free_sigma: bool,
        first_level: int,
        restart_px: float,
    ) -> _Solution:
        """Levenberg-Marquardt on eq. 6 plus priors, coarse to fine down to level 0.

        The solve starts on ``first_level``; when its first step exceeds ``restart_px`` (the
        configured ``coarsest_level_px``, or infinite: never) it starts over from ``start`` on a
        coarser level (:func:`.coarse_to_fine`). The Jacobian is
        evaluated where a level starts and re-evaluated only once the samples have moved
        ``jacobian_refresh_px`` since; the iterations in between only sample the image (one
        ``cv2.remap`` of the ROI points each). A level ends when the nodes stop moving
        (``convergence_px``, ``coarse_convergence_px``) or at the first step that raises the
        cost: with the damping this small, a retry with more of it moves to about the same point.
        """
        costs: list[float] = []

        @cache  # made for the levels solved only
        def projection(index: int) -> PhotometricProjection:
            return self._invariance.projection(templates[index])

        accepted: list[tuple[_Params, _System]] = []  # each level's last accepted point
        coarsest = pyramid.num_levels - 1
        coarsest_solved = False  # the coarsest level is always solved once it is started

        def solve(index: int, params: _Params, first_step_limit: float) -> _Params | None:
            nonlocal coarsest_solved
            level = _Level(
                index=index,
                pyramid=pyramid,
                camera=self._level_cameras[index],
                roi=self._track.rois[index],
                template=templates[index],
                projection=projection(index),
                visibility=np.repeat(node_weights[:, None], templates[index].shape[1], axis=1),
            )
            solution, last = self._solve_level(level, params, free_sigma, costs, first_step_limit)
            accepted.append(last)
            coarsest_solved |= index == coarsest
            return solution

        params = coarse_to_fine(pyramid.num_levels, first_level, restart_px, start, solve)
        fallback, system = accepted[-1]  # level 0's
        return _Solution(
            params=params,
            fallback=fallback,
            condition=_condition(system.hessian),
            fallback_cost=system.cost,
            fallback_sampled=system.sampled,
            fallback_residuals=system.residuals,
            scale=system.scale,
            iterations=len(costs),
            costs=tuple(costs),
            projection=projection(0),
            coarsest_solved=coarsest_solved,
        )

    def _solve_level(
        self,
        level: _Level,
        params: _Params,
        free_sigma: bool,
        costs: list[float],
        first_step_limit: float,
    ) -> tuple[_Params | None, tuple[_Params, _System]]:
        """Levenberg-Marquardt iterations on one pyramid level from ``params``.

        Appends each evaluated cost to ``costs``.

        Returns:
            The level's solution (None, without a step, when the first step would move a node
            more than ``first_step_limit`` level px) and the last accepted point with its
            system (the solution or the point before it).
        """
        config = self._config
        linear = self._linearise(level, params, free_sigma)
        damping = config.damping
        converged = config.coarse_convergence_px if level.index else config.convergence_px
        accepted: tuple[_Params, _System] | None = None
        scale = None
        moved = 0.0
        for _ in range(config.max_iterations):
            system = self._evaluate(level, params, linear, scale)
            scale = system.scale
            costs.append(system.cost)
            if accepted is not None and system.cost > accepted[1].cost:
                return accepted[0], accepted  # no lower cost within reach: the level ends here
            accepted = (params, system)
            damping = max(0.1 * damping, 1e-9)
            step = damped_step(system.hessian, system.gradient, damping)
            motion = np.abs(linear.node_jacobian @ step).max(initial=0.0)
            if motion > first_step_limit:
                return None, accepted
            first_step_limit = np.inf
            params = params.updated(step, self._model.q)
            if motion < converged:
                break
            moved += motion
            if moved > config.jacobian_refresh_px:
                linear = self._linearise(level, params, free_sigma)
                moved = 0.0
        assert accepted is not None  # max_iterations >= 1
        return params, accepted

    def _linearise(self, level: _Level, params: _Params, free_sigma: bool) -> _Linearisation:
        """The Jacobian of eq. 6's photometrically projected residuals at ``params``.

        Image gradient (sampled on the ROIs only) x d pixel / d X_c (eq. 2) x d X_c / d(omega,
        t, alpha[, sigma]) (eq. 1, 3) (:func:`~.mono_kernels.roi_jacobian`), then ``1 - P`` of the
        photometric model.
        """
        basis = self._identity_action_basis if free_sigma else self._action_basis
        rotation, shape = self._pose(params)
        rotated, (x, y) = self._roi_points(params, level.camera, level.roi)
        image = level.pyramid.level(level.index, x, y)
        samples, gradient = sample_with_gradient_xy(image, x, y)
        jacobian, node_jacobian = roi_jacobian(
            rotated,
            rotation @ shape.T,
            params.t,
            level.camera,
            gradient,
            rotation,
            self._d_rotation(params),
            basis,
            level.roi.basis(free_sigma),
        )
        jacobian_t = level.projection.apply(jacobian).reshape(len(jacobian), -1)
        return _Linearisation(
            params=params,
            sampled=_Sampled(samples, inside_xy(x, y, image.shape, margin=1.0)),
            jacobian_t=jacobian_t,
            hessian=weighted_gram(jacobian_t, level.visibility.ravel()),
            node_jacobian=node_jacobian,
        )

    def _roi_points(
        self, params: _Params, camera: np.ndarray, roi: _Roi
    ) -> tuple[np.ndarray, np.ndarray]:
        """(3, N, M) ``R P`` of the ROI points (eq. 1, 3) and their (2, N, M) level pixels (eq. 2).

        ``camera`` is the level's projection matrix P.
        """
        rotation, shape = self._pose(params)
        return roi_points(
            rotation,
            shape,
            params.t,
            camera,
            roi.offsets,
            roi.action,
            params.alpha,
            roi.identity,
            params.sigma - roi.sigma,
        )

    def _evaluate(
        self,
        level: _Level,
        params: _Params,
        linear: _Linearisation,
        scale: float | None,
    ) -> _System:
        """Residuals, Huber-weighted normal equations and cost of eq. 6 on one level.

        ``J' W J`` is the linearisation's ``J' V J`` plus the columns of the samples whose IRLS
        weight W (Huber times visibility times inside the image) differs from their visibility V.

        Args:
            level: the pyramid level, with its template, photometric projection and visibility.
            params: where to evaluate.
            linear: the Jacobian (from a nearby linearisation point).
            scale: the robust residual scale s, or None to estimate it from these residuals.
        """
        sampled = (
            linear.sampled
            if params is linear.params
            else self._sample(level.pyramid, params, level.index, level.roi)
        )
        residuals = level.projection.apply(sampled.samples - level.template)
        weights = level.visibility * sampled.inside
        if scale is None:
            active = np.abs(residuals[weights > 0])
            spread = _MAD_TO_STD * _median(active) if active.size else 0.0
            scale = max(self._config.residual_scale_floor, spread)
        data_cost, hessian, gradient = normal_equations(
            linear.jacobian_t,
            residuals,
            weights,
            level.visibility,
            scale,
            self._config.huber_k,
            linear.hessian,
        )
        free_sigma = linear.jacobian_t.shape[0] > POSE_DIM + self._model.q
        return _System(
            cost=data_cost + self._prior_cost(params, free_sigma),
            hessian=hessian + self._prior_hessians[free_sigma],
            gradient=gradient + self._prior_gradient(params, free_sigma),
            scale=scale,
            sampled=sampled,
            residuals=residuals,
        )

    def _prior_hessian(self, free_sigma: bool) -> np.ndarray:
        """Hessian (halved) of the alpha (and sigma) priors, padded to the pose."""
        q = self._model.q
        size = POSE_DIM + q + (self._model.p if free_sigma else 0)
        hessian = np.zeros((size, size))
        hessian[POSE_DIM : POSE_DIM + q, POSE_DIM : POSE_DIM + q] = self._alpha_precision
        if free_sigma:
            hessian[POSE_DIM + q :, POSE_DIM + q :] = self._sigma_precision
        return hessian

    def _prior_gradient(self, params: _Params, free_sigma: bool) -> np.ndarray:
        """Gradient (halved) of the alpha (and sigma) priors, padded to the pose."""
        blocks = [np.zeros(POSE_DIM), self._alpha_precision @ params.alpha]
        if free_sigma:
            blocks.append(self._sigma_precision @ params.sigma)
        return np.concatenate(blocks)

    def _prior_cost(self, params: _Params, free_sigma: bool) -> float:
        """``alpha' L_a alpha`` (+ ``sigma' L_s sigma`` while sigma is free)."""
        cost = float(params.alpha @ self._alpha_precision @ params.alpha)
        if free_sigma:
            cost += float(params.sigma @ self._sigma_precision @ params.sigma)
        return cost

    def _data_cost(self, residuals: np.ndarray, weights: np.ndarray, scale: float) -> float:
        """Huber cost ``sum w rho(r / s)`` of (N, M) residuals with (N, M) weights."""
        return huber_irls(residuals, weights, scale, self._config.huber_k)[1]

    # --- checks, templates, results ------------------------------------------------------------

    def _loss_reason(
        self,
        params: _Params,
        node_rms: np.ndarray,
        samples: np.ndarray,
        template: np.ndarray,
        visibility: np.ndarray,
        solution: _Solution,
        residual_ratio: float,
    ) -> str:
        """Why this estimate is not a valid track ('' if it is).

        Args:
            params: the solution.
            node_rms: (N,) RMS of each node's (photometrically projected) residual.
            samples: (N, M) level-0 samples of the image at the solution.
            template: (N, M) level-0 template they were compared with.
            visibility: (N,) node visibility at the solution.
            solution: the solver's outcome.
            residual_ratio: a node fails when its residual exceeds this multiple of its texture.
        """
        config = self._config
        values = np.concatenate([params.omega, params.t, params.alpha, params.sigma])
        if not np.all(np.isfinite(values)) or params.t[2] < _MIN_DEPTH:
            return 'the solver diverged'
        # The motion since the last valid estimate, whatever the solve started from (a search
        # or a detection when re-acquiring), over the frames since.
        frames = self._track.missed + 1
        turn = _rotation_angle(self._track.current.omega, params.omega)
        if turn > config.max_rotation_step * frames:
            return f'implausible motion ({np.degrees(turn):.0f} degrees in {frames} frame(s))'
        if solution.condition > config.max_condition:
            return f'ill-conditioned solve (condition {solution.condition:.1e})'
        pixels = self._project_nodes(params)[1]
        visible = (visibility > 0) & inside_image(
            pixels, (self._camera.height, self._camera.width)
        )
        if visible.mean() < config.min_visible_fraction:
            return f'only {visible.sum()} of {len(visible)} nodes visible in the image'
        # Each node's residual against the texture of its ROI in the image: near 1 when the
        # template explains none of it. Nodes flat in both the image and the template abstain.
        floor = config.residual_scale_floor
        image_texture = self._texture(samples)
        votes = visible & (np.maximum(image_texture, self._texture(template)) > floor)
        matched = (image_texture > floor) & (node_rms < residual_ratio * image_texture)
        failing = votes & ~matched
        if not votes.any():
            return (
                f'no visible node shows texture above {floor:g} grey levels, in the image or its '
                'template: a blank, dark or saturated image'
            )
        if failing.sum() > config.lost_node_fraction * votes.sum():
            return f'{failing.sum()} of {votes.sum()} textured nodes do not match their templates'
        drift = self._drift_ratio(
            params, samples, image_texture, visible & (image_texture > floor)
        )
        if drift > config.drift_residual_ratio:
            return f'drifted: residual against the keyframe {drift:.2f} x the ROI texture'
        return ''

    def _drift_ratio(
        self, params: _Params, samples: np.ndarray, texture: np.ndarray, nodes: np.ndarray
    ) -> float:
        """Median over ``nodes`` of the residual against the nearest keyframe alone / texture.

        The drift check of :meth:`_loss_reason`: eq. 6's data term with epsilon = 1, i.e. against
        the keyframe's templates without the previous frame's, photometrically projected like
        the residuals of the solve.

        Args:
            params: the solution.
            samples: (N, M) level-0 samples of the image at the solution.
            texture: (N,) their ROIs' texture (:meth:`_texture`).
            nodes: (N,) the visible nodes whose ROI shows texture.
        """
        keyframe = self._nearest_keyframe(params.omega)
        key = keyframe.templates
        nodes = nodes & (key.visibility > 0)
        if not nodes.any():
            return 0.0
        residuals = keyframe.projection.apply(samples - key.levels[0])
        rms = np.sqrt(np.mean(residuals[nodes] ** 2, axis=1))
        return float(np.median(rms / texture[nodes]))

    def _texture(self, samples: np.ndarray) -> np.ndarray:
        """(N,) RMS of (N, M) ROI samples beyond the brightness change that needs no template."""
        return np.sqrt(np.mean(self._untextured.apply(samples) ** 2, axis=1))

    def _templates(
        self,
        pyramid: ImagePyramid,
        params: _Params,
        rois: tuple[_Roi, ...],
        normals: np.ndarray,
        first: _Sampled | None = None,
    ) -> _Templates:
        """Samples of every level at ``params``'s ROIs, and the node visibility there.

        ``first`` is level 0 at ``params`` when it has been sampled already. The coarser levels
        are sampled when first used (:class:`_OnDemand`), from ``pyramid``, which
        :meth:`_pyramid` keeps until then.
        """
        first = first or self._sample(pyramid, params, 0, rois[0])

        def sample(level: int) -> np.ndarray:
            return self._sample(pyramid, params, level, rois[level]).samples

        levels = _OnDemand(pyramid.num_levels, sample, source=pyramid, first=first.samples)
        return _Templates(levels, self._visibility(params, normals), first.inside)

    def _sample(self, pyramid: ImagePyramid, params: _Params, level: int, roi: _Roi) -> _Sampled:
        """Level ``level``'s samples of its ROIs ``roi`` at ``params``."""
        _, (x, y) = self._roi_points(params, self._level_cameras[level], roi)
        image = pyramid.level(level, x, y)
        return _Sampled(sample_xy(image, x, y), inside_xy(x, y, image.shape, margin=1.0))

    def _visibility(self, params: _Params, normals: np.ndarray) -> np.ndarray:
        """(N,) weights in [0, 1] from the angle between node normals and rays to the camera."""
        rotation, shape = self._pose(params)
        nodes = shape @ rotation.T + params.t
        rays = nodes / np.linalg.norm(nodes, axis=1, keepdims=True)
        facing = -np.einsum('na,na->n', normals @ rotation.T, rays)
        low = self._config.visibility_cos
        return np.clip((facing - low) / max(low, 1e-6), 0.0, 1.0)

    def _pose(self, params: _Params) -> tuple[np.ndarray, np.ndarray]:
        """R(omega) (eq. 1) and the (N, 3) shape (eq. 3) of ``params``.

        The last parameter vector's are kept: one is projected several times (its evaluation,
        linearisation, templates, visibility, result).
        """
        return self._posed_at(params)[:2]

    def _d_rotation(self, params: _Params) -> np.ndarray:
        """(3, 3, 3) dR/domega_k at ``params`` (eq. 1), kept with :meth:`_pose`'s."""
        return self._posed_at(params)[2]

    def _posed_at(self, params: _Params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """R(omega), the shape and dR/domega of ``params``, computed once per parameter vector."""
        if self._posed is None or params is not self._posed[0]:
            rotation, d_rotation = rodrigues(params.omega)
            shape = self._model.shape(params.sigma, params.alpha)
            self._posed = (params, (rotation, shape, d_rotation))
        return self._posed[1]

    def _project_nodes(self, params: _Params) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) camera-frame nodes (eq. 1, 3) and their (N, 2) pixels (eq. 2)."""
        rotation, shape = self._pose(params)
        points_cam = shape @ rotation.T + params.t
        return points_cam, self._camera.project(points_cam)

    def _result(
        self,
        status: TrackStatus,
        params: _Params,
        node_residuals: np.ndarray,
        iterations: int,
        costs: tuple[float, ...],
        reason: str,
    ) -> TrackResult:
        """A TrackResult for ``params``."""
        nodes_cam, nodes_px = self._project_nodes(params)
        return TrackResult(
            status=status,
            omega=params.omega.copy(),
            t=params.t.copy(),
            alpha=params.alpha.copy(),
            sigma=params.sigma.copy(),
            nodes_cam=nodes_cam,
            nodes_px=nodes_px,
            node_residuals=node_residuals,
            mean_residual=float(np.mean(node_residuals)),
            iterations=iterations,
            cost_history=costs,
            reason=reason,
        )

    def _failure(self, reason: str) -> TrackResult:
        """LOST with the last valid estimate, or INITIALIZING before any."""
        if self._track is None:
            model = self._model
            return TrackResult.empty(model.num_nodes, model.p, model.q, reason)
        self._track.missed += 1
        return replace(self._track.last_good, status=TrackStatus.LOST, reason=reason)

    def _pyramid(self, image: np.ndarray) -> ImagePyramid:
        """Validate the image against the camera and build its pyramid.

        It is built into the pyramid of the image before last (:attr:`_buffers`), whose
        templates (if they are still the previous ones: a LOST image since) are sampled first.
        """
        image = np.asarray(image)
        expected = (self._camera.height, self._camera.width)
        if image.shape != expected:
            msg = f'image has shape {image.shape}; the camera expects a grey {expected} image'
            raise InputError(msg)
        older, newer = self._buffers
        if self._track is not None and self._track.previous.reads(older):
            self._track.previous = self._track.previous.sampled()  # before older is rebuilt
        pyramid = ImagePyramid.build(
            image, self._config.pyramid_levels, self._config.smooth_base, reuse=older
        )
        self._buffers = [newer, pyramid]
        return pyramid


def _params_of(result: TrackResult) -> _Params:
    """The parameters of a result."""
    return _Params(result.omega, result.t, result.alpha, result.sigma)


def _carried(current: _Params, before: _Params, after: _Params, scale: float) -> _Params:
    """``current`` moved with a view that an adjustment moved from ``before`` to ``after``.

    One camera cannot tell a face's size from its distance, so an adjustment that changes sigma
    also scales the scene about the camera centre, by ``scale`` (the adjusted view's node
    distances over the old ones). The head's motion since the view, as tracked, takes a
    camera-frame point c to ``R_c R_b' (c - t_b) + t_c``; in the scene scaled by s it takes c to
    ``R_c R_b' (c - s t_b) + s t_c``, the same image motion. The adjusted view sees face point X
    at ``c = R_a X + t_a``, so now it is at ``R_c R_b' R_a X + R_c R_b' (t_a - s t_b) + s t_c``.
    This is exact when the adjusted scene is the tracked one scaled by s about the camera centre
    and described in another face frame. Alpha changes as the view's did; sigma is the
    adjustment's.
    """
    motion = rodrigues(current.omega)[0] @ rodrigues(before.omega)[0].T
    return _Params(
        omega=matrix_to_omega(motion @ rodrigues(after.omega)[0]),
        t=motion @ (after.t - scale * before.t) + scale * current.t,
        alpha=current.alpha + after.alpha - before.alpha,
        sigma=after.sigma,
    )


def _predicted(current: _Params, before: _Params) -> _Params:
    """Constant-velocity prediction: the motion from ``before`` to ``current`` once more.

    The head turns about the face origin (eq. 1), so the rotation repeats as
    ``R_c R_b' R_c`` and the origin moves on by ``t_c - t_b``; alpha and sigma are kept. A head
    that did not turn predicts ``omega_c`` exactly (no round trip through R).
    """
    omega = current.omega
    if not np.array_equal(omega, before.omega):
        rotation = rodrigues(omega)[0]
        omega = matrix_to_omega(rotation @ rodrigues(before.omega)[0].T @ rotation)
    return current._replace(omega=omega, t=current.t + (current.t - before.t))


def _rotation_angle(omega_a: np.ndarray, omega_b: np.ndarray) -> float:
    """Angle of the rotation between R(omega_a) and R(omega_b), rad."""
    relative = rodrigues(omega_a)[0].T @ rodrigues(omega_b)[0]
    return float(np.arccos(np.clip(0.5 * (np.trace(relative) - 1.0), -1.0, 1.0)))


def _median(values: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D array, by one partial sort."""
    half = values.size // 2
    if values.size % 2:
        return float(np.partition(values, half)[half])
    low, high = np.partition(values, (half - 1, half))[half - 1 : half + 1]
    return float((low + high) / 2)


def _condition(hessian: np.ndarray) -> float:
    """Condition number of the Jacobi-scaled normal matrix (inf when singular)."""
    scaling = 1.0 / np.sqrt(np.maximum(np.diag(hessian), 1e-12))
    eigenvalues = np.linalg.eigvalsh(hessian * scaling[:, None] * scaling[None, :])
    return float(eigenvalues[-1] / eigenvalues[0]) if eigenvalues[0] > 0 else float('inf')
