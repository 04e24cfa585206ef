"""Tunables of the stereo tracker (:class:`~.stereo.StereoTracker`), each tied to its symbol.

The tracker minimises eq. 4 + eq. 5 (seed §3.3), each image term split with the drift term of
eq. 6, plus the §4.2 face-texture term and the face-model term (eq. 1 and 3); every field below
is one of that solve's tunables, of its initialisation and depth refinement, or of the checks
on its outcome, validated when the config is made.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

from face_tracking_ros.errors import check_fields
from face_tracking_ros.imaging import MAX_HALF_SIZE
from face_tracking_ros.model.topology import SUPPORTED_NODE_COUNTS
from face_tracking_ros.tracking.initialisation import MIN_INIT_NODES
from face_tracking_ros.tracking.regularisation import RegularisationConfig

MAX_SUBDIVISIONS = 16  # of the texture triangles: (n + 1)(n + 2) / 2 = 153 samples each


@dataclass(frozen=True)
class StereoInitConfig:
    """Tunables of the stereo initialisation.

    Attributes:
        min_depth: nearest face distance searched along the epipolar line, m.
        max_depth: farthest face distance searched, m.
        match_half_size: correlation windows are (2 h + 1)^2 pixels (2 to 30).
        min_score: normalised cross-correlation below which a match is rejected.
        max_face_error: an inner node farther than this from the reference face fitted to the
            inner nodes is rejected as a mismatch, m.
        min_given_nodes: fewest nodes that must be given (and matched); at least 6, the fewest
            an init file or a reset request may name.
        refine_iterations: Gauss-Newton iterations of the depth refinement.
        refine_half_size: the refinement patch is (2 h + 1)^2 samples on the face surface. A
            single pair's left-right cost of a 7x7 patch on smooth skin (lips, brows) can have
            its minimum millimetres off; over 18 subjects of three synthetic populations (19
            nodes) h = 5 against 3 took the matched nodes' depth error from 1.63 / 1.59 / 2.39
            to 1.59 / 1.42 / 1.72 mm RMS per population, the largest from 10.2 to 8.6 mm.
        min_face_scale: the matched inner nodes must triangulate to a face at least this many
            times the size of the reference (adult) face, and
        max_face_scale: at most this many times. Outside, the rig's calibration does not fit
            the images and the initialisation fails, saying so. Triangulated sizes scale with
            the baseline (one k times the true one reads k times the face's size), and adult
            faces vary by about 15 %: the synthetic populations read 0.87-1.14, 0.85-1.21 with
            an expression at full intensity (600 faces each); tracked, 30 subjects read theirs
            within 0.34 %. A baseline doubled then reads 1.70 or more, one halved 0.61 or less;
            one 25 % off passes, as a larger or smaller face does (learn warns of it across
            subjects). Raw images of a rig toed in by 3 degrees, tracked unrectified, read 2.9.
    """

    min_depth: float = 0.25
    max_depth: float = 2.0
    match_half_size: int = 7
    min_score: float = 0.6
    max_face_error: float = 0.025
    min_given_nodes: int = 6
    refine_iterations: int = 5
    refine_half_size: int = 5
    min_face_scale: float = 0.7
    max_face_scale: float = 1.5

    def __post_init__(self) -> None:
        """Validate ranges.

        Raises:
            ConfigError: naming the first inconsistent tunable.
        """
        checks = {
            'max_depth': self.max_depth > 0.0,
            'min_depth': 0.0 < self.min_depth < self.max_depth,
            'match_half_size': 2 <= self.match_half_size <= 2 * MAX_HALF_SIZE,
            'min_score': -1.0 <= self.min_score <= 1.0,
            'max_face_error': self.max_face_error > 0.0,
            'min_given_nodes': self.min_given_nodes >= MIN_INIT_NODES,
            'refine_iterations': self.refine_iterations >= 0,
            'refine_half_size': 1 <= self.refine_half_size <= MAX_HALF_SIZE,
            'max_face_scale': self.max_face_scale > 0.0,
            'min_face_scale': 0.0 < self.min_face_scale < self.max_face_scale,
        }
        check_fields(self, checks)


@dataclass(frozen=True)
class StereoTrackerConfig:
    """Tunables of the stereo tracker, each tied to its symbol in the seed.

    Attributes:
        num_nodes: mesh size, 19 or 34.
        gamma: weight of the cross-camera terms of eq. 4, in [0, 1].
        boundary_gamma: gamma of the face-boundary nodes, in [0, 1]: their left and right
            views show different skin (the face turns away from the cameras there), §4.2.
        boundary_one_sided: face-boundary nodes use the face side of their patch only (§4.2),
            on a surface that runs on beyond them as the skin turns away (rim points, 10 mm
            out, 20 mm back); false: whole patches on the surface through the nodes alone.
        epsilon: share of the frame-1 (drift) terms in every image term, in [0, 1).
        texture_weight: weight of a face-texture sample relative to a node-patch sample (§4.2);
            0 disables the texture term. It covers the triangles that have a face-edge node
            (none in the 19-node mesh).
        texture_subdivisions: barycentric grid order of the texture samples (3 to 16).
        patch_half_size: node patches are (2 h + 1)^2 samples about one pixel apart (1 to 15);
            while tracking, a node counts as seen by an image until its patch leaves it (its
            centre h px beyond the side).
        cross_taper: weigh a two-sided node patch's samples in the cross-camera terms of eq. 4
            and in the depth refinement by a Gaussian of their distance from the node, this
            standard deviation in samples; 0 (the default): all alike. The patches lie on the
            thin plate through the nodes, flatter than the skin around the nose tip, upper lip
            and chin, and a flat patch's error grows away from its node. On issue 5's protocol
            1.5 takes node RMS 0.79 -> 0.69 mm (19 nodes; half size 2.52 -> 1.86 mm) but the
            drift 0.24 -> 0.33 mm (realistic faces 0.39 -> 0.70 mm): the tracked pairs no longer
            sit at the refined frame-1 depths (docs/performance.md, forty-sixth session).
        pyramid_levels: coarse-to-fine levels (1 = full resolution only; the coarsest at least
            16 px).
        gap_pyramid_levels: coarse-to-fine levels of a pair after dropped pairs or bad frames
            (more than one frame interval since the last tracked pair), and of the first pair
            after the initial one (no motion to predict it from), as many as fit the images
            (the coarsest at least 16 px; ``pyramid_levels`` if fewer). The prediction over
            several intervals errs by more than two levels reach (about 5 px of level 0; three
            levels about 9, four 12-16), so such a pair is solved from these coarser levels
            too, made for it alone; the other pairs are solved as before, to the bit. Rendered
            free motion, 150 pairs at 10 fps, 2 pairs dropped every 8-20: LOST 120 / 92 / 70 /
            96 -> 0 on four sequences (with the face-model term's fit moved to the prediction;
            docs/stereo_tracker.md, "Loss and recovery (stereo)").
        fast_motion_px: a pair on which the head is moving more than this, px per frame
            interval in the left image (the largest node displacement of the head's rigid
            motion between the last two pairs), is solved from one pyramid level more than
            ``pyramid_levels``, made for it alone, the face-model term on it (0: never; not
            while flagged nodes have shown an occluder, :mod:`.stereo_occlusion`). An
            expression's onset is not predicted, and where the head moves that fast a frame
            interval is long enough for the jaw to drop beyond the two levels' reach (about 5
            px): the lower lip and chin settled on the neck and were followed there, TRACKING.
            Rendered free motion, 100 pairs at 10 fps: pairs more than 3 px RMS off (the nodes
            both cameras see) 156 -> 29 on seeds 0-7, 236 -> 185 on seeds 8-15; 120 pairs at
            15 fps: 69 -> 3; 150 at 30 fps: 2 -> 2.
        rigid_start_px: a pair one frame interval after the last tracked one starts from the head's
            rigid motion alone (measured on the other nodes) when a node moved more than this a
            frame interval between the last two pairs, px in the left image beyond the head's rigid
            motion, instead of from each node's own motion (``predict_motion``; 0: always each
            node's own; not while flagged nodes have shown an occluder). An expression that moves
            that far in one interval is sampled too coarsely for its motion to be carried on: a
            talking jaw opens and closes every few pairs at 10 fps, and the lower lip and chin
            were left 9-12 px off.
            Rendered free motion, 100 pairs at 10 fps: pairs more than 3 px RMS off 29 -> 12 on
            seeds 0-7, 185 -> 115 on seeds 8-15, 92 -> 48 on seeds 16-31; 15 and 30 fps as before.
        max_iterations: Levenberg-Marquardt iterations per pyramid level.
        step_tolerance: level 0 has converged when no node's projection moves more than this
            in an iteration, px (that last step is taken without evaluating its cost).
        coarse_step_tolerance: the same for the coarser levels, px of that level: the next
            level refines their solution anyway. Measured at 0.5 against 0.1: linearisations
            per pair 4.06 -> 3.06 on the speed benchmark's sequence (34 nodes, 300 pairs; node
            RMS 3.55 mm both, and 4.63 -> 4.48 mm on seed 1); on issue 5's protocol over seeds
            0-3 every figure within 0.06 (seed 3, 1 px clicks: largest reprojection 4.91 ->
            4.97 px, slip 3.78 -> 3.80 mm), but for seed 0's node RMS with 1 px clicks, 3.52
            -> 3.64 mm, its value before level 0's last step went unevaluated (3.63).
        damping: initial Levenberg-Marquardt damping, relative to the Hessian diagonal.
        predict_motion: start each pair's solve from the constant-velocity prediction of the
            nodes (their motion between the last two pairs, carried on over the frame intervals
            since the last pair: more than one after dropped pairs) instead of the last
            pair's nodes; eq. 5 still measures the motion from the last pair. Measured on
            issue 5's protocol (seed 0): every figure the same to the digits shown, and 29 %
            fewer linearisations per pair on the speed benchmark's sequence (coarse level
            3.7 -> 2.0).
        pause_intervals: a gap of more than this many frame intervals since the last tracked
            pair is taken as a pause of the stream (a camera or a bag that stalled; >= 1): the
            pair is solved as a lost track's is re-acquired too (the face found in the left
            image, else the last tracked nodes; eq. 5 from those nodes, no motion predicted),
            and of that and the solve from the motion prediction the one that passes the loss
            checks at the lower residual ratio is taken. The motion of one interval carried on
            over 30 (1 s at 30 fps) put the start 50-250 px off a head that had not moved, and
            eq. 5 held the searched start's solve to it: rendered 640x480, the live benchmark's
            sequence, 4.5 px (25 mm) off after 1 s and LOST after 3 s, now 2.2 px (4.4 mm, as
            without the pause). 9 takes 1 s at 10 fps for a pause (rendered, 4 seeds: 4.7-14.5
            -> 2.6-6.1 mm RMS) and leaves the 10-fps dropped-pair runs (gaps up to 6 intervals)
            as they were; at 30 fps with 10 pairs dropped, taken as pauses, no pair is LOST or
            wrong either way. Every gap taken as a pause (1): at 10 fps with 5 pairs dropped,
            pairs tracked more than 3 px off 1 -> 7 on four sequences.
        coarsest_level_px: the solve starts on level 0, and the coarser levels are solved
            (from level 1, :func:`.coarse_to_fine`; with the default two levels that is the
            coarsest) only when level 0's first step moves a node more than this, px
            (>= 0; 0, the default, always solves them). Faster but off by default: at 0.5 px,
            linearisations per pair 3.06 -> 2.62 on the speed benchmark's sequence (4.06 ->
            2.54 while the coarse level ran to ``step_tolerance``), but on issue 5's protocol
            (measured then) the face edge slips more (seed 3, 1 px clicks: 3.75 -> 4.79 mm;
            exact clicks 1.70 -> 1.76 mm) and the 19-node drift grows (seeds 0-3: 0.22 / 0.32 /
            0.34 / 0.28 -> 0.27 / 0.37 / 0.32 / 0.37 mm), while seed 2's largest 19-node
            reprojection error falls (1.19 -> 1.03 px).
        huber_k: Huber threshold in robust standard deviations of the image residuals.
        noise_floor: smallest robust standard deviation assumed for image residuals, grey levels.
        lost_ratio: the track is LOST when the median over node patches of the residual RMS
            divided by the template's contrast (about 1 for an unrelated image) exceeds this.
        gap_lost_ratio: the same test's limit for a pair after dropped pairs or bad frames (and
            the first pair after the initial one), and for a lost track's re-acquisition, if
            lower than ``lost_ratio``. Such a pair is
            solved from far coarser levels and can settle on another part of the face and pass
            at 0.8 (rendered 10 fps, 5 pairs dropped: 10-33 px off at 0.76-0.80, then followed
            there at 0.5-0.65; the 34-node mesh's gap pairs tracked right measured 0.18-0.61).
            At 0.7 a 19-node track settled 18 px off at 0.70 and went on there; with 0.65, pairs
            more than 3 px off on four such sequences 66 / 0 / 0 / 42 -> 29 / 0 / 0 / 6.
        occlusion_ratio: a node whose patch's left and right images disagree beyond this at
            the solved nodes (the RMS of their ZSSD difference over the left patch's contrast)
            is taken as covered by something in front of the face: it moves with the head's
            rigid motion and keeps its templates until they agree again
            (:mod:`.stereo_occlusion`). The face-edge and nose nodes, which each camera sees
            differently without an occluder, are covered only next to a covered node and
            beyond twice this. Unoccluded rendered sequences read 0.1-0.7 on the other nodes,
            nodes under a passing occluder 0.6-1.8. A patch whose usual disagreement (its mean
            over the pairs it agreed on) is above half of this is covered only beyond twice that
            (a brow reading 0.71 on the median pair of a training sequence, on its feature, was
            held and left 5 px off as it fell). 0 turns the check off.
        min_texture_ratio: the track is LOST when the median over node patches of their
            contrast in the image divided by the template's (about 1 while the face is seen)
            falls below this: a dark, blank or saturated image, which the residual test passes
            (its residual is the template's own contrast, less the brightness ramp: a blank
            pair measured 0.64 on the 19-node mesh).
        model_weight_edge: lambda_i of the face-model term (:mod:`.action_prior`) for the
            face-edge nodes, grey^2 / m^2; 0 disables the term for them.
        model_weight_inner: lambda_i of that term for the other nodes, grey^2 / m^2. Three
            synthetic populations' training sequences (19 nodes) against 1e8: the largest
            reprojection error 0.93 / 1.34 / 1.52 -> 0.97 / 1.09 / 1.35 px (a smiling mouth
            corner and a frowning inner brow stopped short of their motion), node RMS equal.
            The term pulls towards the expressions of its model, here the packaged one learned
            from the same synthetic world, so on faces whose expressions it lacks the gain may
            not hold; 1e9 was kept out for that reason and is no better on these sequences.
        refine_depths: pool the left-right evidence of every pair in the frame-1 node depths
            (:mod:`.depth_refinement`). Off by default: the correction converges over the
            first 20-75 pairs and, in a stream, shows as that much apparent motion of the mesh
            (drift 0.2 -> 1.5-5 mm on the 380-frame sequences); meshes tracked that way and
            learned from taught the demo's model spurious expression modes (LOO A 1.00 -> 0.93).
            Offline, :meth:`StereoTracker.with_final_depths` applies the final depths to every
            pair (the stereo_tracker's retroactive_depths, which face-tracking learn uses on raw
            stereo bags), which is where it pays: node RMS 5.5 / 2.1 -> 1.5 / 1.8 mm on those
            sequences.
        matched_depth_std: standard deviation of a stereo-matched node's initial depth, m.
            Measured over 18 synthetic subjects: 1.4-1.7 mm RMS per population, up to 8.6 mm.
            The refinement corrects at most 3 standard deviations, so with 1 mm a node matched
            10 mm off stayed 7 mm off (three populations, 19 nodes: node RMS 0.84 / 0.81 /
            1.33 -> 0.78 / 0.78 / 0.83 mm with this and ``init.refine_half_size`` 5).
        placed_depth_std: standard deviation of the initial depth of a node placed from the
            reference face (face-edge nodes, unmatched nodes), m.
        depth_gate: a node gets no depth update while its accumulated left-right residual
            exceeds this multiple of its residual between consecutive images.
        depth_step_px: largest depth change per pair, in pixels of disparity.
        deform_patches: node patches deform with the mesh (:class:`.PatchDeformation`): a
            raised brow stretches the skin between brow and eye. Rigid patches stop short of
            the motion; over issue 5's six 380-frame training sequences the 19-node mesh's
            largest reprojection error went 1.71 -> 0.95 px with this (and the texture term
            on the face-edge triangles only), brows and lips; on a second population the
            brows gained as much but a smiling mouth corner lost (1.23 -> 1.33 px).
        fit_edge_weight: weight in [0, 1] of the face-edge nodes, against 1 for the others, in
            the model fit reported with each result (their depth is the least certain: on a
            150-frame free-motion sequence 0.1 brings the fitted rotation from 4.0 to 1.5
            degrees of the truth and the translation from 2.2 to 0.4 mm).
        fit_node_noise: error s, m per coordinate, of the tracked nodes that the model fit
            reported with each result assumes: it adds the §4.1 prior on alpha,
            ``s^2 alpha' Sigma_alpha^-1 alpha``, and so reports the most probable alpha of the
            nodes (:func:`~face_tracking_ros.recognition.node_fit.fit_model_to_nodes`). 0: no
            prior (the least-squares alpha). The inner nodes of 12 rendered 640x480 sequences of
            free head motion (yaw up to 30 degrees, 1-px clicks) were 2.0 mm off per coordinate
            (RMS; 1.4 / 1.4 / 2.9 mm in x / y / depth), which the least-squares alpha read on
            its smallest modes, those the expression classifier weighs most (a frown after a
            jaw_open, the head turned 30 degrees). With 2 mm the packaged classifier's events on
            24 such sequences (six expressions, held or starting under an occluder's pass, with
            and without the occluder): F1 0.889 -> 1.000 without it, 0.529 -> 0.667 with it
            (0.621 with the flags of held nodes only beside another, which end the recogniser's
            hold sooner); from the true nodes 1.000 either way, onsets a frame or two later.
            The prior shrinks a mode of variance l by l / (l + s^2), the smallest (the frown's)
            by 0.57 at 2 mm: at 3 mm the frowns were not recognised.
        gain_compensation: measure the right camera's gain relative to the left at each
            (re)initialisation, on the node patches, and divide it out of the right images
            (:mod:`.camera_gain`): eq. 4's cross-camera terms assume equal gains.
        row_offset_correction: measure at each (re)initialisation how far the right image
            shows the nodes below where the rig projects them and move the right camera's rows
            by that much (:mod:`.row_offset`): eq. 4 assumes the pair is rectified exactly.
        regularisation: the eq. 5 weights.
        init: the epipolar search used at (re)initialisation.
    """

    num_nodes: int = 34
    gamma: float = 0.5
    boundary_gamma: float = 0.0
    boundary_one_sided: bool = True
    epsilon: float = 0.2
    texture_weight: float = 0.5
    texture_subdivisions: int = 4
    patch_half_size: int = 3
    cross_taper: float = 0.0
    pyramid_levels: int = 2
    gap_pyramid_levels: int = 4
    fast_motion_px: float = 4.0
    rigid_start_px: float = 2.0
    max_iterations: int = 6
    step_tolerance: float = 0.1
    coarse_step_tolerance: float = 0.5
    damping: float = 1e-4
    predict_motion: bool = True
    pause_intervals: int = 9
    coarsest_level_px: float = 0.0
    huber_k: float = 1.345
    noise_floor: float = 2.0
    lost_ratio: float = 0.8
    gap_lost_ratio: float = 0.65
    occlusion_ratio: float = 0.7
    min_texture_ratio: float = 0.3
    model_weight_edge: float = 1e9
    model_weight_inner: float = 3e8
    refine_depths: bool = False
    matched_depth_std: float = 0.003
    placed_depth_std: float = 0.005
    depth_gate: float = 2.0
    depth_step_px: float = 0.5
    fit_edge_weight: float = 0.1
    fit_node_noise: float = 0.002
    deform_patches: bool = True
    gain_compensation: bool = True
    row_offset_correction: bool = True
    regularisation: RegularisationConfig = field(default_factory=RegularisationConfig)
    init: StereoInitConfig = field(default_factory=StereoInitConfig)

    def __post_init__(self) -> None:
        """Validate ranges.

        Raises:
            ConfigError: naming the first out-of-range tunable.
        """
        checks = {
            'num_nodes': self.num_nodes in SUPPORTED_NODE_COUNTS,
            'gamma': 0.0 <= self.gamma <= 1.0,
            'boundary_gamma': 0.0 <= self.boundary_gamma <= 1.0,
            'epsilon': 0.0 <= self.epsilon < 1.0,
            'texture_weight': self.texture_weight >= 0.0,
            'texture_subdivisions': 3 <= self.texture_subdivisions <= MAX_SUBDIVISIONS,
            'patch_half_size': 1 <= self.patch_half_size <= MAX_HALF_SIZE,
            'cross_taper': self.cross_taper >= 0.0,
            'pyramid_levels': self.pyramid_levels >= 1,
            'gap_pyramid_levels': self.gap_pyramid_levels >= 1,
            'fast_motion_px': self.fast_motion_px >= 0.0,
            'rigid_start_px': self.rigid_start_px >= 0.0,
            'max_iterations': self.max_iterations >= 1,
            'step_tolerance': self.step_tolerance > 0.0,
            'coarse_step_tolerance': self.coarse_step_tolerance > 0.0,
            'damping': self.damping >= 0.0,
            'pause_intervals': self.pause_intervals >= 1,
            'coarsest_level_px': self.coarsest_level_px >= 0.0,
            'huber_k': self.huber_k > 0.0,
            'noise_floor': self.noise_floor > 0.0,
            'lost_ratio': self.lost_ratio > 0.0,
            'gap_lost_ratio': self.gap_lost_ratio > 0.0,
            'occlusion_ratio': self.occlusion_ratio >= 0.0,
            'min_texture_ratio': 0.0 <= self.min_texture_ratio < 1.0,
            'model_weight_edge': self.model_weight_edge >= 0.0,
            'model_weight_inner': self.model_weight_inner >= 0.0,
            'matched_depth_std': self.matched_depth_std > 0.0,
            'placed_depth_std': self.placed_depth_std > 0.0,
            'depth_gate': self.depth_gate > 0.0,
            'depth_step_px': self.depth_step_px > 0.0,
            'fit_edge_weight': 0.0 <= self.fit_edge_weight <= 1.0,
            'fit_node_noise': 0.0 <= self.fit_node_noise < math.inf,
        }
        check_fields(self, checks)
