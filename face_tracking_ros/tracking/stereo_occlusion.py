"""Node patches an object in front of the face covers, and how the stereo track holds them (§3.3).

The templates of eq. 4 at frame n - 1 are the last pair's, sampled at its nodes. Once an
occluder (a hand, a mug) lies over part of a node patch, that part becomes the next pair's
template, and the node matches the occluder as it moves on: rendered occluders 15 cm in front
of the face dragged the covered mouth nodes 27-88 px (640x480) while the track stayed TRACKING.

The occluder is not at the face's depth, so at a covered node the left and right images show
different things: at the solved nodes the left-right ZSSD difference of each node patch
(:func:`stereo_disagreement`, its RMS over the left patch's contrast) read 0.6-1.8 where the
left image showed a rendered occluder over the node, and 0.1-0.7 on the eye, brow and mouth
patches of the unoccluded sequences measured (docs/performance.md, 2026-12-06 thirty-third
session). The face-edge patches read up to 2.7 without one (their one-sided patches see the face
turn away differently from each camera) and the nose's up to 1.1 (each camera sees its own side
of the nose, most when the mouth puckers): they count as covered only next to a covered node.

A node whose patch disagrees beyond ``occlusion_ratio`` is taken as covered on that pair
(:func:`covered_nodes`): it is moved from the last pair's position as the head moved, the
weighted rigid motion of the others (:func:`held_nodes`), and its patch, with the face texture
of its triangles, keeps the templates of the last pair that saw it (:func:`kept_templates`), so
the occluder never enters them and the node matches the face again once the occluder has gone.
An expression made under the occluder moves the face away from where the hold left the nodes,
so once the occluder is leaving (:func:`occluder_leaving`) the tracker solves the pair again for
the nodes it flagged, their samples weighing frame 1 alone (:func:`first_frame_coefficients`),
from coarser levels.

An occluder that leaves fewer than :data:`MIN_UNCOVERED_NODES` nodes uncovered hides the face
(:func:`face_hidden`): the others no longer measure the head's motion, and the stereo tracker
loses that pair, keeping the last pair's held nodes and templates.

An occluder covers a region, so only a held node with a held neighbour is reported as covered
(:func:`occluder_nodes`, ``FaceState.occluded``). A patch disagrees alone where the head has
turned from one camera: the far brow end, whose correlation window at frame 1 straddles the
face's outline, so that its frame-1 depth is off (8 mm on a rendered head turned 19 degrees, held
on 23 of 80 pairs; :mod:`.stereo_init`). It is held all the same, but no occluder is reported:
on rendered 640x480 free-motion sequences (yaw up to 30 degrees, no occluder) pairs with a node
flagged went 265 / 87 / 22 -> 94 / 2 / 0 (seeds 1, 6, 2) when lone patches stopped being flagged,
while under a passing occluder 0.61-0.73 of the covered node-pairs are flagged (0.61-0.75
before).

Nodes drifted off their features disagree too, a few neighbours together, and are flagged with
no occluder. The flags since the last pair with none (the region) keep a fast-moving head's pairs
from the head's motion and the coarser level meant for it
(:meth:`~.stereo.StereoTracker._followed`) only once one of its patches has disagreed as an
occluder makes it, its two images about unrelated (:func:`occluder_shown`).

Left and right also disagree at a node whose depth is wrong (the other camera's patch is then
sampled beside the feature): a 320x240 initialisation put a brow node 28 mm off, its patch read
1.1-1.2 on every pair, and holding it kept the error. So only a node whose patch has agreed on an
earlier pair of the track (:func:`agreeing`) can be taken as covered: an occluder arrives over a
face that was seen, a wrong depth is there from the start.

Some patches disagree near the ratio with nothing over them: one subject's middle brow read 0.71
on the median pair of its 380-frame training sequence (issue 5's protocol, seed 2, subject 1; the
other 23 subjects' 19-node patches 0.19 on the median, 0.56 at the 99th percentile) while on its
feature, within 0.7 px. Held on every other pair, it stopped as the brow moved and was left 5 px
off. So a patch is covered only beyond :data:`USUAL_FACTOR` times its usual disagreement, the mean
over the pairs on which it agreed (:class:`Agreement`), where that is above the ratio.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_tracking_ros.geometry.procrustes import rigid_align
from face_tracking_ros.model.topology import mesh_neighbours
from face_tracking_ros.tracking.stereo_data import Sampled, SampleSet
from face_tracking_ros.tracking.stereo_kernels import stereo_contrast

# Fewest nodes left uncovered for the others to be held to their rigid motion: a rendered
# occluder covered up to 23 of the 34 nodes (their patches in either image), seed 3's at
# 640x480 29 (:func:`face_hidden`).
MIN_UNCOVERED_NODES = 8
# A face-edge or nose node next to a covered node is covered beyond this times the ratio: the
# occluder dragged the chin and jaw 20 px (320x240 subject 0, 1 px clicks) while the nodes above
# them were held; their patches read up to 1.1 (nose) and 2.7 (face edge) without an occluder,
# but only next to a covered node is that asked.
UNCHECKED_FACTOR = 2.0
# A flagged patch shows an occluder beyond this times the ratio (:func:`occluder_shown`): the
# two images of a patch an occluder covers are about unrelated, sqrt(2) times its contrast
# (1.3-1.8 under rendered occluders), and patches drifted off their features read 0.77-0.80.
OCCLUDER_FACTOR = 2.0
# A patch is covered beyond this times its usual disagreement where that is above the ratio
# (:meth:`Agreement.limits`): a covered patch reads 0.6-1.8, an agreeing one 0.19 on the median.
USUAL_FACTOR = 2.0


def stereo_disagreement(
    samples: SampleSet, sampled: Sampled, left_contrast: np.ndarray
) -> np.ndarray:
    """(N,) RMS of each node patch's left - right difference (ZSSD) over its left contrast.

    Args:
        samples: the sample set (node patches first).
        sampled: the left and right images sampled at its points (level 0), as a solve's last
            accepted point has them.
        left_contrast: (N,) the contrast of each node patch in that left image
            (:attr:`~.stereo_data.GroupStatistics.image_contrast`).

    Returns:
        The ratio per node patch, NaN where the patch has no sample valid in both images.
    """
    members = int(samples.group_sizes[0])
    difference = stereo_contrast(sampled.values, sampled.valid, left_contrast.size, members)
    with np.errstate(invalid='ignore', divide='ignore'):
        return difference / left_contrast


def agreement_limits(checked: np.ndarray, ratio: float) -> np.ndarray:
    """(N,) the disagreement within which a node patch agrees.

    ``ratio`` for a checked node, :data:`UNCHECKED_FACTOR` times it for the others.
    """
    return np.where(checked, ratio, UNCHECKED_FACTOR * ratio)


def agreeing(disagreement: np.ndarray, checked: np.ndarray, ratio: float) -> np.ndarray:
    """(N,) bool, the node patches whose left and right images agree (NaN: not agreeing)."""
    return disagreement <= agreement_limits(checked, ratio)


@dataclass(frozen=True)
class Agreement:
    """How each node patch's left and right images have agreed over a track's earlier pairs.

    Attributes:
        total: (N,) the sum of the patch's disagreement over the pairs on which it agreed.
        count: (N,) those pairs.
    """

    total: np.ndarray
    count: np.ndarray

    @classmethod
    def none(cls, num_nodes: int) -> Agreement:
        """No pair seen yet."""
        return cls(np.zeros(num_nodes), np.zeros(num_nodes, dtype=int))

    def with_pair(self, disagreement: np.ndarray, checked: np.ndarray, ratio: float) -> Agreement:
        """This agreement with one more pair's :func:`stereo_disagreement` taken in."""
        agreed = agreeing(disagreement, checked, ratio)
        return Agreement(
            self.total + np.where(agreed, disagreement, 0.0), self.count + agreed.astype(int)
        )

    def limits(self, checked: np.ndarray, ratio: float) -> np.ndarray:
        """(N,) the disagreement beyond which each patch is covered; inf if it never agreed.

        :func:`agreement_limits`; for a checked patch, :data:`USUAL_FACTOR` times its usual
        disagreement (its mean over the pairs it agreed on) where that is higher. A patch not
        checked is covered only beside a covered one (:func:`covered_nodes`), and the face
        edge's usually disagree more (up to 2.7 without an occluder).
        """
        seen = self.count > 0
        usual = np.divide(self.total, self.count, out=np.zeros_like(self.total), where=seen)
        limits = agreement_limits(checked, ratio)
        limits = np.where(checked, np.maximum(limits, USUAL_FACTOR * usual), limits)
        return np.where(seen, limits, np.inf)


def covered_nodes(
    disagreement: np.ndarray,
    checked: np.ndarray,
    ratio: float,
    edges: np.ndarray,
    agreement: Agreement,
) -> np.ndarray:
    """(N,) bool, the nodes an occluder covers, read from their patches' disagreement.

    A checked node is covered when its patch disagrees beyond its limit (``ratio``, or more for
    a patch that usually disagrees more: :meth:`Agreement.limits`; NaN: not covered). A node
    not checked (the face edge, the nose) is when a mesh neighbour is covered and its own patch
    disagrees beyond its limit (from :data:`UNCHECKED_FACTOR` times ``ratio``). Only nodes whose
    patches agreed on an earlier pair of the track can be covered. Too many of them for the
    others to hold is :func:`face_hidden`.

    Args:
        disagreement: (N,) :func:`stereo_disagreement`.
        checked: (N,) bool, the nodes whose patches alone tell.
        ratio: the disagreement beyond which a checked patch is covered.
        edges: (E, 2) the mesh's edges.
        agreement: the patches' agreement on the track's earlier pairs.
    """
    beyond = disagreement > agreement.limits(checked, ratio)
    covered = checked & beyond
    if covered.any():
        covered |= ~checked & mesh_neighbours(covered, edges) & beyond
    return covered


def face_hidden(covered: np.ndarray) -> bool:
    """Whether an occluder hides the face: too few nodes left uncovered to hold the others.

    The covered nodes move with the weighted rigid motion of the others (:func:`held_nodes`),
    which fewer than :data:`MIN_UNCOVERED_NODES` do not measure; the stereo tracker loses
    such a pair (:meth:`~.stereo.StereoTracker._attempt`).

    Args:
        covered: (N,) bool, :func:`covered_nodes`.
    """
    return covered.size - np.count_nonzero(covered) < MIN_UNCOVERED_NODES


def occluder_nodes(held: np.ndarray, checked: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(N,) bool, the held nodes an occluder covers: those ``FaceState.occluded`` flags.

    An occluder covers a region, so a held checked node is flagged next to another held checked
    node, and a held node not checked (the face edge, the nose) next to a flagged one. A checked
    patch that disagrees alone is a head turned from one camera (the far brow end, whose frame-1
    depth is wrong on such a head): it is held all the same, since its tracking goes wrong on
    the turned side, but no occluder is reported.

    Args:
        held: (N,) bool, :func:`covered_nodes`.
        checked: (N,) bool, the nodes whose own patches tell.
        edges: (E, 2) the mesh's edges.
    """
    region = held & checked
    region &= mesh_neighbours(region, edges)
    return region | (held & ~checked & mesh_neighbours(region, edges))


def occluder_shown(flagged: np.ndarray, disagreement: np.ndarray, ratio: float) -> bool:
    """Whether the flagged nodes show what an occluder makes: a patch the cameras see unrelated.

    An occluder 15 cm in front of the face shows each camera another part of itself, so the
    left and right images of a patch it covers are about unrelated: their ZSSD difference is
    about sqrt(2) times the patch's contrast (medians 1.3-1.8 under rendered occluders). A node
    drifted off its feature is sampled beside it in the other camera, and its patch disagrees
    less: on rendered free motion at 10 fps (seed 9, the head pitching 2 degrees a pair) the
    inner brows drifted 1.8-2.8 px off and were flagged together at 0.77-0.80, with no occluder.
    So an occluder is shown where a flagged patch disagrees beyond :data:`OCCLUDER_FACTOR`
    times ``ratio``; the stereo tracker's fast-motion level and rigid start stay on until one
    has (:meth:`~.stereo.StereoTracker._followed`).

    Args:
        flagged: (N,) bool, :func:`occluder_nodes`.
        disagreement: (N,) :func:`stereo_disagreement`.
        ratio: ``occlusion_ratio``.
    """
    return bool(np.any(disagreement[flagged] > OCCLUDER_FACTOR * ratio))


def occluder_leaving(flagged: np.ndarray, last: np.ndarray) -> bool:
    """Whether the occluder is leaving the flagged nodes: none newly flagged, and fewer than last.

    An occluder that has gone flags none. But nodes it held while the face changed under it are
    left off the face, and some of them disagree left and right there after it has gone: a
    rendered pucker started under a passing occluder kept its far brow end, eye corner and
    temple flagged 28 pairs after it (640x480), with no node flagged anew.

    Args:
        flagged: (N,) bool, :func:`occluder_nodes` on this pair.
        last: (N,) bool, the same on the last pair.
    """
    count = np.count_nonzero(flagged)
    return count == 0 or (not np.any(flagged & ~last) and count < np.count_nonzero(last))


def held_nodes(
    previous: np.ndarray, nodes: np.ndarray, covered: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """``nodes`` with the covered ones moved from ``previous`` as the others moved, rigidly.

    Args:
        previous: (N, 3) the last pair's nodes, m.
        nodes: (N, 3) this pair's solved nodes, m.
        covered: (N,) bool, the nodes to hold.
        weights: (N,) the Procrustes weights of the head's motion (§3.3).
    """
    moved = rigid_align(previous, nodes, np.where(covered, 0.0, weights)).aligned
    return np.where(covered[:, None], moved, nodes)


def kept_templates(
    last: tuple[np.ndarray, ...],
    sampled: tuple[np.ndarray, ...],
    covered: np.ndarray,
    samples: SampleSet,
) -> tuple[np.ndarray, ...]:
    """The new templates of every level, those of the samples moving with a covered node kept.

    A sample keeps its last templates when a covered node moves it: the node's own patch, and
    the face-texture samples inside the triangles it is a corner of. The texture lies under the
    occluder as the patch does; sampled afresh, it took in the occluder and then the face at the
    held mesh, and held the mesh there once the occluder had gone: an expression that started
    under the occluder was not found again (a smile's mouth corners 10-15 px off to its end on
    a rendered 640x480 track, 3-6 px from 1 s after the occluder with the texture kept).

    Args:
        last: per level, (2, S) the templates the pair was solved against.
        sampled: per level, (2, S) the templates sampled on this pair.
        covered: (N,) bool, the nodes whose samples keep their last templates.
        samples: the sample set.
    """
    kept = moved_samples(samples, covered)
    return tuple(np.where(kept, old, new) for old, new in zip(last, sampled, strict=True))


def moved_samples(samples: SampleSet, nodes: np.ndarray) -> np.ndarray:
    """(S,) bool, the samples that ``nodes`` ((N,) bool) move: their patches, their triangles'."""
    return np.concatenate([np.any(nodes[gather], axis=0) for gather in samples.gather])


def first_frame_coefficients(
    coefficients: np.ndarray, samples: SampleSet, region: np.ndarray
) -> np.ndarray:
    """The a_k of eq. 4 with the samples the ``region``'s nodes move weighing frame 1 alone.

    Their frame n - 1 share goes to the frame-1 templates (the drift term's, epsilon = 1): once
    an occluder has gone, their frame n - 1 templates are those kept from before it or, for a
    node released while it passed, sampled where the hold had left it, and an expression made
    under the occluder has moved the face away from both.

    Args:
        coefficients: (4, S) a_k (:meth:`~.stereo_templates.TemplateSamples.coefficients`).
        samples: the sample set.
        region: (N,) bool, the nodes whose samples weigh frame 1 alone.
    """
    moved = moved_samples(samples, region)
    first = coefficients.copy()
    first[2:, moved] += first[:2, moved]
    first[:2, moved] = 0.0
    return first
