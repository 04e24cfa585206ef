"""The templates of a stereo track: where they are sampled and how eq. 4 weighs them (§3.3, §4.2).

A track samples its images on two layouts (:class:`~.stereo_data.SampleLayout`), laid end to end
in its :class:`~.stereo_data.SampleSet`: the node patches (eq. 4's ROI, one-sided on the face
edge) and, when ``texture_weight`` > 0, the face texture inside the mesh triangles that have a
face-edge node (§4.2, :func:`texture_triangles`). The templates of a pair are the grey levels of
every sample in both images at every pyramid level l, the level-0 offsets scaled by 2^l
(:func:`templates`). Against the current image of camera c a sample's terms compare with four
templates T_k, weighed by a_k (:meth:`TemplateSamples.coefficients`):

    k = 0, 1: frame n - 1 in camera c, in the other camera;   a = (1 - epsilon) (1 - gamma, gamma)
    k = 2, 3: frame 1 in camera c, in the other camera;        a = epsilon (1 - gamma, gamma)

eq. 4's gamma split (``boundary_gamma`` on the face edge), each term split (1 - epsilon) :
epsilon between frame n - 1 and frame 1 (the drift term of eq. 6). A texture sample has the
same-camera terms only, times ``texture_weight``: (1 - epsilon) w, 0, epsilon w, 0.
"""

from __future__ import annotations

import numpy as np

from face_tracking_ros.imaging import ImagePyramid, PyramidLevel
from face_tracking_ros.model.topology import Group, MeshTopology
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig
from face_tracking_ros.tracking.stereo_data import SampleLayout, SampleSet, sample_values


class TemplateSamples:
    """Where a track's templates are sampled (its layouts) and the weights a_k of each sample.

    Args:
        config: the tracker's tunables (the templates': ``patch_half_size``,
            ``boundary_one_sided``, ``cross_taper``, ``texture_weight``,
            ``texture_subdivisions``, ``gamma``, ``boundary_gamma``, ``epsilon``).
        topology: the mesh tracked (its face-edge nodes and triangles).
    """

    def __init__(self, config: StereoTrackerConfig, topology: MeshTopology) -> None:
        """Keep the tunables; find the face-edge nodes and the face-texture triangles."""
        self._config = config
        self._boundary = topology.group_mask(Group.EDGE)
        self._texture_triangles = texture_triangles(topology)

    def coefficients(self, samples: SampleSet) -> np.ndarray:
        """(4, S) a_k of every sample, weighing the T_k of a :class:`~.stereo_solve.Level`.

        Node patches: eq. 4 (same camera 1 - gamma, other camera gamma) at frame n - 1 and
        frame 1 in the ratio (1 - epsilon) : epsilon, the other camera's terms times each
        sample's cross-camera weight (the layout's ``cross``: the depth refinement weighs the
        samples so, and the two would otherwise pull the depth to different minima). Texture:
        same camera only, scaled by the texture weight (the flat triangles are not the curved
        face, so the cross-camera terms would be biased there).
        """
        config = self._config
        keep = 1.0 - config.epsilon
        cross = np.where(self._boundary, config.boundary_gamma, config.gamma)
        same = 1.0 - cross
        patches = np.array(
            [keep * same, keep * cross, config.epsilon * same, config.epsilon * cross]
        )
        layout = samples.layouts[0]
        patches = np.repeat(patches, layout.mask.shape[1], axis=1)
        patches[[1, 3]] *= layout.cross.ravel()
        columns = [patches]
        if len(samples.layouts) > 1:
            texture = [keep * config.texture_weight, 0.0, config.epsilon * config.texture_weight]
            columns.append(
                np.repeat(np.array([*texture, 0.0])[:, None], samples.layouts[1].mask.size, axis=1)
            )
        return np.concatenate(columns, axis=1)

    def layouts(self, nodes: np.ndarray, focal: float) -> tuple[SampleLayout, ...]:
        """Node patches (always) and the face-texture samples (if texture_weight > 0)."""
        config = self._config
        layouts = [self.node_patches(nodes, focal)]
        if config.texture_weight > 0 and len(self._texture_triangles):
            layouts.append(
                SampleLayout.triangle_texture(self._texture_triangles, config.texture_subdivisions)
            )
        return tuple(layouts)

    def node_patches(self, nodes: np.ndarray, focal: float) -> SampleLayout:
        """The node patches at ``nodes`` (one-sided on the face edge, as configured).

        Args:
            nodes: (N, 3) nodes in the left camera frame, m.
            focal: the left camera's focal length, px (samples about one pixel apart).
        """
        config = self._config
        return SampleLayout.node_patches(
            nodes,
            nodes[:, 2] / focal,
            config.patch_half_size,
            self._boundary & config.boundary_one_sided,
            config.cross_taper,
        )


def templates(
    pyramids: tuple[ImagePyramid, ImagePyramid],
    projections: tuple[np.ndarray, ...],
    samples: SampleSet,
    nodes: np.ndarray,
    offsets: np.ndarray,
    field: np.ndarray | None = None,
) -> tuple[np.ndarray, ...]:
    """(2, S) grey levels of the samples in both images at every level (the templates).

    Args:
        pyramids: the pyramids of the pair sampled, left then right.
        projections: per pyramid level, (2, 3, 4) P of eq. 2 of both cameras onto it.
        samples: the sample set.
        nodes: (N, 3) nodes, m.
        offsets: (3, S) level-0 sample offsets (turned as at ``nodes``), m.
        field: optional (3, S_p) level-0 deformation of the node patches at ``nodes``, m
            (:meth:`~.stereo_data.SampleSet.points`).
    """
    return tuple(
        level_templates(pyramids, level, onto, samples, nodes, offsets, field)
        for level, onto in enumerate(projections)
    )


def level_templates(
    pyramids: tuple[ImagePyramid, ImagePyramid],
    level: int,
    projections: np.ndarray,
    samples: SampleSet,
    nodes: np.ndarray,
    offsets: np.ndarray,
    field: np.ndarray | None = None,
) -> np.ndarray:
    """(2, S) grey levels of the samples in both images at pyramid level ``level``.

    Args:
        pyramids: the pyramids of the pair sampled, left then right.
        level: the level.
        projections: (2, 3, 4) P of eq. 2 of both cameras onto that level.
        samples: the sample set.
        nodes: (N, 3) nodes, m.
        offsets: (3, S) level-0 sample offsets (turned as at ``nodes``), m.
        field: optional (3, S_p) level-0 deformation of the node patches at ``nodes``, m.
    """
    scale = float(1 << level)
    return sample_values(
        tuple(PyramidLevel(pyramid, level) for pyramid in pyramids),
        projections,
        samples.points(nodes, scale * offsets, field, scale),
    )


def texture_triangles(topology: MeshTopology) -> np.ndarray:
    """The triangles of the face-texture term: those with a face-edge node (§4.2).

    The term is there for the face-edge nodes, whose own patches see little: a node sliding
    along the boundary distorts the texture of its triangles. Inside the face the node patches
    see enough, and a flat triangle stretched by its corners (the brows', when they rise) is
    not how the skin between them moves, which biased the brows by up to a pixel.
    """
    edge = topology.group_mask(Group.EDGE)
    return topology.triangles[np.any(edge[topology.triangles], axis=1)]
