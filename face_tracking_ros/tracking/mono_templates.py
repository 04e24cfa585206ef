"""The templates of eq. 6 and the keyframes of its drift term.

Eq. 6 compares I_n's samples on the ROIs with ``I_(n-1)(x_i(n-1))`` and ``I_1(x_i(1))``: the
templates, each image's samples (:mod:`.mono_projection`) on the ROIs (:mod:`.mono_rois`) of
every pyramid level at its estimate (:class:`Templates`). A frame's coarse levels are sampled
only when a later solve first reads them (:class:`OnDemand`).

The drift term's templates are a keyframe's (:class:`Keyframe`): frame 1's, the seed's I_1.
Optionally (``max_keyframes`` > 1) the drift term compares with the keyframe nearest in rotation
instead of frame 1 (:func:`nearest_keyframe`). Measured on synthetic sequences it does worse than
I_1 alone (keyframes inherit the error of the pose they were taken at), so it is off by default.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple, Protocol

import numpy as np

from face_tracking_ros.geometry.rotation import rodrigues
from face_tracking_ros.imaging import ImagePyramid
from face_tracking_ros.imaging.photometric import PhotometricInvariance, PhotometricProjection
from face_tracking_ros.tracking.mono_projection import FaceProjection, Sampled
from face_tracking_ros.tracking.mono_rois import Params, Roi


class OnDemand(Sequence[np.ndarray]):
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


class Templates(NamedTuple):
    """Samples of every pyramid level at a pose, with node visibility and level-0 inside mask.

    Attributes:
        levels: (N, M) samples per level; coarse levels may be sampled on first use
            (:class:`OnDemand`).
        visibility: (N,) node visibility weights.
        inside: (N, M) level-0 samples inside the image.
        params: the parameter vector they were sampled at.
        covered: (N,) bool, the nodes an occluder covers in the image
            (:func:`~.mono_loss.covered_nodes`): once the frame is accepted their rows hold the
            nearest keyframe's (:meth:`kept`), and they weigh nothing.
    """

    levels: Sequence[np.ndarray]
    visibility: np.ndarray
    inside: np.ndarray
    params: Params
    covered: np.ndarray

    @property
    def seen(self) -> np.ndarray:
        """(N,) the visibility weights of the nodes not covered (the covered ones 0)."""
        return np.where(self.covered, 0.0, self.visibility)

    def kept(self, last: Templates) -> Templates:
        """These templates with the covered nodes' rows of every level taken from ``last``.

        The tracker passes the keyframe nearest the pose. Every level is sampled now (of both)
        when a node is covered: the occluder never enters a covered node's templates, so it
        matches the face again once the occluder has gone. Not the last frame's rows: an
        occluder is seen a few frames after it has come over a node, so those may show it (on a
        rendered hand passing, six nodes then stayed covered 8 frames after the hand had gone).
        """
        if not self.covered.any():
            return self
        rows = self.covered[:, None]
        levels = tuple(
            np.where(rows, old, new) for old, new in zip(last.levels, self.levels, strict=True)
        )
        return self._replace(levels=levels)

    def sampled(self) -> Templates:
        """These templates with every level sampled (to keep past their pyramid)."""
        if isinstance(self.levels, OnDemand):
            return self._replace(levels=self.levels.made())
        return self

    def reads(self, pyramid: ImagePyramid | None) -> bool:
        """Whether a level not sampled yet would be sampled from ``pyramid``."""
        return isinstance(self.levels, OnDemand) and self.levels.reads(pyramid)


class Keyframe(NamedTuple):
    """A keyframe: its templates, the rotation R(omega) they were sampled at, and a projection.

    ``projection`` is the photometric projection of the level-0 template, built once for the
    drift check.
    """

    rotation: np.ndarray
    templates: Templates
    projection: PhotometricProjection


class TemplateSampler:
    """Samples an image's templates on a track's ROIs, and makes keyframes of them.

    Args:
        face: the model posed and projected, which samples the ROIs.
        invariance: the photometric invariance of the residuals (a keyframe's projection).
    """

    def __init__(self, face: FaceProjection, invariance: PhotometricInvariance) -> None:
        """Keep the collaborators."""
        self._face = face
        self._invariance = invariance

    def templates(
        self,
        pyramid: ImagePyramid,
        params: Params,
        rois: tuple[Roi, ...],
        normals: np.ndarray,
        first: Sampled | None = None,
    ) -> Templates:
        """Samples of every level at ``params``'s ROIs, and the node visibility there.

        ``first`` is level 0 at ``params`` when it has been sampled already. The coarser levels
        are sampled when first used (:class:`OnDemand`), from ``pyramid``, which the tracker
        keeps until then.
        """
        first = first or self._face.sample(pyramid, params, 0, rois[0])

        def sample(level: int) -> np.ndarray:
            return self._face.sample(pyramid, params, level, rois[level]).samples

        levels = OnDemand(pyramid.num_levels, sample, source=pyramid, first=first.samples)
        visibility = self._face.visibility(params, normals)
        covered = np.zeros(visibility.shape, dtype=bool)
        return Templates(levels, visibility, first.inside, params, covered)

    def keyframe(self, omega: np.ndarray, templates: Templates) -> Keyframe:
        """A keyframe of ``templates`` sampled at rotation R(omega), every level sampled now."""
        projection = self._invariance.projection(templates.levels[0])
        return Keyframe(rodrigues(omega)[0], templates.sampled(), projection)


def nearest_keyframe(keyframes: Sequence[Keyframe], omega: np.ndarray) -> Keyframe:
    """The keyframe whose rotation is nearest R(omega) (frame 1's alone by default, at once)."""
    if len(keyframes) == 1:
        return keyframes[0]
    return keyframes[int(np.argmax(keyframe_cosines(keyframes, omega)))]


class Rotated(Protocol):
    """Anything seen at a rotation: a keyframe, or a view of the bundle adjustment."""

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) R(omega) it was seen at."""


def keyframe_cosines(keyframes: Sequence[Rotated], omega: np.ndarray) -> np.ndarray:
    """trace(R_k' R(omega)) of every keyframe (or view) k: larger means nearer (3 = same)."""
    rotation, _ = rodrigues(omega)
    return np.array([np.sum(k.rotation * rotation) for k in keyframes])
