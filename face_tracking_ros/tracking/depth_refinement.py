"""Frame-1 node depths refined by the cross-camera evidence of every tracked stereo pair.

The stereo tracker keeps the subject's frame-1 mesh: the face-model term animates it, eq. 5
measures stretch from it and the drift terms compare with its templates. Whatever error the
initialisation leaves in a node's depth therefore stays for the whole sequence. One pair
measures the depth of weakly textured skin (lips, chin, cheeks) only to a few millimetres:
left-right differences of a node's surface patch are then at the noise level of the camera
(on the synthetic faces, 2-3 mm RMS per pair for the lips, 5-15 mm for face-edge nodes, which
are placed from a reference face). The noise of successive pairs is independent, so the
tracker pools them.

For node i the left-right term of eq. 4 within the current pair (its surface patch sampled in
the left image, compared with the right image at the same points, its brightness ramp removed
(:mod:`.stereo_data`), with Huber weights) is
linearised in a depth change delta_i along the node's frame-1 left viewing ray u_i, turned by
the head rotation R(n) since frame 1:

    g_i = J_i^T W r_i,   c_i = J_i^T W J_i,   J_i = d r_i / d delta_i

Every pair is a measurement of the same face-frame depth with residual variance s^2 (the
tracker's robust residual scale), so the recursive least-squares update is

    I_i <- I_i + c_i / s^2,   delta_i <- delta_i - (g_i / s^2) / I_i

with I_i starting at 1 / sigma_i^2, the initialisation's depth variance (a matched node's is
small, a node placed from the reference face's large). Each step is limited to a fraction of a
pixel of disparity, the range in which the linearisation holds.

A node whose two views do not show the same skin (it lies near the rim in one camera, or is
occluded there) has a biased left-right term. It is recognised by its residuals: accumulated
over the pairs, the left-right residual that the linearised fit predicts at its minimum,
``r^T W r - g_i^2 / c_i`` per sample, is compared with the node patch's residual between
consecutive images of one camera. A node whose ratio exceeds ``gate`` gets no update. The
linearised minimum is only a prediction: a node initialised farther from its depth than the
linear range (about a pixel of disparity) looks like one whose views disagree and keeps its
initial depth. Whatever the evidence, a node's depth stays within ``CORRECTION_SIGMAS``
standard deviations of its initial depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_tracking_ros.geometry.camera import StereoRig
from face_tracking_ros.tracking.stereo_data import ImageSource, SampleSet, depth_terms

CORRECTION_SIGMAS = 3.0  # largest total depth correction, in initial standard deviations


@dataclass(frozen=True)
class DepthEvidence:
    """The left-right term of one pair, linearised in each node's depth along its ray.

    Attributes:
        slope: (N,) g_i, grey^2 / m.
        curvature: (N,) c_i, grey^2 / m^2.
        minimum_sq: (N,) predicted mean squared left-right residual at the minimum, grey^2.
    """

    slope: np.ndarray
    curvature: np.ndarray
    minimum_sq: np.ndarray


@dataclass
class DepthRefinement:
    """Pooled depth evidence of one tracking run (frame-1 left-camera frame).

    Attributes:
        rays: (N, 3) unit frame-1 left viewing rays u_i of the nodes.
        limit: (N,) largest total correction, m.
        correction: (N,) total depth correction so far, m.
        information: (N,) I_i, 1 / m^2.
        left_right_sq: (N,) sum over pairs of the predicted minimum squared residual, grey^2.
        temporal_sq: (N,) sum over pairs of the patch's squared residual between consecutive
            left images, grey^2.
    """

    rays: np.ndarray
    limit: np.ndarray
    correction: np.ndarray
    information: np.ndarray
    left_right_sq: np.ndarray
    temporal_sq: np.ndarray

    @classmethod
    def start(cls, first_nodes: np.ndarray, depth_std: np.ndarray) -> DepthRefinement:
        """The pooled evidence before any pair: the initialisation's own depth variance.

        Args:
            first_nodes: (N, 3) frame-1 nodes, left camera frame, m.
            depth_std: (N,) standard deviation sigma_i of their depths, m.
        """
        rays = first_nodes / np.linalg.norm(first_nodes, axis=1, keepdims=True)
        depth_std = np.asarray(depth_std, dtype=float)
        n = first_nodes.shape[0]
        return cls(
            rays=rays,
            limit=CORRECTION_SIGMAS * depth_std,
            correction=np.zeros(n),
            information=1.0 / depth_std**2,
            left_right_sq=np.zeros(n),
            temporal_sq=np.zeros(n),
        )

    def update(
        self,
        evidence: DepthEvidence,
        temporal_sq: np.ndarray,
        noise: float,
        max_step: np.ndarray,
        gate: float,
    ) -> np.ndarray:
        """Pool one pair's evidence; return the depth changes (N,) to apply, m.

        Args:
            evidence: the pair's linearised left-right term.
            temporal_sq: (N,) mean squared residual of each node patch against the previous
                image of the same camera, grey^2 (NaN where unknown).
            noise: residual standard deviation s, grey levels.
            max_step: (N,) largest depth change per pair, m.
            gate: largest ratio of the accumulated left-right to temporal RMS residual.
        """
        known = np.isfinite(evidence.minimum_sq) & np.isfinite(temporal_sq)
        self.left_right_sq += np.where(known, evidence.minimum_sq, 0.0)
        self.temporal_sq += np.where(known, temporal_sq, 0.0)
        agree = self.left_right_sq <= gate**2 * self.temporal_sq
        usable = known & agree & (evidence.curvature > 0)
        variance = noise**2
        self.information += np.where(usable, evidence.curvature / variance, 0.0)
        step = np.where(usable, -(evidence.slope / variance) / self.information, 0.0)
        step = np.clip(step, -max_step, max_step)
        corrected = np.clip(self.correction + step, -self.limit, self.limit)
        step, self.correction = corrected - self.correction, corrected
        return step


def depth_evidence(
    rig: StereoRig,
    left: ImageSource,
    right: ImageSource,
    patches: SampleSet,
    nodes: np.ndarray,
    directions: np.ndarray,
    rotation: np.ndarray,
    huber: float,
) -> DepthEvidence:
    """Linearise the left-right term of every node patch in a depth change along ``directions``.

    Args:
        rig: the rectified rig.
        left: (H, W) float32 full-resolution left image of the pair, or its pyramid's level 0.
        right: the right image so.
        patches: the node patches alone (one group per node).
        nodes: (N, 3) tracked nodes, m.
        directions: (N, 3) unit directions of the depth changes (R(n) u_i).
        rotation: (3, 3) patch orientation (the head's rotation since frame 1).
        huber: Huber threshold, grey levels.
    """
    terms = depth_terms(rig, left, right, patches, nodes, directions, rotation, huber)
    counts = np.maximum(patches.layouts[0].mask.sum(axis=1), 1)
    with np.errstate(invalid='ignore', divide='ignore'):
        explained = np.where(terms.curvature > 0, terms.slope**2 / terms.curvature, 0.0) / counts
    return DepthEvidence(terms.slope, terms.curvature, terms.rms**2 - explained)
