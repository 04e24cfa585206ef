"""The checks that declare the monocular track lost (seed §3.5, §4.4).

Loss of track gives status LOST with the last valid estimate. It is declared when most textured
nodes' ROIs do not match their templates, when they match the previous frame but no longer the
first one (the median residual against the keyframe's templates alone, a drifted track), when
too few nodes are visible, the rotation jumps, or the solve is ill-conditioned or non-finite. A
node matches when its residual (the brightness change projected out) is small against its ROI's
texture in the image: what is left of the ROI after removing the brightness change that needs
no template (its mean and, for GAIN_FIELD, its linear ramp, which alone fit a smooth backdrop or
hand). An image ROI with no texture above ``residual_scale_floor`` cannot confirm a textured
template.

An occluder passing in front of the face (a hand, a mug) covers some nodes while the others fit
as before. The covered nodes are told from the others per image (:func:`covered_nodes`) and are
left out: of the checks (they count as not visible, so too few nodes left uncovered is a loss),
of the next image's solve, and of the templates, whose rows for them are the nearest keyframe's
(:meth:`~.mono_templates.Templates.kept`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import angle_between
from face_tracking_ros.imaging import PhotometricModel
from face_tracking_ros.imaging.photometric import PhotometricProjection
from face_tracking_ros.model.topology import Group, MeshTopology, mesh_neighbours
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.mono_kernels import (
    Votes,
    loss_votes,
    median_rms_ratio,
    row_rms,
)
from face_tracking_ros.tracking.mono_projection import FaceProjection
from face_tracking_ros.tracking.mono_rois import Params
from face_tracking_ros.tracking.mono_templates import Keyframe, nearest_keyframe
from face_tracking_ros.wording import counted

_MIN_DEPTH = 0.05  # m; a face nearer the camera than this has diverged
# A node newly covered fits this many times worse than the lower quartile of the visible inner
# nodes not covered. A change of light raises every node's residual (rendered, on its first frame:
# lower quartile 0.35, worst inner node 0.72 of the ROI texture); an occluder raises those it
# covers alone (0.6-1.0 against a lower quartile of 0.07-0.2).
_COVER_FACTOR = 3.0
# Fewest inner nodes failing at once that start a cover away from a covered node, each next to
# another: on the 48 unoccluded runs of docs/performance.md two neighbours failed together now
# and then (an eye's outer corner and brow end as the head turned, the lips' corners with the
# expression) and, covered, stayed so; with three no cover started there (the runs the same to
# the digit).
_COVER_START = 3
# A covered node is uncovered once it fits its kept template within this fraction of
# occlusion_residual_ratio: an occluder's edge over part of its ROI leaves it fitting at 0.4-0.5,
# and uncovered there its templates took the edge in, which dragged the face along with it.
_UNCOVER_FRACTION = 0.5


class Reference(NamedTuple):
    """What an estimate is checked against.

    Attributes:
        last: the track's last valid estimate.
        frames: the frame intervals since it (1 for the frame after it; dropped images count).
        keyframes: the track's keyframes (the drift check's templates).
    """

    last: Params
    frames: int
    keyframes: Sequence[Keyframe]


class LossChecks:
    """Whether an estimate of eq. 6 is a valid track, and why not.

    Args:
        config: the tracker's tunables (the checks': ``max_rotation_step``, ``max_condition``,
            ``min_visible_fraction``, ``residual_scale_floor``, ``lost_node_fraction``,
            ``drift_residual_ratio``, ``occlusion_residual_ratio`` and ``photometric``).
        camera: the camera (its image size).
        face: the model posed and projected.
        grid: (M, 2) the ROI's sample offsets in grid steps.
        topology: the model's mesh (which nodes are on the face edge, which are neighbours).
    """

    def __init__(
        self,
        config: MonoTrackerConfig,
        camera: PinholeCamera,
        face: FaceProjection,
        grid: np.ndarray,
        topology: MeshTopology,
    ) -> None:
        """Keep the collaborators; make the projection that leaves a ROI's texture."""
        self._config = config
        self._camera = camera
        self._face = face
        self._inner = ~topology.group_mask(Group.EDGE)
        self._edges = topology.edges
        # The brightness change of a ROI that needs no template (a flat template's projection):
        # its mean, and for GAIN_FIELD its linear ramp; what is left is the ROI's texture.
        self._untextured = PhotometricProjection.of(
            np.zeros((1, len(grid))), max(config.photometric, PhotometricModel.BIAS), grid
        )

    def reason(
        self,
        params: Params,
        node_rms: np.ndarray,
        samples: np.ndarray,
        textures: tuple[np.ndarray, np.ndarray],
        visibility: np.ndarray,
        condition: float,
        residual_ratio: float,
        reference: Reference,
    ) -> str:
        """Why this estimate is not a valid track ('' if it is).

        Args:
            params: the solution.
            node_rms: (N,) RMS of each node's (photometrically projected) residual.
            samples: (N, M) level-0 samples of the image at the solution.
            textures: (N,) their ROIs' texture and that of the level-0 template they were
                compared with (:meth:`textures`).
            visibility: (N,) node visibility at the solution.
            condition: the solve's condition number.
            residual_ratio: a node fails when its residual exceeds this multiple of its texture.
            reference: the last valid estimate and the keyframes.
        """
        config = self._config
        values = np.concatenate([params.omega, params.t, params.alpha, params.sigma])
        if not np.isfinite(values).all() or params.t[2] < _MIN_DEPTH:
            return 'the solver diverged'
        # The motion since the last valid estimate, whatever the solve started from (a search
        # or a detection when re-acquiring), over the frames since.
        frames = reference.frames
        turn = angle_between(self._face.rotation(reference.last), self._face.rotation(params))
        if turn > config.max_rotation_step * frames:
            return (
                f'implausible motion ({np.degrees(turn):.0f} degrees in '
                f'{counted(frames, "frame")})'
            )
        if condition > config.max_condition:
            return f'ill-conditioned solve (condition {condition:.1e})'
        # Each node's residual against the texture of its ROI in the image: near 1 when the
        # template explains none of it. Nodes flat in both the image and the template abstain.
        floor = config.residual_scale_floor
        image_texture = textures[0]
        votes = self._votes(params, visibility, textures, node_rms, residual_ratio)
        nodes = len(votes.visible)
        if votes.visible_count / nodes < config.min_visible_fraction:
            return f'only {votes.visible_count} of {nodes} nodes visible in the image'
        if not votes.voting:
            return (
                f'no visible node shows texture above {floor:g} grey levels, in the image or its '
                'template: a blank, dark or saturated image'
            )
        if self.outvoted(votes):
            return f'{votes.failing} of {votes.voting} textured nodes do not match their templates'
        keyframe = nearest_keyframe(reference.keyframes, params.omega)
        drift = _drift_ratio(keyframe, samples, image_texture, votes.textured)
        if drift > config.drift_residual_ratio:
            return f'drifted: residual against the keyframe {drift:.2f} x the ROI texture'
        return ''

    def vote(
        self,
        params: Params,
        node_rms: np.ndarray,
        textures: tuple[np.ndarray, np.ndarray],
        visibility: np.ndarray,
        ratio: float,
    ) -> Votes:
        """The vote of :meth:`reason` (its arguments as there) at any ``ratio``.

        :meth:`outvoted` says whether it fails; ``failing / voting`` is the fraction failing.
        """
        return self._votes(params, visibility, textures, node_rms, ratio)

    def covered(
        self,
        params: Params,
        node_rms: np.ndarray,
        texture: np.ndarray,
        visibility: np.ndarray,
        before: np.ndarray,
        expired: np.ndarray,
    ) -> np.ndarray:
        """(N,) bool, the nodes an occluder covers at this estimate (:func:`covered_nodes`).

        Args:
            params: the estimate.
            node_rms: (N,) RMS of each node's residual there.
            texture: (N,) the texture of the image's ROIs there (:meth:`textures`).
            visibility: (N,) node visibility there.
            before: (N,) bool, the nodes covered at the last valid estimate.
            expired: (N,) bool, those of them to uncover now, however they fit.
        """
        config = self._config
        texture = np.maximum(texture, config.residual_scale_floor)
        ratios = node_rms / texture
        if not (before.any() or (ratios[self._inner] > config.occlusion_residual_ratio).any()):
            return np.zeros_like(before)  # most frames of a track: nothing to cover
        votes = self._votes(params, visibility, (texture, texture), node_rms, 1.0)
        return covered_nodes(
            ratios,
            votes.visible,
            self._inner,
            before,
            config.occlusion_residual_ratio,
            self._edges,
            expired,
        )

    def steady(
        self, params: Params, node_rms: np.ndarray, samples: np.ndarray, visibility: np.ndarray
    ) -> bool:
        """Whether a valid estimate matches the image as closely as a resumed track must.

        The vote of :meth:`reason` at ``reacquire_residual_ratio`` over the visible nodes whose
        ROI shows texture in the image: at most ``lost_node_fraction`` of them may fail. The
        bundle adjustment keeps only such frames as views (:mod:`.mono_adjustment`).

        Args:
            params: the estimate.
            node_rms: (N,) RMS of each node's residual there.
            samples: (N, M) level-0 samples of the image there.
            visibility: (N,) node visibility there.
        """
        config = self._config
        texture = row_rms(self._untextured.apply(samples))
        votes = self._votes(
            params, visibility, (texture, texture), node_rms, config.reacquire_residual_ratio
        )
        return 0 < votes.voting and not self.outvoted(votes)

    def outvoted(self, votes: Votes, fraction: float | None = None) -> bool:
        """Whether more than ``fraction`` of the voting nodes fail: the loss vote.

        ``fraction`` is ``lost_node_fraction`` unless given.
        """
        fraction = self._config.lost_node_fraction if fraction is None else fraction
        return votes.failing > fraction * votes.voting

    def _votes(
        self,
        params: Params,
        visibility: np.ndarray,
        texture: tuple[np.ndarray, np.ndarray],
        node_rms: np.ndarray,
        ratio: float,
    ) -> Votes:
        """:func:`~.mono_kernels.loss_votes` of the nodes at ``params`` in this camera's image."""
        return loss_votes(
            visibility,
            self._face.nodes(params)[1],
            (self._camera.width, self._camera.height),
            texture,
            node_rms,
            self._config.residual_scale_floor,
            ratio,
        )

    def textures(self, samples: np.ndarray, template: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The ROIs' texture in the image and in the template, in one projection.

        Each is the (N,) RMS of the (N, M) ROI values beyond the brightness change that needs
        no template.
        """
        rms = row_rms(self._untextured.apply(np.concatenate((samples, template))))
        return rms[: len(samples)], rms[len(samples) :]


def covered_nodes(
    ratios: np.ndarray,
    visible: np.ndarray,
    inner: np.ndarray,
    before: np.ndarray,
    ratio: float,
    edges: np.ndarray,
    expired: np.ndarray,
) -> np.ndarray:
    """(N,) bool, the nodes an occluder covers, read from how each fits its template (eq. 6).

    A covered node stays covered while it fits its (kept) template worse than
    :data:`_UNCOVER_FRACTION` of ``ratio``, unless its cover has ``expired``: then it is
    uncovered and not covered anew on this image (its templates are sampled afresh). A covered
    face-edge node stays covered only next to a covered inner node: its patch fits its kept
    template worse as the head turns, whether the occluder is still there or not. A visible
    inner node not covered before is newly covered when it fits worse than ``ratio`` and than
    :data:`_COVER_FACTOR` times the lower quartile of the visible inner nodes not covered
    before, and it is next to a covered node (an occluder grows over its neighbours) or
    :data:`_COVER_START` nodes fail so at once and a mesh neighbour of it is one of them (an
    occluder covers a region). A face-edge node failing so is covered only next to a covered
    node: its patch changes most with pose and light. A change of light raises the residuals of
    the whole face, the lower quartile with them.

    Args:
        ratios: (N,) each node's RMS residual over its ROI's texture in the image (floored at
            ``residual_scale_floor``).
        visible: (N,) bool, the nodes visible in the image.
        inner: (N,) bool, the nodes off the face edge.
        before: (N,) bool, the nodes covered at the last valid estimate.
        ratio: ``occlusion_residual_ratio``.
        edges: (E, 2) the mesh's edges.
        expired: (N,) bool, the covered nodes to uncover now, however they fit.
    """
    kept = before & ~expired & visible & (ratios > _UNCOVER_FRACTION * ratio)
    kept &= inner | mesh_neighbours(kept & inner, edges)
    fitting = visible & ~before
    failing = fitting & (ratios > ratio)
    candidates = failing & (inner | mesh_neighbours(kept, edges))
    if not (candidates.any() and (fitting & inner).any()):  # on most frames of a track
        return kept
    failing &= ratios > _COVER_FACTOR * float(np.percentile(ratios[fitting & inner], 25))
    grown = failing & inner & mesh_neighbours(kept, edges)
    if np.count_nonzero(failing & inner) >= _COVER_START:
        grown |= failing & inner & mesh_neighbours(failing & inner, edges)
    covered = kept | grown
    return covered | (failing & ~inner & mesh_neighbours(covered, edges))


def _drift_ratio(
    keyframe: Keyframe, samples: np.ndarray, texture: np.ndarray, nodes: np.ndarray
) -> float:
    """Median over ``nodes`` of the residual against ``keyframe`` alone / texture.

    The drift check of :meth:`LossChecks.reason`: eq. 6's data term with epsilon = 1, i.e.
    against the keyframe's templates without the previous frame's, photometrically projected
    like the residuals of the solve.

    Args:
        keyframe: the keyframe nearest the solution.
        samples: (N, M) level-0 samples of the image at the solution.
        texture: (N,) their ROIs' texture (:meth:`LossChecks.textures`).
        nodes: (N,) the visible nodes whose ROI shows texture.
    """
    key = keyframe.templates
    residuals = keyframe.projection.residuals(samples, key.levels[0])
    return median_rms_ratio(residuals, texture, nodes & (key.visibility > 0))
