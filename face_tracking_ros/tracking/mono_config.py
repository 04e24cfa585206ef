"""Tunables of the monocular tracker (:class:`~.mono.MonoTracker`), each tied to its symbol.

The tracker minimises eq. 6 (seed §3.5) with the §4.1 prior on alpha; every field below is one of
that solve's tunables or one of the checks on its outcome, validated when the config is made.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from face_tracking_ros.errors import check_fields
from face_tracking_ros.imaging import MAX_HALF_SIZE, PhotometricModel
from face_tracking_ros.tracking.bundle import BundleConfig
from face_tracking_ros.tracking.initialisation import FitConfig


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
        patch_half_size: h; each node's ROI has (2 h + 1)^2 samples (1 to 15).
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
            (the head's turn and shift between the last two estimates, carried on over the frame
            intervals since the last image: more than one after dropped images) instead of
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
        pause_intervals: an image more than this many frame intervals after the last valid
            estimate's (no image LOST between) is taken as after a pause of the stream (a camera
            or a bag that stalled; >= 1): the head may have moved anything from one frame's
            motion to the whole gap's. It is solved from the motion prediction over one interval
            too (of the solves that pass, the one that fits best is taken), and the motion found
            is taken as spread over the intervals, from 1 to the gap's, that keep the speed
            nearest the one before it, for the next image's prediction. Carried on over 31
            intervals (a 1-s stall at 30 fps) the motion of one put the start 65 px off. On 120
            rendered pauses (free motion, true model, seeds 0-9, before image 10 or 25; 10-91
            intervals at 30 fps, 10 or 30 at 10 fps) images TRACKING more than 2 px off 70 -> 12
            (all seed 7's at 10 fps, as far off without the pause), pause images LOST 19 -> 0,
            the worst at 30 fps 8.9 -> 1.3 px. 9 takes 1 s at 10 fps for a pause and leaves the
            runs with gaps of up to 6 dropped intervals as they were; at 30 fps with 10 or 20
            dropped (gaps taken as pauses; seeds 1-4) LOST and wrong images the same.
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
        reacquire_residual_ratio: the same ratio for the solves that may resume a lost track,
            for the keyframe-only solves tried when tracking fails and, before
            ``lost_residual_ratio``, for the first image after dropped ones (> 0). Stricter: such
            a solve can settle a few px off the face, which later frames do not correct. A
            frame becomes a view of the bundle adjustment only if it passes this ratio's vote
            too (a face dragged by an occluder passes ``lost_residual_ratio``).
        drift_residual_ratio: LOST when the median, over the visible textured nodes, of a
            node's RMS residual against the nearest keyframe's templates alone (frame 1's by
            default; no blend with frame n-1) exceeds this multiple of its ROI's texture: the
            track has drifted away from what the face looked like (> 0). Measured on the
            1000-frame benchmark sequences: at most 0.65 on the 34-node tracks (true and learned
            models, errors up to 15 degrees), 0.68 median and 0.84 95th percentile on a 19-node
            track that had drifted 15 to 55 degrees; at 0.75 that track is re-acquired when it
            drifts (rotation MAE in x 18.0 -> 6.8 degrees) and the others are unchanged.
        occlusion_residual_ratio: a node is taken as covered by an occluder when its RMS
            residual exceeds this multiple of its ROI's texture in the image (and 3 times the
            lower quartile of the other inner nodes', with neighbours failing too:
            :func:`~.mono_loss.covered_nodes`), and as uncovered again once it fits its template,
            the nearest keyframe's, within half of it (> 0). A covered node weighs nothing in
            eq. 6 and counts as not visible in the loss checks. Measured on 48 rendered 300-frame
            runs with an occluder passing: TRACKING frames more than 5 px off 86 -> 31 at 0.5,
            LOST frames 2666 -> 1477 with the re-acquisition from the adjustment's views; the 48
            runs without it the same to the digit (docs/performance.md).
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
    pause_intervals: int = 9
    coarsest_level_px: float = 1.0
    visibility_cos: float = 0.1
    lost_residual_ratio: float = 0.65
    reacquire_residual_ratio: float = 0.3
    drift_residual_ratio: float = 0.75
    occlusion_residual_ratio: float = 0.5
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
            'patch_half_size': 1 <= self.patch_half_size <= MAX_HALF_SIZE,
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
            'pause_intervals': self.pause_intervals >= 1,
            'coarsest_level_px': self.coarsest_level_px >= 0,
            'visibility_cos': 0.0 <= self.visibility_cos < 0.5,
            'lost_residual_ratio': self.lost_residual_ratio > 0,
            'reacquire_residual_ratio': self.reacquire_residual_ratio > 0,
            'drift_residual_ratio': self.drift_residual_ratio > 0,
            'occlusion_residual_ratio': self.occlusion_residual_ratio > 0,
            'lost_node_fraction': 0.0 < self.lost_node_fraction <= 1.0,
            'min_visible_fraction': 0.0 <= self.min_visible_fraction <= 1.0,
            'max_rotation_step': self.max_rotation_step > 0,
            'max_condition': self.max_condition > 1,
        }
        check_fields(self, checks)
