"""The stereo tracker of §3.3: the mesh nodes tracked in 3-D through rectified stereo sequences.

Each frame, all 3N node coordinates X_c (left camera frame, m) are estimated jointly by
Levenberg-Marquardt on

    E(n) = sum_i E_i(n)                (eq. 4: left-left, right-right and the two cross-camera
                                        terms weighted by gamma, over a patch around each node
                                        that deforms with the mesh, ``deform_patches``)
         + texture term                (§4.2: the same temporal terms over the face texture
                                        inside the mesh triangles that have a face-edge node)
         + eq. 5 regularisation        (rho_i, beta_ij, delta_ij; :mod:`.regularisation`)
         + face-model term             (the frame-1 mesh animated by the learned action basis,
                                        eq. 1 and 3; :mod:`.action_prior`)

coarse to fine on Gaussian pyramids of both images, with Huber weights on every image residual.
Each image term is split (1 - epsilon) : epsilon between frame n - 1 and frame 1, the drift
term of eq. 6, which stops the random walk of plain frame-to-frame tracking. After each pair the
left-right evidence of that pair can be pooled into the frame-1 node depths, which the face-model
term, eq. 5 and the frame-1 templates then follow (``refine_depths``, :mod:`.depth_refinement`):
one pair measures the depth of weakly textured skin and of the face-edge nodes only to
millimetres. Offline, :meth:`StereoTracker.with_final_depths` gives every pair of a track the
depths refined over all of it.
The tunables are :class:`~.stereo_config.StereoTrackerConfig`; E(n) and the Levenberg-Marquardt
solve of one pyramid level are in :mod:`.stereo_solve`, the image terms and their sample layouts
in :mod:`.stereo_data`, a track's templates (where they are sampled, their weights a_k) in
:mod:`.stereo_templates`; initialisation by epipolar search in :mod:`.stereo_init`; the optional
model fit (eq. 1-3) is :func:`face_tracking_ros.recognition.node_fit.fit_model_to_nodes`.

The tracker never raises on a bad frame: it returns a :class:`~.stereo_result.StereoResult` whose
status says what happened (:class:`~.result.TrackStatus`; what declares a track lost is
:mod:`.stereo_loss`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import cache, partial
from typing import NamedTuple

import numpy as np
from scipy.linalg import LinAlgError

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import (
    ConfigError,
    FaceTrackingError,
    InputError,
    ModelFileError,
)
from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.geometry.procrustes import rigid_rotation
from face_tracking_ros.geometry.rotation import matrix_to_omega, rodrigues
from face_tracking_ros.imaging import (
    ImagePyramid,
    PyramidLevel,
    check_levels_fit,
    tracking_levels,
)
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.model.topology import Group, MeshTopology, mesh_topology
from face_tracking_ros.recognition.node_fit import NodeFit, NodeFitProblem
from face_tracking_ros.tracking.action_prior import ActionPrior, ModelPoint
from face_tracking_ros.tracking.camera_gain import GAIN_RESOLUTION, relative_gain
from face_tracking_ros.tracking.coarse_to_fine import coarse_to_fine
from face_tracking_ros.tracking.depth_refinement import DepthRefinement, depth_evidence
from face_tracking_ros.tracking.detector import Detector
from face_tracking_ros.tracking.initialisation import Initialisation
from face_tracking_ros.tracking.mono_priors import Priors
from face_tracking_ros.tracking.mono_search import FaceView
from face_tracking_ros.tracking.regularisation import Regulariser
from face_tracking_ros.tracking.residual_spikes import SOLVE_GAIN, PatchResiduals
from face_tracking_ros.tracking.result import TrackStatus
from face_tracking_ros.tracking.robust import nanmedian
from face_tracking_ros.tracking.row_offset import ROW_OFFSET_RESOLUTION_PX, row_offset
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_data import (
    GroupStatistics,
    Huber,
    SampleSet,
    group_statistics,
    level_projections,
)
from face_tracking_ros.tracking.stereo_init import (
    InitialNodes,
    check_baseline,
    check_face_scale,
    check_in_view,
    check_raw_not_swapped,
    initial_nodes,
)
from face_tracking_ros.tracking.stereo_loss import (
    loss_reason,
    patch_ratios,
    residual_ratio,
    residual_total,
)
from face_tracking_ros.tracking.stereo_occlusion import (
    MIN_UNCOVERED_NODES,
    Agreement,
    covered_nodes,
    face_hidden,
    first_frame_coefficients,
    held_nodes,
    kept_templates,
    occluder_leaving,
    occluder_nodes,
    occluder_shown,
    stereo_disagreement,
)
from face_tracking_ros.tracking.stereo_result import StereoResult, TrackedSequence, split_tracks
from face_tracking_ros.tracking.stereo_solve import Level, LevelSolver, PairEnergy, Point
from face_tracking_ros.tracking.stereo_templates import (
    TemplateSamples,
    level_templates,
    templates,
)
from face_tracking_ros.tracking.surface_patches import PatchDeformation, patch_field
from face_tracking_ros.wording import counted

LEFT, RIGHT = 0, 1
# A pair of raw images the caller rectified, made again when asked with the raw images exchanged
# and each rectified as its own camera's (the right image topic's as the left camera's): the
# pair as it would come if its image topics were remapped the wrong way round.
ExchangedPair = Callable[[], tuple[np.ndarray, np.ndarray]]
# The reported model fit's Gauss-Newton stops at a step this small (rad, m, basis units): from
# the previous pair's fit the steps of tracked pairs run about 8e-3, 8e-5, 4e-6, 3e-8, so the
# fit is then within ~1e-7 (1e-7 took a fourth iteration for nothing visible).
FIT_TOLERANCE = 1e-5
CORRECTION_ROUNDS = 3  # of the rig's gain and row offset at initialisation (see _corrected)


@dataclass
class _State:
    """What the tracker carries from frame to frame.

    Sample arrays run along the sample axis of ``samples`` (node patches, then the face
    texture); template arrays are (2, S) float32, left image then right, one per pyramid level.
    """

    first_nodes: np.ndarray
    nodes: np.ndarray
    rotation: np.ndarray
    first_pyramids: tuple[ImagePyramid, ImagePyramid]
    previous_pyramids: tuple[ImagePyramid, ImagePyramid]  # the pair of ``nodes``
    samples: SampleSet
    patches: SampleSet  # the node patches alone (depth refinement)
    coefficients: np.ndarray  # (4, S) a_k of the templates of :meth:`StereoTracker._level`
    offsets: np.ndarray  # (3, S) level-0 sample offsets turned by ``rotation`` (rigid)
    deformation: PatchDeformation | None  # moves the node-patch samples with the mesh
    first_templates: tuple[np.ndarray, ...]
    previous_templates: tuple[np.ndarray, ...]  # frame n - 1 at ``nodes``
    regulariser: Regulariser
    prior: ActionPrior | None
    theta: ModelPoint | None  # the face-model term's last fit
    noise: np.ndarray
    depths: DepthRefinement | None
    result: StereoResult
    agreement: Agreement  # how the node patches' left and right images agreed so far
    region: np.ndarray  # (N,) bool, nodes flagged since the last pair with none (an occluder's)
    shown: bool  # a patch of the region has shown an occluder (.stereo_occlusion.occluder_shown)
    residuals: PatchResiduals  # the inner node patches' recent residual ratios, left image
    before: np.ndarray | None = None  # the pair before's nodes (the motion prediction)
    span: int = 1  # frame intervals from ``before`` to ``nodes``
    elapsed: int = 0  # frame intervals from ``nodes`` to the pair being tracked (bad frames too)
    unsampled: np.ndarray | None = None  # (N,) covered nodes: templates at ``nodes`` to sample

    @property
    def after_gap(self) -> bool:
        """Whether the pair being tracked is solved and checked as a pair after a gap.

        After dropped pairs or bad frames (more than one frame interval since ``nodes``), and
        on the first pair after the initial one: with no pair before, nothing predicts the
        head's motion, so the solve starts from the initial nodes and their error is the whole
        motion of one interval (rendered free motion at 10 fps: 9-10 px on seeds 9 and 12,
        where the pyramid's two levels reach about 5; seed 9's pair 1 settled 8.7 px off at a
        residual ratio of 0.77, under ``lost_ratio``, and the track went on 10-12 px off).
        """
        return self.elapsed > 1 or self.before is None


@dataclass
class _Solves:
    """What the levels' solves of one pair spent, and each level with its last accepted point."""

    iterations: int = 0
    history: list[float] = field(default_factory=list)
    levels: list[tuple[Level, Point]] = field(default_factory=list)
    theta: ModelPoint | None = None  # the face-model term's fit, moved on by the solves


class _Cover(NamedTuple):
    """What an occluder covers on a pair (:meth:`StereoTracker._cover`)."""

    covered: np.ndarray  # the nodes held to the head's rigid motion
    agreement: Agreement  # the patches' agreement so far, this pair's included
    flagged: np.ndarray  # the covered nodes reported in ``FaceState.occluded``
    shown: bool  # a flagged patch shows an occluder (.stereo_occlusion.occluder_shown)


class _Attempt(NamedTuple):
    """A pair solved from some start: the nodes, their level-0 statistics and why they fail."""

    nodes: np.ndarray
    statistics: GroupStatistics | None  # None when a level's solve failed
    solves: _Solves
    problem: str  # '' when the nodes pass the loss checks
    reference: np.ndarray  # (N, 3) the nodes eq. 5 measured the motion from
    cover: _Cover | None = None  # what an occluder covers there (None: the checks failed)


class StereoTracker:
    """Tracks the N mesh nodes in 3-D through a rectified stereo sequence (eq. 4 and 5).

    Usage: ``reset(init)`` with the nodes' pixel positions in the next left image
    (semi-automatic), or ``reset()`` with a landmark detector (automatic: the detector's nodes
    in the next left image in which it finds a face), then ``step(left, right)`` for every pair.
    A caller that publishes each result may call :meth:`prepare` once it has, so that the result
    does not wait for the templates of the next pair.
    A lost track is re-acquired on a later pair where the face is found again (without a
    detector, :meth:`_reacquire`); with a detector it stays LOST until the detector finds the
    face, which starts a new track (``new_track``); a failed initialisation until the next
    reset or detection.
    """

    def __init__(
        self,
        rig: StereoRig,
        config: StereoTrackerConfig,
        model: FaceModel | None = None,
        detector: Detector | None = None,
    ) -> None:
        """Set up the tracker.

        Args:
            rig: the rectified stereo rig (P matrices of both cameras).
            config: the tunables.
            model: optional face model; when given, every result carries the fit of eq. 1-3.
                The face-model term uses its action basis (the packaged default model's when
                None).
            detector: optional landmark detector (e.g.
                :class:`~face_tracking_ros.tracking.detector.DlibLandmarkDetector`) for
                automatic initialisation by ``reset()``.

        Raises:
            ConfigError: if the model's node count differs from ``config.num_nodes``, the
                pyramid is too deep for the images, or the face-model term is on, no model is
                given and the packaged one is missing.
            InputError: if the rig's baseline shows no face of the initialisation's depth range
                in both images (:func:`~.stereo_init.check_baseline`: a baseline in mm).
        """
        if model is not None and model.num_nodes != config.num_nodes:
            msg = f'model has {model.num_nodes} nodes but the tracker is set to {config.num_nodes}'
            raise ConfigError(msg)
        check_levels_fit(config.pyramid_levels, rig.left.width, rig.left.height)
        fitting = tracking_levels(rig.left.width, rig.left.height)
        self._gap_levels = max(config.pyramid_levels, min(config.gap_pyramid_levels, fitting))
        self._fast_levels = max(config.pyramid_levels, min(config.pyramid_levels + 1, fitting))
        check_baseline(rig, config.init)
        self._calibrated_rig = rig
        self._config = config
        self._prior_model = _prior_model(config, model)
        self._detector = detector
        self._topology: MeshTopology = mesh_topology(config.num_nodes)
        self._template_samples = TemplateSamples(config, self._topology)
        self._boundary = self._topology.group_mask(Group.EDGE)
        # The nodes whose own patches tell an occluder: not the face edge's nor the nose's (the
        # two cameras see those differently without one, :mod:`.stereo_occlusion`).
        self._occludable = ~self._topology.group_mask(Group.EDGE, Group.NOSE)
        self._alignment_weights = self._topology.alignment_weights()  # of the head's rotation
        self._fit_problem = None
        if model is not None:  # the reported fit's, prepared once (weights, prior: _fit)
            weights = np.where(self._boundary, config.fit_edge_weight, 1.0)
            self._fit_problem = NodeFitProblem.of(model, weights, _fit_precision(config, model))
        self._use_rig(rig)
        self._spare: tuple[ImagePyramid, ImagePyramid] | None = None
        self._right_gain = 1.0  # divided out of the right images (measured at initialisation)
        self._pending: np.ndarray | None = None
        self._detect = False
        self._state: _State | None = None
        self._lost: _State | None = None  # a lost track's, re-acquired without a detector
        self._lost_result: StereoResult | None = None  # its last tracked pair's, kept while LOST
        self._status = TrackStatus.INITIALIZING
        self._reason = 'not initialised: call reset() with the initial node positions'

    @property
    def topology(self) -> MeshTopology:
        """The mesh topology being tracked."""
        return self._topology

    @property
    def right_row_offset(self) -> float:
        """How far the right camera's rows are moved from the calibration's, px (down: > 0).

        Each initialisation measures it (``row_offset_correction``, :mod:`.row_offset`); 0
        before.
        """
        return float(self._rig.right.p[1, 2] - self._calibrated_rig.right.p[1, 2])

    @property
    def right_gain(self) -> float:
        """The right camera's gain relative to the left, divided out of its images.

        Each initialisation measures it (``gain_compensation``, :mod:`.camera_gain`); 1 before.
        """
        return self._right_gain

    def reset(self, init: np.ndarray | Initialisation | None = None) -> None:
        """Re-initialise on the next stereo pair from the nodes' left-image positions.

        Args:
            init: an :class:`~.initialisation.Initialisation` (named nodes from an init file,
                the ResetTracking service or a detector), or an (N, 2) array of left-image pixel
                positions with NaN rows for nodes not given. At least
                ``config.init.min_given_nodes`` (default 6) nodes must be given; the rest are
                filled in from the reference face fitted to the given ones. None: run the
                detector on the coming left images until it finds a face.

        Raises:
            InputError: if the array is not (N, 2) or gives fewer than
                ``config.init.min_given_nodes`` nodes.
            ConfigError: if an Initialisation names a node the mesh does not have, or init is
                None and the tracker has no detector. The tracker is then left as it was.
        """
        if init is None and self._detector is None:
            msg = 'reset() without node positions needs a landmark detector'
            raise ConfigError(msg)
        pending = None if init is None else self._left_px(init)
        self._state = self._lost = self._lost_result = None
        self._right_gain = 1.0  # the initialisation measures them afresh, on the raw images
        self._use_rig(self._calibrated_rig)
        self._status = TrackStatus.INITIALIZING
        self._reason = 'waiting for the first stereo pair after reset'
        self._pending, self._detect = pending, init is None

    def _left_px(self, init: np.ndarray | Initialisation) -> np.ndarray:
        """Validated (N, 2) left-image node positions (NaN rows: not given)."""
        if isinstance(init, Initialisation):
            left_px = np.full((self._topology.num_nodes, 2), np.nan)
            left_px[[self._topology.index(name) for name in init.node_names]] = init.points
        else:
            left_px = np.asarray(init, dtype=float)
        if left_px.shape != (self._topology.num_nodes, 2):
            msg = f'left_px must be ({self._topology.num_nodes}, 2), got {left_px.shape}'
            raise InputError(msg)
        given = np.all(np.isfinite(left_px), axis=1)
        if given.sum() < self._config.init.min_given_nodes:
            msg = (
                f'only {counted(int(given.sum()), "node")} given; at least '
                f'{self._config.init.min_given_nodes} are needed'
            )
            raise InputError(msg)
        return left_px

    def step(
        self,
        left: np.ndarray,
        right: np.ndarray,
        intervals: int = 1,
        exchanged: ExchangedPair | None = None,
    ) -> StereoResult:
        """Track one rectified stereo pair.

        Args:
            left: (H, W) grey left image (uint8 or float, grey levels 0-255).
            right: (H, W) grey right image.
            intervals: frame intervals since the previous pair: 1 for the next pair of the
                stream, n + 1 after n dropped pairs; the motion prediction is carried on over
                them, and over those of bad frames since the last tracked pair (as over
                dropped pairs: a bad frame keeps the track), and a pair after such a gap is
                solved from coarser pyramid levels too (``gap_pyramid_levels``); after more
                than ``pause_intervals``, from the last tracked nodes too.
            exchanged: for raw images the caller rectified, the pair made from them exchanged
                (:data:`ExchangedPair`, grey images as ``left`` and ``right``): an
                initialisation that fails on this pair is tried on it, to name image topics
                remapped the wrong way round (:func:`~.stereo_init.check_raw_not_swapped`).
                None: the images came rectified.

        Returns:
            The result; never raises on a bad frame (status LOST, reason set, state kept).

        Raises:
            InputError: if ``intervals`` is less than 1 (not a bad frame but a bad call).
        """
        if intervals < 1:
            msg = f'intervals must be >= 1 (frame intervals since the last pair), got {intervals}'
            raise InputError(msg)
        self.prepare()
        before = self._held()
        for state in (self._state, self._lost):
            if state is not None:
                state.elapsed += intervals
        try:
            pyramids = self._pyramids(left, right)
        except InputError as error:
            return self._not_tracking(TrackStatus.LOST, f'bad frame: {error}')
        if self._detect:
            self._pending = self._detected(left)
        if self._pending is not None:
            result = self._initialise(pyramids, exchanged)
        elif self._state is not None:
            result = self._track(pyramids)
        elif self._lost is not None:
            result = self._reacquire(pyramids)
        else:
            result = self._not_tracking(self._status, self._reason)
        # Frame 1's pyramids and the last tracked pair's are kept, owning their images (they
        # read the caller's until then); the others' arrays take the next pair.
        kept = self._held()
        for pair in kept:
            for pyramid in pair:
                pyramid.own()
        self._spare = next((p for p in (pyramids, *before) if not any(p is k for k in kept)), None)
        return result

    def prepare(self) -> None:
        """Sample the last tracked pair's templates, the next pair's solve's, if not done yet.

        The part of :meth:`step` that its result does not need, left for later: a node runs it
        once the pair's outputs are published (``run_deferred``), and the next ``step`` first
        runs it if no one has. Nodes an occluder covered keep their templates
        (:func:`~.stereo_occlusion.kept_templates`). About 0.3 ms of a 640x480 pair's 3 ms
        (34 nodes, one core).
        """
        state = self._state
        if state is None or state.unsampled is None:
            return
        covered, state.unsampled = state.unsampled, None
        state.offsets = state.samples.level_offsets(state.rotation, 0)
        field = patch_field(state.deformation, state.nodes, state.first_nodes, state.rotation)
        sampled = templates(
            state.previous_pyramids,
            self._projections,
            state.samples,
            state.nodes,
            state.offsets,
            field,
        )
        state.previous_templates = (
            kept_templates(state.previous_templates, sampled, covered, state.samples)
            if covered.any()
            else sampled
        )

    def _held(self) -> tuple[tuple[ImagePyramid, ImagePyramid], ...]:
        """The pyramids a track (or a lost one) keeps: frame 1's and the last tracked pair's."""
        state = self._lost if self._state is None else self._state
        return () if state is None else (state.first_pyramids, state.previous_pyramids)

    def with_final_depths(self, results: Sequence[StereoResult]) -> list[StereoResult]:
        """The results of a run, each with the frame-1 depths refined over its whole track.

        Offline, every pair can get the depths pooled over all pairs of the track
        (:mod:`.depth_refinement`): the mesh of pair n becomes
        ``X(n) + R(n) (X(1 | F) - X(1 | n))``, with X(1 | n) the frame-1 nodes as refined up to
        pair n, X(1 | F) after the last pair and R(n) the head rotation since frame 1. The
        projections, ``first_nodes`` and, with a model, the fit follow the moved nodes; the
        residuals stay those of the tracked solution. Results without frame-1 nodes (before the
        first pair) and results whose frame-1 nodes are already the final ones (no refinement)
        are returned as they are.

        Args:
            results: results in the order of their pairs since a reset; a track starts at each
                ``new_track`` result (a detection after a loss starts another) and gets its own
                final depths.
        """
        final: list[StereoResult] = []
        for track in split_tracks(results):
            refined = [r.first_nodes for r in track if r.first_nodes is not None]
            final += [self._with_first_nodes(r, refined[-1]) for r in track] if refined else track
        return final

    def _with_first_nodes(self, result: StereoResult, first_nodes: np.ndarray) -> StereoResult:
        """``result`` moved with its frame-1 nodes to ``first_nodes`` (see with_final_depths)."""
        if (
            result.first_nodes is None
            or result.rotation is None
            or np.array_equal(result.first_nodes, first_nodes)
        ):
            return result
        nodes = result.nodes_cam + (first_nodes - result.first_nodes) @ result.rotation.T
        return replace(
            result,
            nodes_cam=nodes,
            left_px=self._rig.left.project(nodes),
            right_px=self._rig.right.project(nodes),
            fit=self._fit(nodes, result.fit) if result.ok else result.fit,
            first_nodes=first_nodes,
        )

    # -- initialisation ----------------------------------------------------------------------

    def _detected(self, left: np.ndarray) -> np.ndarray | None:
        """Node positions the detector finds in the left image (None: no usable face yet)."""
        assert self._detector is not None
        gray = np.clip(np.asarray(left), 0, 255).astype(np.uint8)
        try:
            found = self._detector(gray)
            left_px = None if found is None else self._left_px(found)
        except FaceTrackingError as error:
            self._reason = f'waiting for a face: {error}'
            return None
        if left_px is None:
            self._reason = 'waiting for a face: none detected in the left image'
            return None
        self._detect = False
        return left_px

    def _initialise(
        self, pyramids: tuple[ImagePyramid, ImagePyramid], exchanged: ExchangedPair | None
    ) -> StereoResult:
        """Triangulate the pending left-image nodes and start tracking on this pair.

        A failure's reason is the swap of the image topics if the pair made from the raw images
        ``exchanged`` says so (:meth:`_failure_reason`).
        """
        left_px, self._pending = self._pending, None
        config = self._config
        try:
            initial = self._initial_nodes(pyramids, left_px)
            for _ in range(CORRECTION_ROUNDS):  # until what is left is within what they resolve
                if not self._corrected(pyramids, initial):
                    break
                initial = self._initial_nodes(pyramids, left_px)  # matched on the corrected pair
            check_face_scale(initial, self._topology, self._rig, config.init)
            check_in_view(initial, self._topology, self._rig)
        except FaceTrackingError as error:  # no estimate yet: INITIALIZING, as the mono tracker
            self._status = TrackStatus.INITIALIZING
            reason = self._failure_reason(error, left_px, exchanged)
            self._reason = f'initialisation failed: {reason}'
            self._detect = self._detector is not None  # then look for the face again
            return self._not_tracking(self._status, self._reason)
        self._state = self._start(pyramids, initial)
        return self._state.result

    def _failure_reason(
        self, error: FaceTrackingError, left_px: np.ndarray, exchanged: ExchangedPair | None
    ) -> str:
        """Why the initialisation failed: ``error``, unless the raw images look exchanged.

        The pair made from them ``exchanged`` (if given) is initialised with the calibrated rig
        (:func:`~.stereo_init.check_raw_not_swapped`), as float32 images (a pyramid's level 0).
        """
        if exchanged is not None:
            left, right = (np.asarray(image, dtype=np.float32) for image in exchanged())
            try:
                check_raw_not_swapped(
                    self._calibrated_rig, (left, right), left_px, self._topology, self._config.init
                )
            except InputError as swapped:
                return str(swapped)
        return str(error)

    def _start(self, pyramids: tuple[ImagePyramid, ImagePyramid], initial: InitialNodes) -> _State:
        """The state of a track starting at ``initial`` on this pair: samples, templates, terms."""
        config = self._config
        nodes = initial.nodes
        layouts = self._template_samples.layouts(nodes, self._rig.left.focal)
        samples = SampleSet.of(layouts, self._topology.num_nodes)
        offsets = samples.level_offsets(np.eye(3), 0)
        first_templates = templates(pyramids, self._projections, samples, nodes, offsets)
        prior, theta = self._action_prior(nodes)
        depth_std = np.where(initial.matched, config.matched_depth_std, config.placed_depth_std)
        return _State(
            first_nodes=nodes,
            nodes=nodes,
            rotation=np.eye(3),
            first_pyramids=pyramids,
            previous_pyramids=pyramids,
            samples=samples,
            patches=SampleSet.of(layouts[:1], self._topology.num_nodes),
            coefficients=self._template_samples.coefficients(samples),
            offsets=offsets,
            deformation=(
                PatchDeformation.of(nodes, layouts[0].offsets) if config.deform_patches else None
            ),
            first_templates=first_templates,
            previous_templates=first_templates,
            regulariser=Regulariser.build(self._topology, config.regularisation, nodes),
            prior=prior,
            theta=None if prior is None else prior.point(theta),
            noise=np.full(len(layouts), config.noise_floor),
            depths=DepthRefinement.start(nodes, depth_std) if config.refine_depths else None,
            result=replace(self._result(nodes, nodes, np.eye(3), None), new_track=True),
            agreement=Agreement.none(self._topology.num_nodes),
            region=np.zeros(self._topology.num_nodes, dtype=bool),
            shown=False,
            residuals=PatchResiduals(),
        )

    def _initial_nodes(
        self, pyramids: tuple[ImagePyramid, ImagePyramid], left_px: np.ndarray
    ) -> InitialNodes:
        """The pair's initial 3-D nodes from their left-image positions (:func:`initial_nodes`)."""
        return initial_nodes(
            self._rig,
            pyramids[LEFT].levels[0],
            pyramids[RIGHT].levels[0],
            left_px,
            self._topology,
            self._config.init,
        )

    def _corrected(
        self, pyramids: tuple[ImagePyramid, ImagePyramid], initial: InitialNodes
    ) -> bool:
        """Measure the right camera's gain and row offset at the initial nodes; correct them.

        The gain is divided out of the pair's right pyramid (and of every later one), the
        offset moves the right camera's rows (as the configuration asks), each on top of what
        earlier rounds corrected.

        Returns:
            True if either exceeded what its measurement resolves (:data:`GAIN_RESOLUTION`,
            :data:`ROW_OFFSET_RESOLUTION_PX`): the initial nodes, matched on the pair before the
            correction, are then to be matched again and the pair measured again.
        """
        config = self._config
        gain = self._measured_gain(pyramids, initial.nodes) if config.gain_compensation else 1.0
        if gain != 1.0:
            pyramids[RIGHT].scale(1.0 / gain)
            self._right_gain *= gain
        offset = 0.0
        if config.row_offset_correction:
            inner = initial.nodes[initial.matched & ~self._boundary]
            offset = row_offset(
                pyramids[LEFT].levels[0],
                pyramids[RIGHT].levels[0],
                self._rig.left.project(inner),
                self._rig.right.project(inner),
            )
        if offset != 0.0:
            self._use_rig(self._rig.with_right_rows_shifted(offset))
        return abs(gain - 1.0) > GAIN_RESOLUTION or abs(offset) > ROW_OFFSET_RESOLUTION_PX

    def _use_rig(self, rig: StereoRig) -> None:
        """Track with ``rig`` (the calibrated one, or it with the right camera's rows moved)."""
        self._rig = rig
        self._projections = tuple(
            level_projections((rig.left, rig.right), level)
            for level in range(self._config.pyramid_levels)
        )
        self._solver = LevelSolver(self._config, self._projections[0])

    def _measured_gain(
        self, pyramids: tuple[ImagePyramid, ImagePyramid], nodes: np.ndarray
    ) -> float:
        """The right image's gain relative to the left at the node patches of ``nodes``."""
        layout = self._template_samples.node_patches(nodes, self._rig.left.focal)
        patches = SampleSet.of((layout,), self._topology.num_nodes)
        offsets = patches.level_offsets(np.eye(3), 0)
        values = templates(pyramids, self._projections, patches, nodes, offsets)[0]  # level 0's
        return relative_gain(
            values.reshape(2, *layout.mask.shape), layout.mask, self._config.noise_floor
        )

    def _action_prior(self, nodes: np.ndarray) -> tuple[ActionPrior | None, np.ndarray]:
        """The face-model term for a run starting at ``nodes`` (None without weights)."""
        config = self._config
        weights = np.where(self._boundary, config.model_weight_edge, config.model_weight_inner)
        if self._prior_model is None or not np.any(weights > 0):
            return None, np.zeros(0)
        return ActionPrior.build(self._prior_model, nodes, weights)

    # -- tracking ----------------------------------------------------------------------------

    def _track(self, pyramids: tuple[ImagePyramid, ImagePyramid]) -> StereoResult:
        """Solve eq. 4 + eq. 5 for this pair from the predicted nodes, and update the state.

        With ``coarsest_level_px`` set, the solve starts on level 0 and, when level 0's first
        step exceeds it, starts over from the prediction on level 1 (and from the coarsest level
        if level 1's does too: :func:`~.coarse_to_fine.coarse_to_fine`).

        A pair after a gap (more than one frame interval since the last tracked pair) is
        checked at ``gap_lost_ratio`` too, and if its solve fails the checks it is solved again
        from where the face is found (:meth:`_searched`), as a lost track is re-acquired.

        Eq. 5 measures such a pair's motion from the last tracked nodes moved rigidly over the
        gap (:meth:`_rigid_predicted`), not from the nodes themselves: its rho and beta terms
        cost the nodes' motion and the mesh's turn since the last pair, so over a gap they held
        the mesh near that pair's pose, and a turned head's solve shifted the mesh to match the
        last pair's templates instead (rendered free motion at 10 fps, 5 pairs dropped: the
        head turned 22 degrees, the solve 7, and settled 3.4 px off at a residual ratio of 0.48,
        where the check refuses above 0.65; the track went on there).

        After a pause of the stream (more than ``pause_intervals`` since the last tracked pair:
        a camera or a bag that stalled) the pair is solved as a lost track's is re-acquired as
        well (:meth:`_found_again`: eq. 5 from the last tracked nodes, no motion predicted), and
        of the two solutions that pass the checks the one at the lower residual ratio is taken
        (:func:`_better`), as the mono tracker takes the better of its solves after a gap. The
        motion of one interval carried on over a pause is no estimate of where the head is: after
        1 s at 30 fps (30 intervals) with the head moved one frame's worth, the prediction
        started 63 px off, and eq. 5, measured from the rigid prediction as far off, pulled the
        solve from the searched start (0.5 px off) to 11 px: LOST (rendered seed 4; on the live
        benchmark's sequence TRACKING 4.5 px off, 25 mm, and after 3 s LOST). Now 0.24 px.
        """
        state = self._state
        assert state is not None
        searched = cache(partial(self._searched, state, pyramids))  # searched once at most
        attempt = self._followed(state, pyramids, searched)
        if state.elapsed > self._config.pause_intervals:
            attempt = _better(attempt, self._found_again(state, pyramids, searched))
        if attempt.problem:
            return self._lose(attempt.problem)
        return self._advance(state, pyramids, attempt)

    def _followed(
        self,
        state: _State,
        pyramids: tuple[ImagePyramid, ImagePyramid],
        searched: Callable[[], np.ndarray],
    ) -> _Attempt:
        """The pair solved from the motion prediction, after a gap from the searched start too.

        Eq. 5 measures a gap pair's motion from the rigid prediction (see :meth:`_track`).
        ``searched()`` gives the searched start (:meth:`_searched`). Any other pair starts
        from each node's own motion carried on (:meth:`_predicted`), or from the head's rigid
        motion alone after a fast expression (:meth:`_followed_start`), and is solved from one
        coarser level too if the head is moving fast (:meth:`_moving_fast`), or else if an inner
        patch's residual leapt on it (:meth:`_onset_solved`); the first two measure the head's
        rigid motion carried on, made and projected once. None applies without a pair before
        the last, nor while a region of flagged nodes has shown an occluder
        (``state.shown``, :func:`~.stereo_occlusion.occluder_shown`): the region's solve was
        measured from each node's own motion on two levels (from the coarser level, the nodes
        it had covered were left up to 50 px off as it left: rendered 30 fps, a pucker started
        under the occluder; 5.5 px without). Nodes drifted off their features are flagged too,
        with no occluder, but do not show one: on rendered free motion at 10 fps (seed 9, the
        head pitching 2 degrees a pair) the inner brows, 2-3 px off, were flagged together at
        0.77-0.80 of their contrast, and with both off from then the smile's lower lip and chin
        were left 10-17 px off.
        """
        gap = state.after_gap
        if gap:
            rigid = self._rigid_predicted(state)
            attempt = self._attempt(state, pyramids, self._predicted(state), rigid)
        else:
            start, fast = self._predicted(state), False
            if state.before is not None and not state.shown:
                rigid_px = self._rig.left.project(self._rigid_predicted(state))
                start = self._followed_start(state, start, rigid_px)
                fast = self._moving_fast(state, rigid_px)
            attempt = self._attempt(state, pyramids, start, state.nodes, fast=fast)
            if state.before is not None and not state.shown and not fast:
                attempt = self._onset_solved(state, pyramids, start, attempt)
        if attempt.problem and gap:
            found = self._attempt(state, pyramids, searched(), rigid)
            attempt = attempt if found.problem else found
        if attempt.statistics is not None and not attempt.problem:
            state.residuals.add(self._inner_ratios(attempt.statistics))
        return attempt

    def _inner_ratios(self, statistics: GroupStatistics) -> np.ndarray:
        """The inner node patches' residual-to-contrast ratios in the left image (.stereo_loss)."""
        return patch_ratios(statistics)[LEFT][~self._boundary]

    def _onset_solved(
        self,
        state: _State,
        pyramids: tuple[ImagePyramid, ImagePyramid],
        start: np.ndarray,
        attempt: _Attempt,
    ) -> _Attempt:
        """``attempt``, or the pair solved from one coarser level too if that fits it better.

        Asked only when an inner node patch's residual leapt on ``attempt`` in the left image
        (:class:`~.residual_spikes.PatchResiduals`): an expression's onset beyond the two
        levels' reach. Taken when it passes the loss checks at a total residual
        (:func:`~.stereo_loss.residual_total`) below :data:`~.residual_spikes.SOLVE_GAIN` times
        the first solve's.
        """
        if attempt.problem or attempt.statistics is None:
            return attempt
        if not state.residuals.leapt(self._inner_ratios(attempt.statistics)):
            return attempt
        again = self._attempt(state, pyramids, start, state.nodes, fast=True)
        if again.problem or again.statistics is None:
            return attempt
        lower = residual_total(again.statistics) < SOLVE_GAIN * residual_total(attempt.statistics)
        return again if lower else attempt

    def _reacquire(self, pyramids: tuple[ImagePyramid, ImagePyramid]) -> StereoResult:
        """Solve a lost track's pair from where its face is found; LOST unless that passes.

        Without a detector a lost track kept its state (:meth:`_lose`): the last tracked
        pair's nodes, templates and pyramids. Each later pair is solved as a pair after a gap
        (every pyramid level of ``gap_pyramid_levels``, checked at ``gap_lost_ratio``) from those
        nodes moved onto the face's rigid displacement in the left image (:meth:`_searched`);
        the track resumes where that passes the loss checks. Eq. 5 measures the motion from the
        last tracked nodes (the head's motion before the loss says nothing of where it is now).
        If that fails, the pair is solved from those nodes as they were: the search follows
        what the last tracked image shows, and a track lost under an occluder's pass shows the
        occluder there (rendered 640x480, seed 3, 27 of 34 nodes covered: the searched starts
        18-140 px off the face over pairs 141-155, while the head had moved 0.6-7.6 px from the
        last tracked pair; found again from its nodes at pair 149, 2.5 px off, where frame 1's
        start below found it at pair 155, 7.4 px off).

        If that fails too, the pair is solved and checked once more as if frame 1 were the last
        tracked pair (:meth:`_from_first_pair`): the last tracked pair can show what lost the
        track. An occluder passing over part of the face (rendered training sequences at
        30 fps) leaves the median patch residual under ``lost_ratio`` for some pairs, which
        then become templates and the searched face view with the occluder in them; once it
        had gone, the face view correlated best 150 px off the face, and even solved from the
        true nodes the residual against those templates stayed at 0.66-0.91 of their contrast,
        above ``gap_lost_ratio``: the track stayed LOST to the end (48 of 90 pairs).

        A pair not found again is LOST with the reason the track was lost and the last
        attempt's (the mono tracker gives each lost image's own reason too).
        """
        state = self._lost
        assert state is not None
        attempt = self._found_again(state, pyramids, partial(self._searched, state, pyramids))
        if attempt.problem:
            state = self._from_first_pair(state)
            attempt = self._attempt(state, pyramids, self._searched(state, pyramids), state.nodes)
        if attempt.problem:
            reason = f'{self._reason}; not found again: {attempt.problem}'
            return self._not_tracking(TrackStatus.LOST, reason)
        self._state, self._lost = state, None
        return self._advance(state, pyramids, attempt)

    def _found_again(
        self,
        state: _State,
        pyramids: tuple[ImagePyramid, ImagePyramid],
        searched: Callable[[], np.ndarray],
    ) -> _Attempt:
        """The pair solved from the face found in it, or else from the last tracked nodes.

        The solve from the last tracked nodes moved onto the face's displacement in the left
        image (:meth:`_searched`) and, if that fails the loss checks, from those nodes as they
        were; eq. 5 measures the motion from them (no motion is predicted). The first attempt
        that passes, or the search's if neither does. A lost track is re-acquired so
        (:meth:`_reacquire`), and a pair after a pause of the stream is solved so too
        (:meth:`_track`). ``searched()`` gives the searched start (:meth:`_searched`).
        """
        attempt = self._attempt(state, pyramids, searched(), state.nodes)
        if attempt.problem:
            still = self._attempt(state, pyramids, state.nodes, state.nodes)
            attempt = attempt if still.problem else still
        return attempt

    def _from_first_pair(self, state: _State) -> _State:
        """A lost track's state with frame 1 as its last tracked pair: nodes, images, templates.

        The frame-1 nodes are the ones the depth refinement has moved (its templates follow
        them); the state's terms, its depth refinement among them, are shared. With no pair
        before frame 1 the pair is checked as one after a gap.
        """
        return replace(
            state,
            nodes=state.first_nodes,
            rotation=np.eye(3),
            previous_pyramids=state.first_pyramids,
            offsets=state.samples.level_offsets(np.eye(3), 0),
            previous_templates=state.first_templates,
            before=None,
        )

    def _predicted(self, state: _State) -> np.ndarray:
        """Where the nodes are expected on the pair being tracked (``predict_motion``)."""
        if not self._config.predict_motion or state.before is None:
            return state.nodes
        # The nodes' motion between the last two pairs, per frame interval, carried on over
        # the intervals since the last pair (1 and 1 without dropped pairs: 2 n - b).
        ahead = state.elapsed / state.span
        return (1.0 + ahead) * state.nodes - ahead * state.before

    def _followed_start(
        self, state: _State, predicted: np.ndarray, rigid_px: np.ndarray
    ) -> np.ndarray:
        """Where a pair one interval after the last tracked one starts: see ``rigid_start_px``.

        Each node's own motion carried on (``predicted``, :meth:`_predicted`), unless a node
        moved more than ``rigid_start_px`` a frame interval between the last two pairs beyond
        the head's rigid motion (``rigid_px``, :meth:`_rigid_predicted` in the left image; the
        expression changed that fast): then the head's rigid motion alone,
        measured on the nodes that did not (:meth:`_rigid_predicted`), unless fewer than
        :data:`~.stereo_occlusion.MIN_UNCOVERED_NODES` did not. An expression's motion of one
        interval that large is sampled too coarsely to be carried on: a talking jaw opens and
        closes every few 10-fps pairs, and carried on, its motion doubled the error of a jaw that
        turned back (the lower lip and chin then settled 9-12 px off and were followed there).
        """
        limit = self._config.rigid_start_px
        if limit <= 0:
            return predicted
        moved = np.linalg.norm(self._rig.left.project(predicted) - rigid_px, axis=1)
        moving = moved > limit * state.elapsed  # per frame interval, as carried on
        if not moving.any() or np.count_nonzero(~moving) < MIN_UNCOVERED_NODES:
            return predicted
        return self._rigid_predicted(state, np.where(moving, 0.0, self._alignment_weights))

    def _rigid_predicted(self, state: _State, weights: np.ndarray | None = None) -> np.ndarray:
        """The last tracked nodes moved rigidly as the head moved between the last two pairs.

        The head's turn and shift from the pair before to the last pair (Procrustes weighted by
        ``weights``, :meth:`_rotation`'s when None) are carried on over the intervals since the
        last pair, about the nodes' weighted centroid; the mesh keeps its shape. The last nodes
        without ``predict_motion`` or a pair before.
        """
        if not self._config.predict_motion or state.before is None:
            return state.nodes
        weights = self._alignment_weights if weights is None else weights
        ahead = state.elapsed / state.span
        turn, _ = rodrigues(
            ahead * matrix_to_omega(rigid_rotation(state.before, state.nodes, weights))
        )
        share = weights / weights.sum()
        centre, centre_before = share @ state.nodes, share @ state.before
        return centre + ahead * (centre - centre_before) + (state.nodes - centre) @ turn.T

    def _moving_fast(self, state: _State, rigid_px: np.ndarray) -> bool:
        """Whether the head is moving more than ``fast_motion_px`` a frame interval.

        The head's motion carried on from the last two pairs (``rigid_px``,
        :meth:`_rigid_predicted` in the left image): its largest displacement of a node in the
        left image, per interval since the last pair. The head's, not each node's: a node found
        again as an occluder leaves jumps by 10 px and more, which says nothing of the frame
        rate. False with the threshold 0.
        """
        limit = self._config.fast_motion_px
        if limit <= 0:
            return False
        moved = rigid_px - self._rig.left.project(state.nodes)
        return float(np.linalg.norm(moved, axis=1).max()) > limit * state.elapsed

    def _searched(self, state: _State, pyramids: tuple[ImagePyramid, ImagePyramid]) -> np.ndarray:
        """The last tracked nodes moved with the face's displacement in this left image.

        The displacement is where the inner face of the last tracked left image (the nodes off
        the face edge) correlates best with this one (:class:`~.mono_search.FaceView`, the
        mono tracker's search, on level 1), each node moved by it parallel to the image plane
        at its depth.
        """
        left = self._rig.left
        inner = ~self._boundary
        view = FaceView.of(state.previous_pyramids[LEFT], left.project(state.nodes), inner)
        shift = view.shift(pyramids[LEFT])  # level-0 px
        moved = state.nodes.copy()
        moved[:, :2] += shift * state.nodes[:, 2:] / left.focal
        return moved

    def _attempt(
        self,
        state: _State,
        pyramids: tuple[ImagePyramid, ImagePyramid],
        start: np.ndarray,
        reference: np.ndarray,
        region: np.ndarray | None = None,
        fast: bool = False,
    ) -> _Attempt:
        """This pair solved from ``start`` (:meth:`_solve_pair`) and checked (:mod:`.stereo_loss`).

        ``reference``: (N, 3) the nodes eq. 5 measures the motion from; ``region``: the nodes
        found again once an occluder has gone; ``fast``: the head is moving fast (both
        :meth:`_solve_pair`). A pair after a gap, and a pair solved for a region, are checked at
        the stricter ``gap_lost_ratio`` too (solved from coarser levels).

        Nodes that pass fail all the same where an occluder hides the face
        (:func:`~.stereo_occlusion.face_hidden`: too few nodes left uncovered to hold the
        covered ones to the head's motion). Taken with none held, as until 2026-12-07, such a
        pair's templates took in the occluder over the whole face, and the next pair was lost
        with the occluder's flags gone (rendered 640x480, seed 3: 29 of 34 nodes under the
        occluder, 26 flagged on the pair before; the pair after lost at a residual of 0.89 of
        the contrast): the expression recogniser ended the held expression there. Lost on the
        pair the occluder hides, the track keeps the last pair's held nodes and their templates,
        and ``face/state`` says LOST with that pair's flags.
        """
        try:
            nodes, solves = self._solve_pair(state, pyramids, start, reference, region, fast)
        except (LinAlgError, FaceTrackingError) as error:
            return _Attempt(start, None, _Solves(), f'solver failed: {error}', reference)
        level, accepted = solves.levels[-1]  # level 0's
        statistics = group_statistics(
            state.samples, accepted.sampled, accepted.residuals, level.templates[:, 0]
        )
        strict = state.after_gap or region is not None
        problem = loss_reason(nodes, statistics, self._rig, self._config, strict)
        cover = None if problem else self._cover(state, statistics, accepted)
        if cover is not None and face_hidden(cover.covered):
            problem = (
                f'an occluder hides the face ({np.count_nonzero(cover.covered)} of '
                f'{counted(cover.covered.size, "node")} covered)'
            )
        return _Attempt(nodes, statistics, solves, problem, reference, cover)

    def _solve_pair(
        self,
        state: _State,
        pyramids: tuple[ImagePyramid, ImagePyramid],
        start: np.ndarray,
        reference: np.ndarray,
        region: np.ndarray | None = None,
        fast: bool = False,
    ) -> tuple[np.ndarray, _Solves]:
        """The nodes that minimise eq. 4 + eq. 5 on this pair from ``start``, coarse to fine.

        Eq. 5 measures the nodes' motion from ``reference`` (the last tracked nodes, or over a
        gap their rigid prediction).

        ``region`` ((N,) bool, or None): the nodes an occluder covered, found again on the pair
        it has gone (:meth:`_advance`). The samples they move weigh frame 1 alone
        (:func:`~.stereo_occlusion.first_frame_coefficients`), and the pair is solved from the
        coarser levels too, as after a gap: an expression made under the occluder moved them
        beyond the two levels' reach from where the hold left them (rendered 640x480: a smile's
        mouth corners 10-12 px, a lower lip dropped 8-10 px).

        After dropped pairs or bad frames (more than one frame interval since the last tracked
        pair) the prediction can be off by more than the coarsest level reaches (rendered free
        motion at 10 fps, 2 pairs dropped: the inner nodes' median error 4.7 px at the median
        gap, 7.1 at the upper quartile, up to 14; two levels reach about 5), and the face-model
        term, refitted by one Gauss-Newton step a trial point from its fit at the last pair,
        held the nodes back near that pair's pose. Such a pair is solved from the coarser
        levels of ``gap_pyramid_levels`` too (:meth:`_coarser_levels`), the fit moved to the
        start first.

        A pair on which the head is moving fast (``fast``, :meth:`_moving_fast`) is solved from
        one coarser level too, the face-model term kept on it: an expression's onset is not
        predicted, and at 10 fps the jaw drops beyond the two levels' reach in one interval.
        Left to two levels, the lower lip and chin settled on the neck and were followed there
        (rendered free motion at 10 fps, 100 pairs each: pairs TRACKING more than 3 px RMS off,
        over the nodes both cameras see, 156 -> 29 on seeds 0-7 and 236 -> 185 on seeds 8-15;
        at 15 fps 69 -> 3 on seeds 0-7; the face-model term left out of that level, 37 on seeds
        0-7).

        A gap's coarser levels leave the face-model term out: a level's image terms weigh 4 times
        less per m^2 of node motion than the next finer one's (its pixels are twice as far
        apart), the model term's the same on every level, so on level 3 it weighs 64 times
        more against the images than on level 0, and it held the nodes 10-16 px off (rendered
        10 fps, 3 pairs dropped: level 3 took seed 4's pair 41 from 16.5 to 15.7 px, 8.1
        without the term; with the fit converged at every trial point, 13.0). The first finer
        level moves the fit to where they left the nodes.

        Raises:
            LinAlgError, FaceTrackingError: when a level's solve fails.
        """
        config = self._config
        energy = self._energy(state, reference)
        if region is not None:
            energy.coefficients = first_frame_coefficients(
                energy.coefficients, state.samples, region
            )
        nodes = start
        coarser: tuple[Level, ...] = ()
        coarser_terms = energy
        if state.after_gap or region is not None:
            coarser = self._coarser_levels(state, pyramids, self._gap_levels)
            coarser_terms = replace(energy, prior=None)  # the images alone
        elif fast:
            coarser = self._coarser_levels(state, pyramids, self._fast_levels)
        if state.after_gap:
            _move_fit(energy, nodes)
        solves = _Solves()

        def solve(index: int, start: np.ndarray, first_step_limit: float) -> np.ndarray | None:
            if index >= config.pyramid_levels:
                level, terms = coarser[index - config.pyramid_levels], coarser_terms
            else:
                level, terms = self._level(state, pyramids, index), energy
                if solves.levels and solves.levels[-1][0].index >= config.pyramid_levels:
                    _move_fit(energy, start)  # from a coarser level
            solved = self._solver.solve(terms, level, start, first_step_limit)
            if solved is None:
                return None
            nodes, spent, costs, accepted = solved
            solves.iterations += spent
            solves.history.extend(costs)
            solves.levels.append((level, accepted))
            return nodes

        levels = config.pyramid_levels + len(coarser)
        nodes = coarse_to_fine(levels, 0, config.coarsest_level_px, nodes, solve)
        solves.theta = energy.theta
        return nodes, solves

    def _energy(self, state: _State, reference: np.ndarray) -> PairEnergy:
        """E(n) on this pair from the state: its samples, templates' weights, eq. 5, face model.

        ``reference``: (N, 3) the nodes eq. 5 measures the motion from.
        """
        return PairEnergy(
            samples=state.samples,
            coefficients=state.coefficients,
            huber=Huber.of(state.samples, self._config.huber_k * state.noise),
            regulariser=state.regulariser,
            previous=reference,
            prior=state.prior,
            theta=state.theta,
            deformation=state.deformation,
            first_nodes=state.first_nodes,
            rotation=state.rotation,
        )

    def _advance(
        self, state: _State, pyramids: tuple[ImagePyramid, ImagePyramid], attempt: _Attempt
    ) -> StereoResult:
        """Take this pair's solved nodes into the state: noise, rotation, depths; not templates.

        The templates at the nodes are left to :meth:`prepare`.

        Nodes an occluder covers (their left and right patches disagree, ``occlusion_ratio``)
        are moved with the head's rigid motion instead, keep their templates (their patches' and
        the face texture of their triangles) and add nothing to the frame-1 depths
        (:mod:`.stereo_occlusion`); the result flags those of them with a held neighbour
        (:func:`~.stereo_occlusion.occluder_nodes`).

        On a pair on which the occluder is leaving (:func:`~.stereo_occlusion.occluder_leaving`:
        no node flagged that was not on the last pair, and fewer of them), the nodes flagged
        since the last pair with none (``state.region``) are found again: the pair is solved
        once more from its solution for them (:meth:`_solve_pair`), taken if it passes the loss
        checks and, while nodes are still flagged, flags fewer. Held nodes whose expression
        changed under the occluder were left off the face, some of them disagreeing left and
        right there, so held on (rendered 640x480 onsets under the occluder: a lower lip 8-10 px
        off and held for 50 pairs after it had gone; a smile's corners released 10-11 px off; a
        pucker's far brow end, eye corner and temple flagged for 28 pairs after it, the face's
        far side drifting 25 px off, until the region was all 34 nodes and its solve failed).
        """
        config = self._config
        assert attempt.cover is not None
        covered, agreement, flagged, shown = attempt.cover
        found_again = False
        if state.region.any() and occluder_leaving(flagged, state.result.occluded):
            found = self._attempt(state, pyramids, attempt.nodes, attempt.reference, state.region)
            if not found.problem:
                cover = found.cover
                assert cover is not None
                fewer = np.count_nonzero(cover.flagged) < np.count_nonzero(flagged)
                if not flagged.any() or fewer:
                    attempt, found_again = found, True
                    covered, agreement, flagged, shown = cover
        restart = found_again or not flagged.any()
        state.agreement = agreement
        state.region = flagged if restart else state.region | flagged
        state.shown = shown if restart else state.shown or shown
        nodes, statistics, solves = attempt.nodes, attempt.statistics, attempt.solves
        assert statistics is not None
        if covered.any():
            nodes = held_nodes(state.nodes, nodes, covered, self._alignment_weights)
        state.theta = solves.theta  # the face-model term's fit, moved on by the solve
        state.noise = np.array([max(config.noise_floor, nanmedian(rms)) for rms in statistics.rms])
        state.rotation = self._rotation(state.first_nodes, nodes)
        if state.depths is not None:
            unknown = np.where(covered, np.nan, statistics.rms[0][LEFT])  # no covered evidence
            nodes = self._refine_depths(state, pyramids, nodes, unknown)
        state.before, state.nodes, state.previous_pyramids = state.nodes, nodes, pyramids
        state.span, state.elapsed = state.elapsed, 0
        state.unsampled = covered  # the templates at these nodes: prepare()
        result = self._result(
            nodes,
            state.first_nodes,
            state.rotation,
            statistics,
            solves.iterations,
            tuple(solves.history),
            fit_start=state.result.fit,
            occluded=flagged,
        )
        state.result = result
        return result

    def _cover(self, state: _State, statistics: GroupStatistics, accepted: Point) -> _Cover:
        """What an occluder covers on this pair: the held nodes, the agreement, the flagged.

        Read from the left and right images at level 0's last accepted point of the solve,
        ``accepted`` with its ``statistics`` (:func:`~.stereo_occlusion.stereo_disagreement`,
        ``occlusion_ratio``): a node is covered only if it was seen agreeing on an earlier pair
        (``state.agreement``), beyond its limit (:meth:`~.stereo_occlusion.Agreement.limits`);
        the agreement returned takes this pair in. The covered nodes with a covered neighbour
        are flagged (:func:`~.stereo_occlusion.occluder_nodes`), and ``shown`` says whether one
        of them disagrees as an occluder makes it (:func:`~.stereo_occlusion.occluder_shown`).
        None is covered when the check is off.
        """
        ratio = self._config.occlusion_ratio
        if ratio == 0:
            none = np.zeros(self._topology.num_nodes, dtype=bool)
            return _Cover(none, state.agreement, none, False)
        disagreement = stereo_disagreement(
            state.samples, accepted.sampled, statistics.image_contrast[LEFT]
        )
        covered = covered_nodes(
            disagreement, self._occludable, ratio, self._topology.edges, state.agreement
        )
        agreement = state.agreement.with_pair(disagreement, self._occludable, ratio)
        flagged = occluder_nodes(covered, self._occludable, self._topology.edges)
        return _Cover(covered, agreement, flagged, occluder_shown(flagged, disagreement, ratio))

    def _rotation(self, first_nodes: np.ndarray, nodes: np.ndarray) -> np.ndarray:
        """The head's rotation since frame 1 (weighted Procrustes of the nodes, §3.3)."""
        return rigid_rotation(first_nodes, nodes, self._alignment_weights)

    def _refine_depths(
        self,
        state: _State,
        pyramids: tuple[ImagePyramid, ImagePyramid],
        nodes: np.ndarray,
        left_rms: np.ndarray,
    ) -> np.ndarray:
        """Pool this pair's left-right evidence in the frame-1 depths; return the moved nodes.

        The frame-1 nodes move along their left viewing rays, the tracked nodes along the same
        rays turned by the head rotation; the face-model term, eq. 5 and the frame-1
        templates follow the frame-1 nodes.

        Args:
            state: the state (frame-1 nodes, rotation, depth evidence so far).
            pyramids: this pair's pyramids.
            nodes: (N, 3) the solution for this pair, m.
            left_rms: (N,) RMS residual of each node patch against the previous left image.
        """
        assert state.depths is not None
        config = self._config
        directions = state.depths.rays @ state.rotation.T
        evidence = depth_evidence(
            self._rig,
            PyramidLevel(pyramids[LEFT], 0),
            PyramidLevel(pyramids[RIGHT], 0),
            state.patches,
            nodes,
            directions,
            state.rotation,
            config.huber_k * state.noise[0],
        )
        disparity_per_depth = self._rig.left.focal * self._rig.baseline / nodes[:, 2] ** 2
        step = state.depths.update(
            evidence,
            left_rms**2,
            float(state.noise[0]),
            config.depth_step_px / disparity_per_depth,
            config.depth_gate,
        )
        if not np.any(step):
            return nodes
        shift = step[:, None] * state.depths.rays
        state.first_nodes = state.first_nodes + shift
        if state.prior is not None and state.theta is not None:
            state.prior = state.prior.moved(shift)
            state.theta = state.prior.point(state.theta.theta)
        state.regulariser = state.regulariser.moved(state.first_nodes)
        state.first_templates = templates(
            state.first_pyramids,
            self._projections,
            state.samples,
            state.first_nodes,
            state.samples.level_offsets(np.eye(3), 0),
        )
        nodes = nodes + step[:, None] * directions
        state.rotation = self._rotation(state.first_nodes, nodes)
        return nodes

    def _level(
        self, state: _State, pyramids: tuple[ImagePyramid, ImagePyramid], index: int
    ) -> Level:
        """Level ``index`` of the pair with the state's templates T_k (:func:`_make_level`)."""
        return _make_level(
            index,
            pyramids,
            self._projections[index],
            state.offsets,
            (state.previous_templates[index], state.first_templates[index]),
        )

    def _coarser_levels(
        self, state: _State, pyramids: tuple[ImagePyramid, ImagePyramid], count: int
    ) -> tuple[Level, ...]:
        """The levels below the coarsest, to ``count`` levels in all, made for this pair.

        Their images are this pair's pyramids, the last tracked pair's and frame 1's deepened
        (:meth:`~face_tracking_ros.imaging.ImagePyramid.deepen`: made where they are read),
        their templates sampled where the state's are (frame n - 1 at ``nodes`` as
        :meth:`_advance` samples it, frame 1 at the frame-1 nodes as :meth:`_start` does).
        """
        current, previous, first = pyramids, state.previous_pyramids, state.first_pyramids
        for pyramid in (*current, *previous, *first):
            pyramid.deepen(count)
        samples = state.samples
        field = patch_field(state.deformation, state.nodes, state.first_nodes, state.rotation)
        first_offsets = samples.level_offsets(np.eye(3), 0)
        levels = []
        for index in range(self._config.pyramid_levels, count):
            onto = level_projections((self._rig.left, self._rig.right), index)
            templates_k = (
                level_templates(previous, index, onto, samples, state.nodes, state.offsets, field),
                level_templates(first, index, onto, samples, state.first_nodes, first_offsets),
            )
            levels.append(_make_level(index, current, onto, state.offsets, templates_k))
        return tuple(levels)

    # -- results -----------------------------------------------------------------------------

    def _result(
        self,
        nodes: np.ndarray,
        first_nodes: np.ndarray,
        rotation: np.ndarray,
        statistics: GroupStatistics | None,
        iterations: int = 0,
        history: tuple[float, ...] = (),
        fit_start: NodeFit | None = None,
        occluded: np.ndarray | None = None,
    ) -> StereoResult:
        """A TRACKING result; residuals are zero on the initial pair (it is its own template).

        The model fit starts from ``fit_start`` when given (:meth:`_fit`); ``occluded`` are the
        nodes flagged as under an occluder (none when not given).
        """
        n = nodes.shape[0]
        left_res = np.zeros(n) if statistics is None else statistics.rms[0][LEFT]
        right_res = np.zeros(n) if statistics is None else statistics.rms[0][RIGHT]
        return StereoResult(
            status=TrackStatus.TRACKING,
            nodes_cam=nodes,
            left_px=self._rig.left.project(nodes),
            right_px=self._rig.right.project(nodes),
            left_residuals=left_res,
            right_residuals=right_res,
            mean_residual=float(np.nanmean(np.concatenate([left_res, right_res]))),
            iterations=iterations,
            cost_history=history,
            fit=self._fit(nodes, fit_start),
            first_nodes=first_nodes,
            rotation=rotation,
            occluded=np.zeros(n, dtype=bool) if occluded is None else occluded,
        )

    def _fit(self, nodes: np.ndarray, start: NodeFit | None) -> NodeFit | None:
        """The fit of eq. 1-3 to the nodes, face-edge nodes down-weighted; None without a model.

        With ``fit_node_noise`` it takes the §4.1 prior on alpha (:func:`_fit_precision`).

        Gauss-Newton starts from ``start``, a fit of nearby nodes (the previous pair's), when
        given, instead of Procrustes: 1.90 -> 1.26 ms per fit over a tracked 380-pair sequence
        (on a slow machine), the fits equal to 4e-8.
        """
        if self._fit_problem is None:
            return None
        return self._fit_problem.fit(nodes[None], tolerance=FIT_TOLERANCE, start=start)

    def _lose(self, reason: str) -> StereoResult:
        """Drop the track: LOST until re-acquired (:meth:`_reacquire`) or a new detection."""
        self._status = TrackStatus.LOST
        self._reason = f'track lost: {reason}'
        self._detect = self._detector is not None
        self._state, previous = None, self._state
        assert previous is not None
        self._lost = None if self._detect else previous  # re-acquired (_reacquire)
        last = self._lost_result = previous.result
        return StereoResult(
            status=TrackStatus.LOST,
            nodes_cam=last.nodes_cam,
            left_px=last.left_px,
            right_px=last.right_px,
            left_residuals=last.left_residuals,
            right_residuals=last.right_residuals,
            mean_residual=last.mean_residual,
            reason=self._reason,
            first_nodes=last.first_nodes,
            rotation=last.rotation,
            occluded=last.occluded,
        )

    def _not_tracking(self, status: TrackStatus, reason: str) -> StereoResult:
        """A result without a new estimate: the last valid nodes if any, else NaN.

        The last valid nodes are the track's, or while LOST the lost track's last tracked pair's
        (``face/state`` says LOST with the last valid estimate, as the mono tracker's does).
        """
        n = self._topology.num_nodes
        last = None if self._state is None else self._state.result
        if last is None and status == TrackStatus.LOST:
            last = self._lost_result
        nan = np.full((n, 3), np.nan)
        return StereoResult(
            status=status,
            nodes_cam=nan if last is None else last.nodes_cam,
            left_px=nan[:, :2] if last is None else last.left_px,
            right_px=nan[:, :2] if last is None else last.right_px,
            left_residuals=np.full(n, np.nan),
            right_residuals=np.full(n, np.nan),
            mean_residual=float('nan'),
            reason=reason,
            first_nodes=None if last is None else last.first_nodes,
            rotation=None if last is None else last.rotation,
            occluded=None if last is None else last.occluded,
        )

    def _pyramids(self, left: np.ndarray, right: np.ndarray) -> tuple[ImagePyramid, ImagePyramid]:
        """Pyramids of both images, checked against the rig's image size."""
        expected = (self._rig.left.height, self._rig.left.width)
        for name, image in (('left', left), ('right', right)):
            shape = np.shape(image)
            if shape != expected:
                msg = f'{name} image is {shape}, the rig expects {expected} grey images'
                raise InputError(msg)
        levels = self._config.pyramid_levels
        spare = (None, None) if self._spare is None else self._spare
        # The images are borrowed: step() returns before the caller may change them, and the
        # pyramids it keeps take copies of them first (ImagePyramid.own).
        return (
            ImagePyramid.build(left, levels, reuse=spare[LEFT], borrow=True),
            ImagePyramid.build(
                right, levels, reuse=spare[RIGHT], factor=1.0 / self._right_gain, borrow=True
            ),
        )


def track_sequence(
    tracker: StereoTracker,
    frames: Iterable[tuple[np.ndarray, np.ndarray]],
    init: np.ndarray | Initialisation,
) -> TrackedSequence:
    """Track a whole stereo sequence from given initial node positions, as ``learn`` does.

    (``learn`` runs the stereo_tracker's processor through ``replay``, with the same
    ``retroactive_depths``; this is the tracker alone, for tests on frames in memory.)

    Offline, every frame gets the frame-1 depths refined over the whole sequence
    (:meth:`StereoTracker.with_final_depths`).

    Args:
        tracker: a stereo tracker.
        frames: (left, right) grey image pairs.
        init: the nodes in the first left image (see :meth:`StereoTracker.reset`).

    Returns:
        The (F, N, 3) meshes, (F,) statuses and the per-frame results.
    """
    tracker.reset(init)
    results = tuple(tracker.step(left, right) for left, right in frames)
    n = tracker.topology.num_nodes
    final = tracker.with_final_depths(results)
    meshes = np.array([r.nodes_cam for r in final]).reshape(len(results), n, 3)
    status = np.array([int(r.status) for r in results], dtype=np.int64)
    return TrackedSequence(meshes=meshes, status=status, results=results)


def _make_level(
    index: int,
    pyramids: tuple[ImagePyramid, ImagePyramid],
    projections: np.ndarray,
    offsets: np.ndarray,
    templates_k: tuple[np.ndarray, np.ndarray],
) -> Level:
    """Level ``index`` of the pair from frame n - 1's and frame 1's templates there (2, S) each.

    For each image T_k is frame n - 1 in the same camera, in the other camera, then frame 1 in
    the same and the other camera (:meth:`~.stereo_templates.TemplateSamples.coefficients`
    weighs them). ``offsets`` are the (3, S) level-0 sample offsets.
    """
    previous, first = templates_k
    return Level(
        index=index,
        images=(PyramidLevel(pyramids[LEFT], index), PyramidLevel(pyramids[RIGHT], index)),
        projections=projections,
        offsets=float(1 << index) * offsets,
        templates=np.stack([previous, previous[::-1], first, first[::-1]], axis=1),
    )


def _better(first: _Attempt, second: _Attempt) -> _Attempt:
    """Of two attempts at a pair, the one that passes the loss checks at the lower ratio.

    The ratio is :func:`~.stereo_loss.residual_ratio`; the first attempt on a tie or if neither
    passes.
    """
    if second.problem:
        return first
    if first.problem:
        return second
    assert first.statistics is not None and second.statistics is not None
    better = residual_ratio(second.statistics) < residual_ratio(first.statistics)
    return second if better else first


def _move_fit(energy: PairEnergy, nodes: np.ndarray) -> None:
    """Move the face-model term's fit to ``nodes`` (one Gauss-Newton step), if the term is on."""
    if energy.prior is not None and energy.theta is not None:
        energy.theta = energy.prior.fit(nodes, energy.theta)


def _fit_precision(config: StereoTrackerConfig, model: FaceModel | None) -> np.ndarray | None:
    """``s^2 Sigma_alpha^-1`` of the reported fit's prior on alpha (s: ``fit_node_noise``).

    The §4.1 prior as the mono tracker weighs it (:class:`~.mono_priors.Priors`), with lambda
    ``s^2``. None without a model or with ``fit_node_noise`` 0.
    """
    if model is None or config.fit_node_noise == 0.0:
        return None
    return Priors.of(model, config.fit_node_noise**2).alpha_precision


def _prior_model(config: StereoTrackerConfig, model: FaceModel | None) -> FaceModel | None:
    """The model whose actions the face-model term uses: ``model``, else the packaged one."""
    if model is not None or (config.model_weight_edge == 0 and config.model_weight_inner == 0):
        return model
    try:
        return load_model(default_model_path(config.num_nodes))
    except ModelFileError as error:
        msg = f'the face-model term needs a model: {error} (or set its weights to 0)'
        raise ConfigError(msg) from None
