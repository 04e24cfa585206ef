"""Monocular model-based tracking of pose and expression (seed §3.5, eq. 6, §4.4).

For each new image I_n the tracker estimates the pose (omega, t) of eq. 1 and the expression alpha
of eq. 3, with the identity sigma held fixed, by minimising eq. 6::

    C_n = sum_(i, ROI) (1 - epsilon) (I_n(x_i(n)) - I_(n-1)(x_i(n-1)))^2
                       + epsilon (I_n(x_i(n)) - I_1(x_i(1)))^2

plus the §4.1/§4.4 Gaussian prior on alpha, ``lambda alpha' Sigma_alpha^-1 alpha``.

:class:`MonoTracker` is the state machine that starts a track, follows it, declares it lost and
re-acquires it. What it composes has a module of its own:

- :mod:`.mono_config`: the tunables, each tied to its symbol;
- :mod:`.mono_rois`: the regions of interest, small 3-D surface patches around the nodes that
  foreshorten with the head's rotation and deform with eq. 3;
- :mod:`.mono_projection`: the model posed at an estimate (eq. 1, 3) and projected (eq. 2), its
  nodes' visibility, and an image sampled on the ROIs there;
- :mod:`.mono_templates`: the templates of frames n-1 and 1 sampled on them, and the keyframes;
- :mod:`.mono_priors`: the Gaussian priors on alpha and sigma (§4.1), their precisions;
- :mod:`.mono_solve`: eq. 6's Levenberg-Marquardt solve of one image, coarse to fine;
- :mod:`.mono_loss`: the checks that declare the track lost;
- :mod:`.mono_search`: a frame's face found in an image, for re-acquiring a lost track;
- :mod:`.mono_adjustment`: the bundle adjustment of the first views, which refines frame 1's
  estimate and the skin under the ROIs.

Design, in the seed's terms:

- Face-edge nodes weigh ``edge_weight`` (0.1) in eq. 6: the skin there turns away from the
  camera, so its shading and outline change most with pose and light (measured on another
  sequence with an exact model, initialisation and surface under moving light: pitch error 1.67
  -> 0.36 degrees without them). They still enter the initial fit, which needs their 2-D
  positions most.
- Each frame starts from the constant-velocity prediction of the last two estimates, on level 0
  when that moves the nodes little (``fine_start_px``); a solve from level 0 that fails is made
  again (:meth:`MonoTracker._solve_frame`). One that still fails, or passes doubtfully, is made
  once more from where the last valid frame's inner face correlates best, a failed one's taken
  only if the last valid frame solves back from it (:meth:`MonoTracker._followed_frame`).
- Time is counted in frame intervals: a caller that knows images were dropped (a gap in the
  stamps) passes how many intervals passed (``intervals`` of :meth:`MonoTracker.track`), and
  the motion prediction and the loss check's rotation limit run over that many. More than
  ``pause_intervals`` may be a pause of the stream, which resumes with the next frame: the image
  is solved from the prediction over one interval too, and the motion found is taken as spread
  over the intervals that keep the head's speed (:meth:`MonoTracker._span`).
- The bundle adjustment's stages run after the frame's result is out (:meth:`MonoTracker.track`,
  then :meth:`MonoTracker.adjust`; ``step`` does both), so a live node publishes the pose before
  it spends time on them, and an adjustment takes effect from the frame after its last stage.
- Loss of track gives status LOST with the last valid estimate (:mod:`.mono_loss`).
- Nodes an occluder covers (a hand passing in front of the face) are told from the others by how
  they fit their templates (:func:`.mono_loss.covered_nodes`); a frame where some are newly
  covered is solved again without them (:meth:`MonoTracker._solve_frame`), and while they stay
  covered they weigh nothing in eq. 6, take the templates of the keyframe nearest the pose and
  count as not visible in the loss checks, so the pose follows the visible nodes and the track
  is LOST only when fewer than ``min_visible_fraction`` of the nodes are left. A LOST image
  checks every node again. Measured on 48 rendered runs with an occluder passing (seeds 1-3,
  two subjects, 640x480 and 320x240, 19 and 34 nodes, true and packaged model), with the
  re-acquisition below: TRACKING frames more than 5 px off 86 -> 31, more than 10 px 35 -> 6,
  LOST frames 2666 -> 1477 (1029 with a view's solve confirmed by solving back, below); the same
  runs without the occluder the same to the digit.
- Recovery needs no detector. While LOST, each image is solved as the frame after the last valid
  one (eq. 6 from its estimate and templates); if that fails, as when tracking fails, it is solved
  against the keyframe templates alone from the initial pose translated onto the best normalised
  cross-correlation of frame 1's inner face over the image (:mod:`.mono_search`), and from a fresh
  detection when a detector was given; from the second LOST image on, also against the templates of
  the bundle adjustment's views nearest the last valid rotation, from each view's pose moved to
  where its inner face correlates best near where the face was. The first image after dropped
  ones is solved as a followed frame both from the motion prediction and from where the last valid
  frame's inner face correlates best, and of the solves that pass, the one whose nodes match their
  templates best is taken; no node is newly taken as covered on it (nodes that fit badly after a
  gap say the solve is off, as while LOST), and it is re-acquired only if both fail. The
  keyframe-only solves, every solve while LOST and those of the first image after dropped ones pass
  only at the stricter ``reacquire_residual_ratio``: they can settle a few pixels off. A followed
  solve of the first image after dropped ones that passes only at ``lost_residual_ratio`` is taken
  if solving the last valid frame's image back from it returns to that frame's estimate (a
  forward-backward check); so is a solve from a view that passes only there, if solving the
  view's image back returns to the view's estimate. A solve from a view solves only the levels on
  which the view's face spans ``_VIEW_FACE_PX``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
import functools
import itertools
import math
from typing import NamedTuple

import numpy as np
from numpy.linalg import LinAlgError

from face_tracking_ros.errors import ConfigError, InputError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.distances import rms_length
from face_tracking_ros.geometry.rotation import matrix_to_omega, rodrigues
from face_tracking_ros.imaging import ImagePyramid, check_levels_fit, square_offsets
from face_tracking_ros.imaging.photometric import PhotometricInvariance
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.topology import Group
from face_tracking_ros.tracking.detector import Detector
from face_tracking_ros.tracking.initialisation import Initialisation, fit_model_to_points
from face_tracking_ros.tracking.mono_adjustment import Adjusted, FirstViews, View, ViewAdjuster
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.mono_kernels import Votes, blended_template, row_rms
from face_tracking_ros.tracking.mono_loss import LossChecks, Reference
from face_tracking_ros.tracking.mono_priors import Priors
from face_tracking_ros.tracking.mono_projection import FaceProjection, Sampled
from face_tracking_ros.tracking.mono_rois import Params, Roi, RoiLayout
from face_tracking_ros.tracking.mono_search import FaceView, PendingView
from face_tracking_ros.tracking.mono_solve import Hopeless, MonoSolver, Solution
from face_tracking_ros.tracking.mono_templates import (
    Keyframe,
    OnDemand,
    Templates,
    TemplateSampler,
    keyframe_cosines,
    nearest_keyframe,
)
from face_tracking_ros.tracking.result import TrackResult, TrackStatus

# The level a solve starts on unless the motion prediction is small (fine_start_px).
_START_LEVEL = 1
# How far from where the motion prediction puts it the last valid frame's face is searched after
# dropped images, in x and y, in the larger side of its view (:meth:`MonoTracker._searched`).
_LAST_VIEW_REACH = 0.5
# The turn, either way about the camera's y and x axes, of the last valid rotation in the starts
# a LOST image after dropped images is solved from when the others fail (MonoTracker._turned):
# over a long gap the head turns 20-40 degrees, and eq. 6 from the last valid rotation does not
# get there. On 17 rendered runs with LOST images (docs/performance.md, forty-first session) 10 /
# 15 / 20 degrees: LOST images 316 -> 259 / 254 / 314, none TRACKING more than 3 px off added.
_TURN = math.radians(15.0)
_TURNS = _TURN * np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
# How many of the bundle adjustment's views a LOST image is searched for and solved from
# (:meth:`MonoTracker._viewed`): each is a search and a solve.
_VIEWS_SEARCHED = 2
# How far from where the last valid estimate puts the face a view's face is searched, in x and y,
# in the larger side of its view (:meth:`MonoTracker._viewed`).
_VIEW_REACH = 1.0
# The coarsest level a LOST image's solve from a view solves is the coarsest on which the view's
# inner face spans at least this many px (its larger side; :meth:`MonoTracker._view_face`): on
# the coarsest level of a 320x240 image (the inner face 5-7 px) solves from the true pose settled
# 10-20 px off. The inner face spans 80-115 px at 640x480 (all 4 levels solved), 40-57 at 320x240.
_VIEW_FACE_PX = 10.0
# A solve from a view that passes only at lost_residual_ratio is confirmed by solving the view's
# image back only if at most this fraction of its voting nodes fail at that ratio: on the
# occluder grid, the 16 such solves that re-acquire (0.7-2.7 px off the face) had at most 21 %;
# one 6.7 px off (a variant solving from level 2), dragged by an occluder over 15 of its 34
# nodes, 47 %, and it solved back within 1.4 px.
_VIEW_CONFIRM_FRACTION = 0.25
# How near a view's estimate the solve back to its image must land to confirm a solve from the
# view (level-0 px; :meth:`MonoTracker._returns`): on the occluder grid, the 16 solves that
# re-acquire returned within 0.18-0.87 px (within 0.96 px in the variants tried); two 5.2 and
# 6.7 px off (an occluder over 5 and 15 of their nodes) within 1.27 and 1.43.
_VIEW_RETURN_PX = 1.0
# How near the frame it solves back to (inner nodes' RMS, level-0 px) the solve back from a solve
# that passed only at lost_residual_ratio must land to confirm it (:meth:`MonoTracker._returns`).
_RETURN_PX = 1.5
# How far (level-0 px, in x and in y) from the last valid estimate that solve back starts: it must
# come back, not stay where it started (:meth:`MonoTracker._solved_back`).
_RETURN_START_PX = 3.0
# Frames a node stays covered at most (:meth:`MonoTracker._checked`); its templates are then
# sampled afresh. A node taken as covered on an unoccluded face (an eye's outer corner and brow
# end, on 2 of the protocol's 1000-frame tracks) never fitted its kept template again as the head
# turned on: it stayed covered for the 671-861 frames left. The occluders rendered cover a node
# for at most 28 frames (30 fps).
_COVER_FRAMES = 30
# A solve while the track is LOST is given up before level 0 when, at level 1's solution seen on
# level 0, more than lost_node_fraction of the textured nodes fail at this multiple of
# reacquire_residual_ratio (:meth:`MonoTracker._hopeless`): it would fail the checks.
_HOPELESS_RATIO = 2.0


class _ViewFace(NamedTuple):
    """A view of the bundle adjustment as a LOST image is searched for and solved against.

    Attributes:
        face: its inner face (:class:`.FaceView`).
        centre: (2,) level-0 px, the mean of its inner nodes.
        templates: its templates, every level sampled, at the view's estimate.
        levels: how many of the finest pyramid levels a solve from it solves (``_VIEW_FACE_PX``).
    """

    face: FaceView
    centre: np.ndarray
    templates: Templates
    levels: int


class _Return(NamedTuple):
    """A frame a solve that passes only ``lost_residual_ratio`` is solved back to.

    Attributes:
        pyramid: builds the frame's pyramid (called only when a solve back is made).
        params: the frame's estimate, which the solve back must return to.
        restart_px: the solve back's first step on level 1 beyond which it starts over on the
            coarsest level (:meth:`MonoTracker._solved_back`).
        levels: how many of the finest levels the solves solve (all if None).
        fraction: the largest fraction of the voting nodes that may fail at
            ``lost_residual_ratio`` (``lost_node_fraction`` if None).
        return_px: how near ``params`` the solve back must land (:meth:`MonoTracker._returns`).
    """

    pyramid: Callable[[], ImagePyramid]
    params: Params
    restart_px: float
    levels: int | None = None
    fraction: float | None = None
    return_px: float = _RETURN_PX


class _Checked(NamedTuple):
    """A solve's outcome as the loss checks saw it (:meth:`MonoTracker._checked`).

    Attributes:
        result: the result (TRACKING or LOST with a reason).
        sampled: the templates sampled at its estimate (the next frame's I_(n-1) samples).
        textures: (N,) the texture of the image's ROIs there and of the level-0 template the
            solve was compared with (:meth:`~.mono_loss.LossChecks.textures`), made once for
            every vote on the result (:meth:`MonoTracker._vote`).
        doubtful: whether it passed doubtfully and no solve made again replaced it
            (:meth:`MonoTracker._solve_frame`).
    """

    result: TrackResult
    sampled: Templates
    textures: tuple[np.ndarray, np.ndarray]
    doubtful: bool = False


@dataclass
class _Track:
    """State of a running track; ``keyframes[0]`` holds frame 1 (the seed's I_1).

    ``rois`` holds each level's ROI samples, ``first_views`` the views kept for the bundle
    adjustment of the first views and the adjustment under way. ``view`` is frame 1's inner face
    and ``last_view`` the last valid frame's (:mod:`.mono_search`). ``before`` is the valid
    estimate before ``current`` in the same face frame (None on the track's first frame, moved
    with it by an adjustment): the motion prediction's other point, ``span`` the intervals from
    it to ``current`` (more than 1 when images were dropped or LOST between them). ``missed``
    counts the images since ``current`` that gave no valid estimate (LOST); ``elapsed`` the
    frame intervals from ``current`` to the image being tracked, dropped images included
    (``missed + 1`` in a stream without gaps). ``view_faces`` holds the bundle adjustment's
    views' inner faces and templates by frame, made when a LOST image is first searched for them
    (:meth:`MonoTracker._viewed`), dropped when an adjustment is applied.
    """

    rois: tuple[Roi, ...]
    normals: np.ndarray
    keyframes: list[Keyframe]
    first_views: FirstViews
    previous: Templates
    start: Params
    view: FaceView
    last_view: PendingView
    current: Params
    last_good: TrackResult
    covered_for: np.ndarray
    frames: int = 1
    missed: int = 0
    elapsed: int = 0
    before: Params | None = None
    span: int = 1
    view_faces: dict[int, _ViewFace] = field(default_factory=dict)

    @property
    def lost(self) -> bool:
        """Whether the last image gave no valid estimate (the track is re-acquiring)."""
        return self.missed > 0

    @property
    def covered(self) -> np.ndarray:
        """(N,) bool, the nodes covered at ``current``; none once an image since was LOST.

        A LOST image's solves weigh and check every node again, the covered ones against the
        keyframe templates they took while covered.
        """
        return self.previous.covered & (not self.lost)

    @property
    def bridging(self) -> bool:
        """Whether images were dropped since ``current`` (more intervals than images tracked)."""
        return self.elapsed > self.missed + 1


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
        """Store the collaborators and build the parts that do not change between frames."""
        self._model = model
        self._camera = camera
        self._config = config = config or MonoTrackerConfig()
        self._detector = detector
        check_levels_fit(config.pyramid_levels, camera.width, camera.height)
        self._edge_nodes = model.topology.group_mask(Group.EDGE)
        self._roi_weights = np.where(self._edge_nodes, config.edge_weight, 1.0)
        grid = square_offsets(config.patch_half_size)
        invariance = PhotometricInvariance.of(config.photometric, grid)
        priors = Priors.of(model, config.prior_weight)
        self._face = FaceProjection(model, camera, config.pyramid_levels, config.visibility_cos)
        self._rois = RoiLayout(model, camera.focal, grid, config)
        self._sampler = TemplateSampler(self._face, invariance)
        self._solver = MonoSolver(model, config, self._face, invariance, priors)
        self._loss = LossChecks(config, camera, self._face, grid, model.topology)
        self._adjuster = ViewAdjuster(
            model, config, self._rois, self._face, invariance, self._roi_weights, priors
        )
        # Two pyramids, each rebuilt in place every other frame: the previous frame's stays
        # while the next is tracked, for its templates' coarse levels (TemplateSampler).
        self._buffers: list[ImagePyramid | None] = [None, None]
        self._init: Initialisation | None = None
        self._use_init = False
        self._track: _Track | None = None
        self._followed: tuple[ImagePyramid, TrackResult] | None = None  # awaiting adjust()

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

    def step(self, image: np.ndarray, intervals: int = 1) -> TrackResult:
        """Track the face into a new image, then run its share of the bundle adjustment.

        :meth:`track` followed by :meth:`adjust`, for callers with nothing to do in between.

        Args:
            image: (H, W) grey image (uint8 or float, grey levels 0-255) of the camera's size.
            intervals: frame intervals since the previous image (see :meth:`track`).

        Returns:
            The :class:`TrackResult` of this image.

        Raises:
            InputError: if ``intervals`` is less than 1.
        """
        result = self.track(image, intervals)
        self.adjust()
        return result

    def track(self, image: np.ndarray, intervals: int = 1) -> TrackResult:
        """Track the face into a new image, leaving the bundle adjustment to :meth:`adjust`.

        Call :meth:`adjust` before the next image (once this result is published, say): until
        then the frame is neither kept as a view nor does the adjustment under way advance.

        Never raises on a bad frame: a malformed image, a failed fit or a lost face give a result
        with status LOST (or INITIALIZING while no face has been found) and a ``reason``.

        Args:
            image: (H, W) grey image (uint8 or float, grey levels 0-255) of the camera's size.
            intervals: frame intervals since the previous image: 1 for the next frame of the
                stream, n + 1 after n dropped images. The motion prediction is carried on over
                them, and the loss check allows ``max_rotation_step`` per interval since the
                last valid estimate. Measured on two rendered 300-frame 30-fps sequences (free
                motion, true model) with 2, 3 or 5 images dropped every 8-20 frames: LOST
                frames 0 / 0, 0 / 53, 0 / 1 -> 0 everywhere; rotation MAE with 5 dropped
                2.65 / 3.45 -> 0.54 / 0.31 degrees (0.51 / 0.30 without gaps).

        Returns:
            The :class:`TrackResult` of this image.

        Raises:
            InputError: if ``intervals`` is less than 1 (not a bad frame but a bad call).
        """
        if intervals < 1:
            msg = f'intervals must be >= 1 (frame intervals since the last image), got {intervals}'
            raise InputError(msg)
        self._followed = None
        if self._track is not None:
            self._track.elapsed += intervals
        try:
            pyramid = self._pyramid(image)
            if self._track is None:
                return self._initialise(pyramid)
            return self._follow(pyramid)
        except (InputError, LinAlgError) as error:
            return self._failure(str(error))

    def adjust(self) -> None:
        """Run the last tracked frame's share of the bundle adjustment of the first views.

        Keeps the frame as a view if it shows a new rotation
        (:meth:`~.mono_adjustment.ViewAdjuster.keep_view`) and runs ``bundle.stages_per_frame``
        stages of the adjustment (:meth:`~.mono_adjustment.ViewAdjuster.advance`); nothing after
        a frame that was not followed (initialised, lost or re-acquiring). A frame with nodes an
        occluder covers can be a view, its covered nodes left out (as in eq. 6), but the
        adjustment waits: one applied then would sample the covered nodes' templates anew on the
        occluder (on a rendered run, 19 nodes, the track then slid 34 px off with the occluder,
        TRACKING). Such a view holds the pose the face is next lost at, and a LOST image is
        re-acquired from it (:meth:`_viewed`). Measured on the 48 rendered runs with an occluder
        passing (docs/performance.md, thirty-fifth session): LOST frames 1738 -> 1477, no frame
        TRACKING more than 5 px off added; when covered frames kept no view, two runs (320x240,
        19 nodes) whose last view was 37 frames before the loss stayed LOST for 144 frames where
        a view kept as the occluder came re-acquired the face after 11-12.
        An adjustment that ends here replaces the track's estimate from the next frame on
        (:meth:`_apply_adjustment`). One that fails (numerically, or on input it cannot use) is
        dropped, as a rejected one is: the track goes on as it was, and this never raises, as
        :meth:`track` does not.
        """
        if self._followed is None:
            return
        (pyramid, result), self._followed = self._followed, None
        track = self._track
        try:
            self._adjuster.keep_view(
                track.first_views,
                pyramid,
                track.current,
                track.previous.visibility,
                track.covered,
                track.frames,
                lambda: self._loss.steady(
                    track.current,
                    result.node_residuals,
                    track.previous.levels[0],
                    track.previous.visibility,
                ),
            )
            if track.covered.any():
                return
            adjusted = self._adjuster.advance(track.first_views, pyramid.num_levels)
            if adjusted is not None:
                self._apply_adjustment(pyramid, adjusted, result)
        except (InputError, LinAlgError):
            track.first_views.drop_adjustment()

    # --- initialisation and recovery -----------------------------------------------------------

    def _initialise(self, pyramid: ImagePyramid) -> TrackResult:
        """Fit the model to the init points (or a detection) and start a track on this image."""
        init = self._init if self._use_init else self._detect(pyramid)
        if init is None:
            return self._failure('waiting for an initialisation (init points or a detection)')
        return self._start_track(pyramid, init, *self._fit(init))

    def _start_track(
        self, pyramid: ImagePyramid, init: Initialisation, params: Params | None, error: str
    ) -> TrackResult:
        """Start a new track on this image from ``params``, the model's fit to ``init``.

        The fit gives the track's sigma, refined over its first ``sigma_frames`` images and by
        the bundle adjustment of its first views. A fit that failed (``params`` None, with its
        ``error``) gives a failure instead.
        """
        if params is None:
            return self._failure(f'initialisation failed: {error}')
        rois, normals = self._rois.rois(params, pyramid.num_levels)
        templates = self._sampler.templates(pyramid, params, rois, normals)
        residuals = np.zeros(self._model.num_nodes)
        result = self._result(TrackStatus.TRACKING, params, residuals, 0, (), '')
        first = ImagePyramid(levels=tuple(level.copy() for level in pyramid.levels))
        self._track = _Track(
            rois=rois,
            normals=normals,
            keyframes=[self._sampler.keyframe(params.omega, templates)],
            first_views=FirstViews(
                first,
                [View.of(first.levels[0], templates.visibility, params, 1, templates.covered)],
                init,
                rois[0],
            ),
            previous=templates,
            start=params,
            view=FaceView.of(pyramid, result.nodes_px, ~self._edge_nodes),
            last_view=PendingView(pyramid, result.nodes_px, ~self._edge_nodes),
            current=params,
            last_good=result,
            covered_for=np.zeros(self._model.num_nodes, dtype=int),
        )
        return result

    def _detect(self, pyramid: ImagePyramid) -> Initialisation | None:
        """Run the detector, if any, on the full-resolution grey image."""
        if self._detector is None:
            return None
        return self._detector(np.clip(pyramid.levels[0], 0, 255).astype(np.uint8))

    def _reacquire(self, pyramid: ImagePyramid, reason: str) -> TrackResult:
        """When eq. 6 from the last valid estimate fails: solve against keyframe templates alone.

        Candidate starts are a fresh detection (if a detector was given) and the initial fit
        moved to where the face is found by :meth:`_search`, each compared with its nearest
        keyframe, and on an image after a LOST one the bundle adjustment's views nearest the last
        valid rotation, each moved to where its inner face correlates best near where the face
        was and compared with its own templates (:meth:`_viewed`); the first that passes the loss
        checks at ``reacquire_residual_ratio`` resumes the track, else the image is LOST for
        ``reason``.

        Frame 1's face and templates find a head only near frame 1's pose, while the views, kept
        at new rotations and only when they matched the image closely (:mod:`.mono_adjustment`),
        hold the poses the track has seen: a face lost behind an occluder is found where it comes
        back, not once the head returns near frame 1's pose. Measured with an occluder passing
        over the face on 48 rendered 300-frame runs (2 views a LOST image): LOST frames 2666 ->
        1423, runs LOST for more than 20 frames 25 -> 10, never re-acquired 2 -> 0, no frame
        TRACKING more than 5 px off added; a LOST image costs about twice the CPU (median 11-18 ->
        21-35 ms at 640x480 and 320x240). The image the face is first lost on does not search the
        views: a run that never goes LOST is the same to the bit.

        A solve from a view solves only the levels on which the view's inner face spans
        ``_VIEW_FACE_PX`` (the coarsest of a 320x240 image is left out), and one that fails at
        ``reacquire_residual_ratio`` but passes at ``lost_residual_ratio`` with at most
        ``_VIEW_CONFIRM_FRACTION`` of its voting nodes failing there is taken if solving the
        view's image back from it lands within ``_VIEW_RETURN_PX`` of the view's estimate
        (:meth:`_solve_frame`). A head lost between views, 5-20 degrees from each, was found by
        the nearest view's search 1-6 px off, but the solve from the coarsest level (the inner
        face 5-7 px there) settled 5-20 px off where one from level 1 or 2 converged to 0.7-1 px,
        and there the view's templates, sampled at the view's pose, matched at more than
        ``reacquire_residual_ratio`` (23-27 of 34 nodes failing). Measured on the 48 occluder
        runs (docs/performance.md, thirty-seventh session): LOST frames 1477 -> 1029 (seed 1,
        subject 0, 320x240, 34 nodes: 139 / 140 -> 10 / 10), the 448 frames newly TRACKING
        within 2.7 px, the frames more than 5 px off the same; the runs without the occluder
        the same to the digit.

        When images were dropped since the last valid estimate (:attr:`_Track.bridging`), a
        keyframe-only solve that fails the checks is made again from its solution with eq. 6's
        templates of a followed frame (:meth:`_blended_templates`), at the same ratio.
        After a long gap of fast motion the keyframe-only solve finds the face, but frame 1's
        templates, sampled 15-25 degrees from the head's pose, match it at 0.3-0.45 x the ROI
        texture (median) even where the pose is right (1.2 px off), while the last valid
        frame's, seen just before the gap, match it as a followed frame's do. Measured at 10
        fps with 5 images dropped every 8-20 frames (true model, seeds 1, 2, 6): LOST frames
        62 / 10 / 17 -> 13 / 9 / 14; the sample bag with images 11-15 dropped (packaged model),
        13 -> 0. Without dropped images every image since the last valid one was seen and
        failed: the face left that view (it left the image, was covered, or turned or was lit
        beyond the templates), so its templates are no reference. Made there too, this solve
        took a face coming back into the image (test/hardening) 9.4 px off, and the track
        stayed 9-12 px off, TRACKING.

        A detection that resumes nothing on an image after a LOST one starts a new track
        (:meth:`_start_track`): the face found is another person, or this one beyond what its
        keyframes show (turned far, or lit anew), and a track of its own fits its sigma and
        samples its templates and keyframes. The image the face is first lost on stays LOST, so
        that a non-TRACKING state separates any two tracks (the identity recogniser starts over
        at one). A re-acquired face keeps the motion prediction, as a followed one does: the head
        moved on from the last valid estimate, in one frame or over the LOST images since
        (:meth:`_accept`). Measured on fast motion (every 5th frame of issue 6's sequences, true
        model), a face re-acquired right after a valid estimate: dropping the prediction, seed 1
        was LOST on 160 of 200 frames with rotation errors of 6.8 / 3.1 degrees; keeping it, 49
        frames and 1.1 / 1.1 degrees.
        """
        track = self._track
        ratio = self._config.reacquire_residual_ratio
        detected = self._detect(pyramid)
        fit, error = self._fit(detected) if detected is not None else (None, '')
        # A detection resumes the track with the track's sigma, or starts a new one with its own.
        starts = [fit._replace(sigma=track.current.sigma)] if fit is not None else []
        starts.append(self._search(pyramid))
        keyframed = (
            (start, nearest_keyframe(track.keyframes, start.omega).templates, None)
            for start in starts
        )
        candidates = itertools.chain(keyframed, self._viewed(pyramid) if track.lost else ())
        for start, reference, returned in candidates:
            weights = reference.visibility * self._face.visibility(start, track.normals)
            result, templates, *_ = self._solve_frame(
                pyramid, start, reference.levels, weights, ratio, returned=returned
            )
            if not result.ok and track.bridging:
                found, templates, *_ = self._solve_frame(
                    pyramid, templates.params, *self._blended_templates(), ratio
                )
                result = _summed(result, found)
            if result.ok:
                self._accept(pyramid, result, templates)
                return result
        if detected is not None and track.missed > 0:
            return self._start_track(pyramid, detected, fit, error)
        return self._failure(f'lost: {reason}')

    def _search(self, pyramid: ImagePyramid) -> Params:
        """The initial fit moved onto where frame 1's inner face correlates best with the image."""
        track = self._track
        return self._moved(track.start, track.view.shift(pyramid))

    def _viewed(self, pyramid: ImagePyramid) -> Iterator[tuple[Params, Templates, _Return]]:
        """Starts from the bundle adjustment's views, each with the templates it is solved against.

        ``_VIEWS_SEARCHED`` of the views (frame 1's aside: :meth:`_search`), ranked by the
        nearness of their rotations to the last valid estimate's: the ``_VIEWS_SEARCHED - 1``
        nearest on every LOST image, and one of the rest, the next on each image in turn, so that
        a long loss tries every view at the cost of a few. Each gives the view's estimate moved to
        where its inner face correlates best with the image within ``_VIEW_REACH`` of where the
        last valid estimate puts the face, the view's own templates, and the view as the frame
        a solve from it is confirmed by solving back to (:class:`_Return`; its pyramid built only
        then), with the levels solved (``_VIEW_FACE_PX``).
        """
        track = self._track
        views = track.first_views.views[1:]
        ranked = [views[i] for i in np.argsort(-keyframe_cosines(views, track.current.omega))]
        tried, rest = ranked[: _VIEWS_SEARCHED - 1], ranked[_VIEWS_SEARCHED - 1 :]
        if rest:
            tried.append(rest[(track.missed - 1) % len(rest)])
        here = self._face.nodes(track.current)[1][~self._edge_nodes].mean(axis=0)
        for view in tried:
            viewed = track.view_faces.get(view.frame) or self._view_face(view)
            track.view_faces[view.frame] = viewed
            shift = viewed.face.shift(pyramid, here - viewed.centre, _VIEW_REACH)
            returned = _Return(
                functools.partial(self._view_pyramid, view),
                view.params,
                math.inf,
                viewed.levels,
                _VIEW_CONFIRM_FRACTION,
                _VIEW_RETURN_PX,
            )
            yield self._moved(view.params, shift), viewed.templates, returned

    def _view_pyramid(self, view: View) -> ImagePyramid:
        """The pyramid of a view's image."""
        config = self._config
        return ImagePyramid.build(view.image, config.pyramid_levels, config.smooth_base)

    def _view_face(self, view: View) -> _ViewFace:
        """A view's inner face and templates, sampled on its image's pyramid at its estimate.

        The nodes an occluder covered in the view are left out of both: the crop spans the
        inner nodes not covered (all of them if every one was), and their templates weigh
        nothing (the view's visibility, :meth:`~.mono_adjustment.View.of`, sampled with the
        track's normals as these templates are).
        """
        track = self._track
        pyramid = self._view_pyramid(view)
        nodes_px = self._face.nodes(view.params)[1]
        inner = ~self._edge_nodes
        seen = inner & ~view.covered
        templates = self._sampler.templates(pyramid, view.params, track.rois, track.normals)
        span = np.ptp(nodes_px[inner], axis=0).max()
        levels = int(np.log2(max(span / _VIEW_FACE_PX, 1.0))) + 1
        return _ViewFace(
            FaceView.of(pyramid, nodes_px, seen if seen.any() else inner),
            nodes_px[inner].mean(axis=0),
            templates.sampled()._replace(visibility=view.visibility),
            min(levels, pyramid.num_levels),
        )

    def _searched(self, pyramid: ImagePyramid, start: Params) -> Params:
        """``start`` moved to where the last valid frame's inner face correlates best.

        The search is centred on the inner nodes' mean image move from the last valid estimate to
        ``start`` and reaches ``_LAST_VIEW_REACH`` of the view's size from there: over the whole
        image, a head turned 35 degrees from that view correlated best 100 px from where it was
        (rendered seed 6 at 10 fps, 22 px away). The position is the last valid estimate's
        moved by the shift found (:meth:`_moved`), the rest ``start``'s.
        """
        track = self._track
        inner = ~self._edge_nodes
        moves = self._face.nodes(start)[1][inner] - self._face.nodes(track.current)[1][inner]
        shift = track.last_view.view().shift(pyramid, moves.mean(axis=0), _LAST_VIEW_REACH)
        return start._replace(t=self._moved(track.current, shift).t)

    def _turned(self, searched: Params) -> list[Params]:
        """The starts at new rotations of a LOST image after dropped images.

        ``searched`` (the last valid estimate moved to where its face is found,
        :meth:`_searched`) turned about the face origin by ``_TURN`` either way about the
        camera's y axis (yaw) and x axis (pitch).
        """
        rotation = self._face.rotation(searched)
        return [
            searched._replace(omega=matrix_to_omega(rodrigues(axis)[0] @ rotation))
            for axis in _TURNS
        ]

    def _moved(self, params: Params, shift: np.ndarray) -> Params:
        """``params`` moved parallel to the image plane by a level-0 image ``shift`` (px).

        A pixel of shift is ``t_z / f`` in x and y.
        """
        t = params.t.copy()
        t[:2] += shift * t[2] / np.diag(self._camera.p)[:2]
        return params._replace(t=t)

    def _fit(self, init: Initialisation) -> tuple[Params | None, str]:
        """The model's fit to 2-D node positions (its own sigma), or None and why it failed."""
        try:
            fit = fit_model_to_points(self._model, self._camera, init, self._config.fit)
        except (InputError, ConfigError) as error:
            return None, str(error)
        return Params(fit.omega, fit.t, fit.alpha, fit.sigma), ''

    # --- tracking ------------------------------------------------------------------------------

    def _follow(self, pyramid: ImagePyramid) -> TrackResult:
        """Track one frame (eq. 6) from the last valid estimate; if that fails, re-acquire.

        While LOST this is the solve of the frame after the last valid one, checked at the
        stricter ``reacquire_residual_ratio``. So is the first image after dropped ones
        (:attr:`_Track.bridging`): over the gap the prediction can be several px off, and the
        solve from it settle 7-21 px off the face yet pass at ``lost_residual_ratio``, the track
        then staying that far off, TRACKING. If it fails there, the image is re-acquired
        (:meth:`_reacquire`), or else LOST; it is no longer accepted at ``lost_residual_ratio``
        after all. Measured on rendered free motion (true model, 10 fps, seeds 1-6 with 2 / 3 /
        5 images dropped every 8-20 frames), that took 59 images TRACKING 3.8-21 px off on 3 of
        18 runs (now 0; the re-acquisition from the last valid frame's face finds most of them)
        and kept one run's 9 images from a gap on right (0.8-1.0 px), which the solve back
        now takes (:meth:`_solve_frame`).
        """
        config = self._config
        strict = self._track.lost or self._track.bridging
        ratio = config.reacquire_residual_ratio if strict else config.lost_residual_ratio
        result = self._followed_frame(pyramid, ratio, returned=self._returned_to())
        if result.ok:
            return result
        return self._reacquire(pyramid, result.reason)

    def _followed_frame(
        self, pyramid: ImagePyramid, ratio: float, returned: _Return | None = None
    ) -> TrackResult:
        """Eq. 6's solve from the last valid estimate, or its motion prediction, at ``ratio``.

        ``returned``: the last valid frame (:class:`_Return`), to confirm a solve that fails at
        ``ratio`` but passes at ``lost_residual_ratio`` (:meth:`_solve_frame`).
        A result that passes the loss checks is accepted as a followed frame.

        After dropped images (:attr:`_Track.bridging`) the image is solved from a second start
        too: the first's position moved to where the last valid frame's inner face correlates
        best with the image, near where the first puts it (:meth:`_searched`). Frame 1's face is
        found only within some 25 degrees of its pose, while a head seen just before the gap is
        found as it turned on; the solve from the motion prediction alone can settle 7-21 px off
        after a gap of fast motion. Measured (tried when the prediction's solve failed, with the
        change in :meth:`_follow`) at 10 fps with 5 images dropped every 8-20 frames (true
        model, seeds 1 / 3 / 4 / 6): LOST frames 13 / 66 / 46 / 14 -> 0 / 3 / 16 / 8; at 30 fps
        with 20 dropped (seeds 1 / 2): 75 / 16 -> 36 / 12. That solve too is taken at
        ``lost_residual_ratio`` if it solves back to the last valid frame (:meth:`_solve_frame`;
        there with 20 dropped: LOST 36 / 12 -> 20 / 0).

        A followed image whose solve passed doubtfully and was not mended by the solves made
        again (:meth:`_solve_frame`) is solved from that searched start too (a search, under
        1 ms, and a solve), and that solve is taken if it passes and is not
        doubtful. The track's second image has no motion prediction: it starts from the first
        image's estimate, 17-20 px off on rendered free motion at 5 fps (seeds 9 and 12); there,
        a later image's prediction was 11 px off (seed 4). The solves from them and from the last
        estimate settled 4-7 px off with the expression wrong and 7-9 nodes taken as covered (no
        occluder), and the track stayed off, TRACKING; from the searched start (3.1-7.9 px off)
        they converged 0.6-0.7 px off. Measured on rendered free motion (true model, 1-px
        clicks; docs/performance.md, forty-third session): at 5 fps (16 runs) images TRACKING
        more than 3 px off 103 -> 9; 88 runs at 10 and 30 fps the same to 0.01 px.

        A followed image whose solve failed (not while LOST, nor after dropped images: those have
        their own starts) is solved from that searched start too, and that solve is taken if it
        passes, is not doubtful, and solving the last valid frame (the image before) back from it
        returns to that frame's estimate (:meth:`_returned`); else the image is re-acquired.
        At 5 fps (rendered seed 14) the prediction was 6.8-11.6 px off on four images, its solve
        failed, and so did the re-acquisition from frame 1's face: LOST, each found on the next
        image. From the searched start (1.4-2.4 px off) the solves converged 0.8 px off and solved
        back within 0.04-0.12 px. The solve back is what tells a wrong face: on a face coming back
        into the image (test/hardening) the image after its re-acquisition, the prediction 8.4 px
        off, took from the searched start (0.7 px off) a solve 5.8 px off that passed even at
        ``reacquire_residual_ratio`` (36 % of its voting nodes failing there), and the track then
        drifted 11.7 px off, TRACKING; its solve back lands 4.0 px away.

        Of the solves that pass the checks, the one whose nodes match their templates best is taken
        (:meth:`_failing_fraction`; the first on a tie). Over a gap of fast motion the prediction
        can be 15-25 px off, and its solve settle in a minimum that passes with the lower face
        wrong: on rendered seed 3 at 10 fps with images 19-21 dropped, the jaw and lips 13-15 px
        off (the nodes 6.3 px RMS), 15 of 31 nodes failing at ``reacquire_residual_ratio``, where
        the solve from the search, 2.8 px off, found the face 1.1 px off with 5 failing. Of the 159
        first images after a gap on 20 rendered runs (true model; 10 fps, seeds 1-6 with 2 / 3 / 5
        images dropped every 8-20 frames; 30 fps, seeds 1-2 with 20 dropped every 10-18), both
        solves passed on 102, 100 of them with as many nodes failing (the same minimum, the
        prediction's taken); on the other two the one with fewer failing was right (1.1 px) and the
        other wrong (3.4 and 6.3 px).

        While the track is LOST after dropped images, when those solves fail, the image is solved
        from the search's start turned ``_TURN`` (15 degrees) either way in yaw and in pitch
        (:meth:`_turned`), the one with fewest nodes failing taken. Over a gap of 0.67 s the head
        can turn 20-40 degrees beyond every pose the track has seen; every start keeps the last
        valid rotation, and eq. 6 from it settled 13-14 px and 38-45 degrees off on rendered seed
        1 at 30 fps with the face found within 5 px. Measured on rendered free motion
        (true model, 30 fps with 20 images dropped every 10-18 kept, 10 fps with 3 or 5 every 8-20;
        25 runs with LOST images): LOST images 356 -> 284 (held-out seed 10 at 30 fps 66 -> 6,
        found at image 36 turned 15 degrees in pitch; seed 23 11 -> 3), none TRACKING more than 3
        px off added; a stream without gaps, or never LOST after one, is the same to the bit.
        The four solves raise such a LOST image's CPU from a median 37 to 65 ms (30 fps, 640x480).

        After a pause of the stream (:meth:`_paused`) the image is solved from the prediction over
        one interval too (:meth:`_stalled`): a stream that stalled resumes with the next frame,
        and the prediction over the whole pause can put the start 65 px off, the search from it
        keeping its rotation. On rendered seed 4 at 30 fps, image 10 told 31 intervals, the
        search's solve settled 8.4 px off, failed ``reacquire_residual_ratio``, and was taken at
        ``lost_residual_ratio`` because solving image 9 back from it returned within 1.2 px (the
        head had moved one frame); the solve from one interval's prediction passes at 0.7 px with
        9 % of its nodes failing against 52 %.
        """
        track, config = self._track, self._config
        blended, weights = self._blended_templates()
        free_sigma = track.frames <= config.sigma_frames
        start, first_level = track.current, _START_LEVEL
        predicted = config.predict_motion and track.before is not None and not track.lost
        if predicted:
            ahead = track.elapsed / track.span
            start = _predicted(track.current, track.before, ahead, self._face.rotation)
            first_level = self._first_level(track.current, start)
        starts = [(start, first_level)]
        # Where the last valid frame's face is found: after dropped images, and below for a
        # solve that failed or stands doubtful.
        searched = None
        if track.bridging:
            searched = self._searched(pyramid, start)
            starts.append((searched, self._first_level(track.current, searched)))
        if predicted and self._paused():
            stalled = self._stalled()
            starts.append((stalled, self._first_level(track.current, stalled)))

        def solved(begins: list[tuple[Params, int]], still: Params | None) -> list[_Checked]:
            """Each start's solve; ``still`` for its retries (:meth:`_solve_frame`)."""
            return [
                self._solve_frame(
                    pyramid, begin, blended, weights, ratio, free_sigma, level, still, returned
                )
                for begin, level in begins
            ]

        outcomes = solved(starts, track.current)
        first = outcomes[0]
        failed = not (first.result.ok or track.lost or track.bridging)
        if first.doubtful or failed:
            searched = self._searched(pyramid, start)
            again = solved([(searched, self._first_level(track.current, searched))], None)[0]
            if again.result.ok and not again.doubtful:
                found, returns = _summed(first.result, again.result), True
                if failed:  # taken only if the last valid frame solves back from it
                    returns, found = self._returned(self._last_frame(), again.sampled, found)
                if returns:
                    outcomes = [again._replace(result=found)]
        passed = [found for found in outcomes if found.result.ok]
        if not passed and track.lost and searched is not None:
            turned = [
                (begin, self._first_level(track.current, begin))
                for begin in self._turned(searched)
            ]
            passed = [found for found in solved(turned, track.current) if found.result.ok]
        if not passed:
            return outcomes[0].result
        best = passed[0]  # most images: one solve, which needs no vote to rank (min votes on it)
        if len(passed) > 1:
            best = min(passed, key=lambda found: self._failing_fraction(found, ratio))
        result, templates, *_ = best
        self._accept(pyramid, result, templates)
        self._followed = (pyramid, result)
        return result

    def _failing_fraction(self, checked: _Checked, ratio: float) -> float:
        """The fraction of a result's voting nodes that fail the loss checks' vote at ``ratio``.

        0 when no node votes.
        """
        votes = self._vote(checked, ratio)
        return votes.failing / votes.voting if votes.voting else 0.0

    def _vote(self, checked: _Checked, ratio: float) -> Votes:
        """The loss checks' vote (:meth:`~.mono_loss.LossChecks.vote`) on a result at ``ratio``.

        The nodes of its templates not covered vote, with the textures its check made.
        """
        sampled = checked.sampled
        return self._loss.vote(
            sampled.params, checked.result.node_residuals, checked.textures, sampled.seen, ratio
        )

    def _returned(
        self, returned: _Return, sampled: Templates, result: TrackResult
    ) -> tuple[bool, TrackResult]:
        """Whether ``returned``'s frame, solved back from ``sampled``, returns; ``result`` counted.

        The solve back (:meth:`_solved_back`) confirms a later solve whose templates were
        sampled at ``sampled`` when it returns to that frame's estimate (:meth:`_returns`). Its
        iterations and costs are added to ``result``'s, the solves made for the image so far.
        """
        back = self._solved_back(returned, sampled)
        counted = replace(
            result,
            iterations=result.iterations + back.iterations,
            cost_history=result.cost_history + back.costs,
        )
        return self._returns(back.params, returned), counted

    def _returned_to(self) -> _Return | None:
        """The last valid frame for the first image after dropped images, else None."""
        track = self._track
        if not track.bridging or track.lost:
            return None
        return self._last_frame()

    def _last_frame(self) -> _Return:
        """The last valid frame as a solve back's, when it is the image before (none LOST since).

        Its pyramid is then the older of the two kept (:meth:`_pyramid`); it is solved back to
        from level 1, the coarsest on demand.
        """
        last = self._buffers[0]
        return _Return(lambda: last, self._track.current, self._config.coarsest_level_px)

    def _blended_templates(self) -> tuple[OnDemand, np.ndarray]:
        """Eq. 6's templates of a followed frame and the node weights they are solved with.

        Each level is ``(1 - epsilon) I_(n-1) + epsilon I_1``: the last valid frame's templates
        blended with those of the keyframe nearest its pose (frame 1's by default), epsilon
        scaled by the keyframe's node visibility; the weights are the node visibility at the last
        valid estimate, where its templates were sampled.
        """
        track = self._track
        keyframe = nearest_keyframe(track.keyframes, track.current.omega).templates
        epsilon = self._config.epsilon * keyframe.visibility
        previous = track.previous.levels
        blended = OnDemand(
            len(previous),
            lambda level: blended_template(previous[level], keyframe.levels[level], epsilon),
        )
        return blended, np.where(track.covered, 0.0, track.previous.visibility)

    def _first_level(self, current: Params, predicted: Params) -> int:
        """The level a predicted frame's solve starts on: 0 for a small predicted motion."""
        at_current = self._face.nodes(current)[1]
        motion = self._face.nodes(predicted)[1] - at_current
        small = np.abs(motion).max(initial=0.0) < self._config.fine_start_px
        return 0 if small else _START_LEVEL

    def _accept(self, pyramid: ImagePyramid, result: TrackResult, templates: Templates) -> None:
        """Make a successful frame the previous frame of the next one, and maybe a keyframe.

        The covered nodes take the nearest keyframe's templates (:meth:`Templates.kept`). Its
        inner face in ``pyramid`` becomes the track's ``last_view``. The last valid
        estimate becomes ``before`` (the motion prediction's other point) however this frame was
        found (followed or re-acquired, after LOST images too), the frame intervals since it its
        ``span`` (after a pause, those that keep the head's speed: :meth:`_span`): after a
        re-acquisition the next image is predicted by the motion averaged over the LOST images.
        Solved from the re-acquired estimate instead, the next image of a head
        moving 8 px a frame (rendered seed 7, 10 fps, image 30) settled 8.1 px off, passed at
        ``lost_residual_ratio``, and the track stayed 8.1-9.1 px off, TRACKING, for 5 images.
        """
        track = self._track
        track.span = self._span(templates.params)
        track.before = track.current
        if templates.covered.any():  # looked up only then: most frames cover nothing
            templates = templates.kept(nearest_keyframe(track.keyframes, result.omega).templates)
        config = self._config
        if len(track.keyframes) < config.max_keyframes:
            # trace(R) = 1 + 2 cos(angle)
            nearest = np.max(keyframe_cosines(track.keyframes, result.omega))
            if nearest < 1.0 + 2.0 * np.cos(config.keyframe_spacing):
                track.keyframes.append(self._sampler.keyframe(result.omega, templates))
        track.covered_for = np.where(templates.covered, track.covered_for * track.covered + 1, 0)
        track.current = templates.params  # the result's own, whose pose is kept
        track.previous = templates
        track.last_view = PendingView(pyramid, result.nodes_px, ~self._edge_nodes)
        track.last_good = result
        track.frames += 1
        track.missed = 0
        track.elapsed = 0

    def _paused(self) -> bool:
        """Whether the stream paused since the last valid estimate (``pause_intervals``).

        The image follows that estimate's (no image LOST since) after more than
        ``pause_intervals`` frame intervals.
        """
        track = self._track
        return not track.lost and track.elapsed > self._config.pause_intervals

    def _stalled(self) -> Params:
        """The motion prediction over one frame interval (the next frame of a stalled stream)."""
        track = self._track
        return _predicted(track.current, track.before, 1 / track.span, self._face.rotation)

    def _span(self, params: Params) -> int:
        """The frame intervals the motion from the last valid estimate to ``params`` spans.

        Those since it (``elapsed``), except after a pause (:meth:`_paused`): then the number k
        in 1 to ``elapsed`` whose motion per interval, the inner nodes' image motion to
        ``params`` over k, is nearest (least squares) that of one interval before it
        (:meth:`_stalled`): 1 for a head that moved one frame while the stream stalled, so that
        it is predicted to move on at that speed, not at that motion spread over the pause;
        ``elapsed`` for one that moved on at its speed, or turned back.
        """
        track = self._track
        if track.before is None or not self._paused():
            return track.elapsed
        inner = ~self._edge_nodes
        at = self._face.nodes(track.current)[1][inner]
        step = self._face.nodes(self._stalled())[1][inner] - at
        moved = self._face.nodes(params)[1][inner] - at
        along = float(np.sum(moved * step))
        if along <= 0.0:
            return track.elapsed
        return int(np.clip(round(float(np.sum(moved**2)) / along), 1, track.elapsed))

    def _solve_frame(
        self,
        pyramid: ImagePyramid,
        start: Params,
        templates: Sequence[np.ndarray],
        node_weights: np.ndarray,
        residual_ratio: float,
        free_sigma: bool = False,
        first_level: int = _START_LEVEL,
        still: Params | None = None,
        returned: _Return | None = None,
    ) -> _Checked:
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

        A solve checked at the ordinary ``lost_residual_ratio`` that passes doubtfully
        (:meth:`_doubtful`) is made again: from ``still`` on level 1 (the coarsest on demand:
        the head may have moved far; not when ``start`` is ``still``, the same solve) and, unless
        it solved the coarsest level, from ``start`` on the coarsest. The first of those that
        passes and is not doubtful is taken, else the first solve stands, flagged
        (``_Checked.doubtful``; :meth:`_followed_frame` then tries one more start). A head
        moving 7-14 px a frame (rendered free motion at 5 fps, true model) left solves from the
        prediction settled 4-7 px off in a local minimum of eq. 6 that passed, and the track
        followed its own templates sampled there: TRACKING images more than 3 px off on 16 such
        runs 252 -> 103; 88 runs at 10 and 30 fps are unchanged
        (docs/performance.md, forty-first session).

        A solve whose outcome has nodes newly covered by an occluder (:meth:`_checked`) is made
        again from the same start without them, and checked with them covered: the first solve
        fits them to the occluder in part, which drags the face and raises the others' residuals.

        While the track is LOST, a solve whose level-1 solution cannot pass the checks is given
        up before level 0 (:meth:`_hopeless`).

        ``returned`` is an earlier frame (:class:`_Return`): the last valid one for the first image
        after dropped images, or the view a LOST image is solved from. A solve that fails the
        checks at ``residual_ratio`` but passes them at ``lost_residual_ratio`` (with at most
        ``returned.fraction`` of its voting nodes failing there, :meth:`_confirmable`) is taken
        if solving that frame back from it returns to its estimate (:meth:`_returns`). Every
        solve made solves only the finest ``returned.levels`` levels.

        Returns:
            The frame's result (TRACKING or LOST with a reason; its iterations those of every
            solve made), the templates sampled at its solution (the next frame's I_(n-1)
            samples) and its ROIs' textures (:class:`_Checked`).
        """
        node_weights = node_weights * self._roi_weights
        track = self._track
        rois = track.rois
        hopeless = self._hopeless(templates[0]) if track.lost and not track.bridging else None
        levels = None if returned is None else returned.levels

        def attempt(begin: Params, level: int, restart_px: float) -> tuple[Solution, _Checked]:
            solution = self._solver.solve(
                pyramid,
                begin,
                templates,
                node_weights,
                rois,
                free_sigma,
                level,
                restart_px,
                hopeless,
                levels,
            )
            checked = self._checked(solution, pyramid, templates[0], residual_ratio)
            weights = np.where(checked.sampled.covered, 0.0, node_weights)
            if not (weights < node_weights).any():
                return solution, checked
            # Nodes newly covered: solved again without them, from the same start, and every
            # node covered before checked again there (the first solve's drag can uncover some).
            again = self._solver.solve(
                pyramid,
                begin,
                templates,
                weights,
                rois,
                free_sigma,
                level,
                restart_px,
                levels=levels,
            )
            found = self._checked(
                again,
                pyramid,
                templates[0],
                residual_ratio,
                checked.sampled.covered | track.covered,
            )
            return again, found._replace(result=_summed(checked.result, found.result))

        solution, checked = attempt(start, first_level, self._config.coarsest_level_px)
        total = checked.result
        strict = residual_ratio <= self._config.reacquire_residual_ratio
        doubtful = checked.result.ok and not strict and self._doubtful(checked)
        if doubtful or not (solution.coarsest_solved or checked.result.ok or first_level > 0):
            retries = []
            if not solution.coarsest_solved:
                retries.append((start, pyramid.num_levels - 1, self._config.coarsest_level_px))
            if still is not None and still is not start and pyramid.num_levels > 1:
                # Level 1 solved whatever its first step, but for a doubtful solve's retry: the
                # coarsest on demand (it may have moved far from the last estimate).
                restart_px = self._config.coarsest_level_px if doubtful else math.inf
                retries.insert(0, (still, 1, restart_px))
            for begin, level, restart_px in retries:
                retried, rechecked = attempt(begin, level, restart_px)
                total = _summed(total, rechecked.result)
                if doubtful:  # taken only if it passes and matches closely enough
                    if rechecked.result.ok and not self._doubtful(rechecked):
                        solution, checked, doubtful = retried, rechecked, False
                        break
                    continue
                solution, checked = retried, rechecked  # the last made, as the first failed
                if checked.result.ok:
                    break
            total = replace(
                checked.result, iterations=total.iterations, cost_history=total.cost_history
            )
        if checked.result.ok or returned is None:
            return checked._replace(result=total, doubtful=doubtful)
        lenient = self._checked(solution, pyramid, templates[0], self._config.lost_residual_ratio)
        if not (lenient.result.ok and self._confirmable(lenient, returned)):
            return lenient._replace(result=total)
        returns, counted = self._returned(returned, lenient.sampled, total)
        if returns:
            counted = replace(
                lenient.result, iterations=counted.iterations, cost_history=counted.cost_history
            )
        return lenient._replace(result=counted)

    def _doubtful(self, checked: _Checked) -> bool:
        """Whether a result that passed the checks at ``lost_residual_ratio`` may be off the face.

        It may when nodes are newly taken as covered on it, or when more than
        ``lost_node_fraction`` of its voting nodes fit worse than ``reacquire_residual_ratio``
        (a resumed track's ratio). Of the followed frames of 88 rendered runs at
        10 and 30 fps (free motion, true model), none had more than 45 % of the voting nodes
        failing at that ratio; solves that settled 4-7 px off at 5 fps had 91-100 %, or the
        expression wrong and 7-12 nodes taken as covered, the rest passing (no occluder).
        A covered node is no vote: passed without them, such a solve looks like a face with a
        hand over its mouth; an occluder that is there covers the nodes of the solves made
        again too, and the first stands.
        """
        if (checked.sampled.covered & ~self._track.covered).any():
            return True
        votes = self._vote(checked, self._config.reacquire_residual_ratio)
        return self._loss.outvoted(votes)

    def _hopeless(self, template: np.ndarray) -> Hopeless:
        """Whether a solve while LOST is given up before level 0 (:data:`.mono_solve.Hopeless`).

        It is when the vote of the loss checks, at level 1's solution seen on level 0 against
        ``template`` (level 0's), fails at ``_HOPELESS_RATIO`` times ``reacquire_residual_ratio``.
        The result is then checked as any other's (:meth:`_checked`) and fails: a node failing
        at the larger ratio fails at the smaller. Most solves of a LOST image settle far off the
        face (the face is still covered, or elsewhere), and level 0, a quarter of such a solve's
        iterations, is not seen to bring one that far back. Not on the image the face is first
        lost on, nor on the first after dropped images: there a failed solve may still have its
        newly covered nodes left out, or be carried on (:meth:`_reacquire`).

        Measured on the 48 rendered runs with an occluder passing (seeds 1-3, two subjects,
        640x480 and 320x240, 19 and 34 nodes, true and packaged model; docs/performance.md,
        thirty-sixth session), over the solves made while LOST: the 48 that re-acquired the face
        had at most 36 % of their voting nodes failing at that ratio, and 96 % of the 5881 that
        failed more than half. Every frame's status and nodes are the same as without it; the
        CPU of a LOST image (34 nodes, true model), median / p90, 21.3 / 24.7 -> 16.5 / 19.4 ms.
        """
        track = self._track
        ratio = _HOPELESS_RATIO * self._config.reacquire_residual_ratio

        def hopeless(params: Params, sampled: Sampled, residuals: np.ndarray) -> bool:
            textures = self._loss.textures(sampled.samples, template)
            visibility = self._face.visibility(params, track.normals)
            votes = self._loss.vote(params, row_rms(residuals), textures, visibility, ratio)
            return self._loss.outvoted(votes)

        return hopeless

    def _confirmable(self, checked: _Checked, returned: _Return) -> bool:
        """Whether a result passing ``lost_residual_ratio`` may be confirmed by a solve back.

        It may when at most ``returned.fraction`` of its voting nodes fail at that ratio (always
        when that is None: the ordinary check's vote, which it passed).
        """
        if returned.fraction is None:
            return True
        votes = self._vote(checked, self._config.lost_residual_ratio)
        return not self._loss.outvoted(votes, returned.fraction)

    def _solved_back(self, returned: _Return, templates: Templates) -> Solution:
        """Eq. 6 solved on an earlier frame's pyramid against a later image's templates.

        The earlier frame is the last valid one after dropped images (:meth:`_returned_to`) or
        after a followed solve that failed (:meth:`_followed_frame`), or the view a LOST image
        was solved from (:meth:`_viewed`). The solve starts
        ``_RETURN_START_PX`` from that frame's estimate in x and y (moved parallel to the image
        plane) on level 1, started over on the coarsest level when its first step exceeds
        ``returned.restart_px``, with ``templates``
        (sampled in the later image at its solution) as I_(n-1) alone and their visibility as
        the node weights: a forward-backward check. Templates that match nothing near that
        estimate give the solve no gradient, and started on it, it stayed there: the frame-1
        search's solves after a gap, 9-12 px off the true nodes and passing at
        ``lost_residual_ratio``, returned within 0.3-1.2 px when started on the estimate, and
        landed 9.1 px away (the one that got that far) when started 3 px off in x and y.
        The solve back to a view takes level 1 whatever its first step (it starts 3 px off by
        construction): started over on the coarsest level when that step was large, the solves
        back from a head 20 degrees beyond every view (seed 1, subject 3, 640x480, 34 nodes),
        0.7-0.8 px off the face, landed 7.7-13.7 px away, whose level 1 alone returns within
        0.6 px: LOST 74 -> 24 frames. The solve back after dropped images keeps the restart:
        without it, 18 rendered 10 fps runs with 2-5 images dropped every 8-20 frames (seeds 1-6,
        true model) took one wrong solve on seed 5 (31 images TRACKING more than 3 px off).
        """
        offset = np.full(2, _RETURN_START_PX)
        return self._solver.solve(
            returned.pyramid(),
            self._moved(returned.params, offset),
            templates.levels,
            templates.seen * self._roi_weights,
            self._track.rois,
            False,
            _START_LEVEL,
            returned.restart_px,
            levels=returned.levels,
        )

    def _returns(self, back: Params, returned: _Return) -> bool:
        """Whether the solve back (:meth:`_solved_back`) returned to the earlier frame's estimate.

        It does when the inner nodes (off the face edge) are within ``returned.return_px`` RMS
        (``_RETURN_PX`` for the last valid frame, ``_VIEW_RETURN_PX`` for a view) of where that
        estimate puts them. A later solve that settled off the face carries its
        offset into its templates, so the solve back lands off by about as much. Measured on
        rendered free motion (true model; 10 fps, seeds 1-6 with 2 / 3 / 5 images dropped every
        8-20 frames; 30 fps, seeds 1-2 with 20 dropped every 10-18), the solves of a first image
        after a gap that failed at ``reacquire_residual_ratio`` and passed at
        ``lost_residual_ratio``: the four 0.8-2.1 px off the true nodes returned within 0.26-0.81
        px, the ten 2.9-12 px off landed 2.2-11 px away. LOST images over the 20 runs 115 -> 76
        (seed 6 with 3 dropped at 10 fps 8 -> 0, seed 3 with 5 dropped 3 -> 0, 30 fps 36 / 12
        -> 20 / 0), none TRACKING more than 3 px off before or after.
        """
        inner = ~self._edge_nodes
        moved = self._face.nodes(back)[1][inner] - self._face.nodes(returned.params)[1][inner]
        return rms_length(moved) <= returned.return_px

    def _checked(
        self,
        solution: Solution,
        pyramid: ImagePyramid,
        template: np.ndarray,
        residual_ratio: float,
        covered: np.ndarray | None = None,
    ) -> _Checked:
        """The result of a solution that passes the loss checks (TRACKING) or not (LOST).

        ``template`` is the level-0 template the solution was compared with; ``covered`` the
        nodes taken as covered before it (the last valid frame's by default), which stay covered
        until they fit their templates again (:func:`~.mono_loss.covered_nodes`). A solve while
        the track is LOST (re-acquiring) covers no node: its start is not the last frame's, so
        nodes that fit badly there say the pose is off, not that an occluder came. (Measured on a
        rendered run re-acquired after an occluder had passed: 16 of 34 nodes taken as covered on
        the re-acquired image held the track 5-6 px off for 18 frames.) Nor is a node newly
        covered on the first image after dropped images (:attr:`_Track.bridging`), for the same
        reason: its solve starts from a prediction over the gap or a search, and a node covered
        before the gap stays covered only while it still fits its kept template badly. On 20
        rendered runs with 2-20 images dropped every 8-20 frames (true model, no occluder),
        solves that settled with the jaw and lips 13-24 px off took those 8-15 nodes as covered
        and passed without them: 62 images TRACKING 5.1-10.2 px off on two runs (seed 4 at 10 fps
        with 5 dropped, seed 2 at 30 fps with 20), none since; LOST images 92 -> 82.

        Returns:
            The result, the templates sampled at its estimate and the textures of their level-0
            samples and of ``template`` (:class:`_Checked`).
        """
        track = self._track
        params = solution.params
        sampled = self._sampler.templates(
            pyramid, params, track.rois, track.normals, solution.sampled
        )
        node_rms = row_rms(solution.residuals)
        textures = self._loss.textures(sampled.levels[0], template)
        before = track.covered if covered is None else covered
        expired = track.covered & (track.covered_for >= _COVER_FRAMES)
        cover = np.zeros_like(before)
        if not track.lost:
            cover = self._loss.covered(
                params, node_rms, textures[0], sampled.visibility, before, expired
            )
        if track.bridging:
            cover &= before
        sampled = sampled._replace(covered=cover)
        reason = self._loss.reason(
            params,
            node_rms,
            sampled.levels[0],
            textures,
            sampled.seen,
            solution.condition,
            residual_ratio,
            Reference(track.current, track.elapsed, track.keyframes),
        )
        status = TrackStatus.LOST if reason else TrackStatus.TRACKING
        result = self._result(
            status, params, node_rms, solution.iterations, solution.costs, reason, sampled.covered
        )
        return _Checked(result, sampled, textures)

    # --- bundle adjustment of the first views ---------------------------------------------------

    def _apply_adjustment(
        self, pyramid: ImagePyramid, adjusted: Adjusted, result: TrackResult
    ) -> None:
        """Restart the track's state from an adjustment: the next frame starts from its estimate.

        ``result`` is this frame's (its residuals go into the last valid result, which a LOST
        frame reports). The current estimate, the one before it and the views are carried into
        the adjusted scene (:meth:`~.mono_adjustment.ViewAdjuster.carry`); frame 1's templates
        are sampled anew on the adjusted ROIs, and this frame's. The next frame is solved from
        the motion prediction as any followed frame. Solved from the adjusted estimate with no
        motion instead, a head moving about 8 px a frame (rendered seed 7, 10 fps, true model)
        settled 7.9 px off on the image after the adjustment at image 27, LOST with 19 of 34
        nodes failing; with the prediction all of images 0-45 are TRACKING within 0.7 px.
        """
        track, estimate = self._track, adjusted.estimate
        normals = self._rois.normals(estimate.sigma)
        views, current, before = self._adjuster.carry(
            track.first_views, estimate, track.current, track.frames, normals, track.before
        )
        start = views[0].params
        # Everything is made before the track changes: a failure (InputError) leaves it as it was.
        first = self._sampler.templates(track.first_views.first, start, adjusted.rois, normals)
        keyframe = self._sampler.keyframe(start.omega, first)
        previous = self._sampler.templates(pyramid, current, adjusted.rois, normals)
        track.rois, track.normals, track.keyframes = adjusted.rois, normals, [keyframe]
        track.view_faces = {}
        track.first_views.rebase(views, adjusted)
        track.start, track.previous, track.current, track.before = start, previous, current, before
        track.last_good = self._result(
            TrackStatus.TRACKING,
            current,
            result.node_residuals,
            result.iterations,
            result.cost_history,
            '',
        )

    # --- results --------------------------------------------------------------------------------

    def _result(
        self,
        status: TrackStatus,
        params: Params,
        node_residuals: np.ndarray,
        iterations: int,
        costs: tuple[float, ...],
        reason: str,
        occluded: np.ndarray | None = None,
    ) -> TrackResult:
        """A TrackResult for ``params``; ``occluded``, the nodes covered (none when not given)."""
        nodes_cam, nodes_px = self._face.nodes(params)
        return TrackResult(
            status=status,
            omega=params.omega.copy(),
            t=params.t.copy(),
            alpha=params.alpha.copy(),
            sigma=params.sigma.copy(),
            nodes_cam=nodes_cam.copy(),
            nodes_px=nodes_px.copy(),
            node_residuals=node_residuals,
            mean_residual=float(np.mean(node_residuals)),
            iterations=iterations,
            cost_history=costs,
            reason=reason,
            occluded=np.zeros(len(node_residuals), dtype=bool) if occluded is None else occluded,
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
        templates (if they are still the previous ones: a LOST image since) are sampled first,
        and the track's last valid view cropped.
        """
        image = np.asarray(image)
        expected = (self._camera.height, self._camera.width)
        if image.shape != expected:
            msg = f'image has shape {image.shape}; the camera expects a grey {expected} image'
            raise InputError(msg)
        older, newer = self._buffers
        track = self._track
        if track is not None and track.previous.reads(older):
            track.previous = track.previous.sampled()  # before older is rebuilt
        if track is not None and track.last_view.reads(older):
            track.last_view.view()  # cropped before older is rebuilt
        pyramid = ImagePyramid.build(
            image, self._config.pyramid_levels, self._config.smooth_base, reuse=older
        )
        self._buffers = [newer, pyramid]
        return pyramid


def _summed(earlier: TrackResult, later: TrackResult) -> TrackResult:
    """``later``, its iterations and cost history preceded by those of ``earlier``."""
    return replace(
        later,
        iterations=earlier.iterations + later.iterations,
        cost_history=earlier.cost_history + later.cost_history,
    )


def _predicted(
    current: Params, before: Params, ahead: float, rotation: Callable[[Params], np.ndarray]
) -> Params:
    """Constant-velocity prediction: the motion from ``before`` to ``current``, ``ahead`` times.

    ``ahead`` is the ratio of the frame intervals to come to those from ``before`` to
    ``current`` (1 in a stream without gaps). The head turns about the face origin (eq. 1) by
    ``D = R_c R_b'``, so the rotation goes on as ``D^ahead R_c`` (``D^ahead`` the turn about
    D's axis by ``ahead`` times its angle) and the origin moves on by ``ahead (t_c - t_b)``;
    alpha and sigma are kept. A head that did not turn predicts ``omega_c`` exactly (no round
    trip through R). ``rotation`` gives R(omega) of a parameter vector
    (:meth:`.FaceProjection.rotation`).
    """
    omega = current.omega
    if not (omega == before.omega).all():  # np.array_equal's answer for two (3,) vectors
        turned = rotation(current)
        turn = turned @ rotation(before).T
        if ahead != 1.0:
            turn = rodrigues(matrix_to_omega(turn) * ahead)[0]
        omega = matrix_to_omega(turn @ turned)
    return current._replace(omega=omega, t=current.t + (current.t - before.t) * ahead)
