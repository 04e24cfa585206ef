"""Mesh topology: the named nodes of the 19- and 34-node face meshes (seed §3.2 and §4.1).

The face frame (used by every module and stated in ``FaceState.msg``): origin at the midpoint
between the two eye-centre nodes; x towards the subject's left (image right in a frontal view);
y towards the chin; z into the head (away from the camera in a frontal view). With this frame a
rotation vector ``omega = 0`` is a frontal face looking at the camera, and eq. 1 maps it into the
camera optical frame (x right, y down, z forward). Node coordinates are in metres.

"right" and "left" in node names are the subject's own sides, as in anatomy: ``right_eye`` appears
on the image's left in a frontal view.

The 19-node mesh of §3.2 has eyes (2), nose (3), mouth (8) and eyebrows (6). The 34-node mesh of
§4.1 adds 15 nodes: the four eye corners and eleven face-edge nodes from temple to temple
through the chin.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from functools import cache

import numpy as np
from scipy.spatial import Delaunay

from face_tracking_ros.errors import ConfigError


class Group(StrEnum):
    """Anatomical groups: they set Procrustes weights (§3.3) and stiffness (eq. 5)."""

    EYE = 'eye'
    NOSE = 'nose'
    MOUTH = 'mouth'
    BROW = 'brow'
    EYE_CORNER = 'eye_corner'
    EDGE = 'edge'


# Reference (generic adult) positions in millimetres in the face frame, with each node's group.
# Used for edges, generic initialisation and as the base of the synthetic population. The order of
# this table is the node order of every array in the package (19-node meshes keep the first 19).
_REFERENCE_MM: tuple[tuple[str, Group, tuple[float, float, float]], ...] = (
    # 19-node mesh of §3.2
    ('right_eye', Group.EYE, (-31.5, 0.0, 0.0)),
    ('left_eye', Group.EYE, (31.5, 0.0, 0.0)),
    ('nose_tip', Group.NOSE, (0.0, 38.0, -27.0)),
    ('nose_right', Group.NOSE, (-17.0, 45.0, -9.0)),
    ('nose_left', Group.NOSE, (17.0, 45.0, -9.0)),
    ('mouth_right', Group.MOUTH, (-25.0, 70.0, -6.0)),
    ('mouth_left', Group.MOUTH, (25.0, 70.0, -6.0)),
    ('upper_lip_right', Group.MOUTH, (-11.0, 63.0, -13.0)),
    ('upper_lip', Group.MOUTH, (0.0, 62.0, -15.0)),
    ('upper_lip_left', Group.MOUTH, (11.0, 63.0, -13.0)),
    ('lower_lip_right', Group.MOUTH, (-11.0, 77.0, -12.0)),
    ('lower_lip', Group.MOUTH, (0.0, 79.0, -13.0)),
    ('lower_lip_left', Group.MOUTH, (11.0, 77.0, -12.0)),
    ('right_brow_inner', Group.BROW, (-17.0, -17.0, -4.0)),
    ('right_brow_middle', Group.BROW, (-33.0, -22.0, -2.0)),
    ('right_brow_outer', Group.BROW, (-49.0, -17.0, 6.0)),
    ('left_brow_inner', Group.BROW, (17.0, -17.0, -4.0)),
    ('left_brow_middle', Group.BROW, (33.0, -22.0, -2.0)),
    ('left_brow_outer', Group.BROW, (49.0, -17.0, 6.0)),
    # 15 nodes added in §4.1
    ('right_eye_outer', Group.EYE_CORNER, (-45.0, 1.0, 7.0)),
    ('right_eye_inner', Group.EYE_CORNER, (-16.0, 1.0, 2.0)),
    ('left_eye_inner', Group.EYE_CORNER, (16.0, 1.0, 2.0)),
    ('left_eye_outer', Group.EYE_CORNER, (45.0, 1.0, 7.0)),
    ('right_temple', Group.EDGE, (-66.0, -8.0, 28.0)),
    ('right_cheek_upper', Group.EDGE, (-66.0, 28.0, 30.0)),
    ('right_cheek_lower', Group.EDGE, (-61.0, 60.0, 26.0)),
    ('right_jaw', Group.EDGE, (-50.0, 88.0, 16.0)),
    ('right_chin', Group.EDGE, (-28.0, 106.0, 2.0)),
    ('chin', Group.EDGE, (0.0, 112.0, -6.0)),
    ('left_chin', Group.EDGE, (28.0, 106.0, 2.0)),
    ('left_jaw', Group.EDGE, (50.0, 88.0, 16.0)),
    ('left_cheek_lower', Group.EDGE, (61.0, 60.0, 26.0)),
    ('left_cheek_upper', Group.EDGE, (66.0, 28.0, 30.0)),
    ('left_temple', Group.EDGE, (66.0, -8.0, 28.0)),
)

SUPPORTED_NODE_COUNTS = (19, 34)

# Procrustes weights of §3.3: rigid parts 0.9, deformable parts 0.1.
ALIGNMENT_WEIGHTS: dict[Group, float] = {
    Group.EYE: 0.9,
    Group.NOSE: 0.9,
    Group.EYE_CORNER: 0.9,
    Group.EDGE: 0.5,
    Group.MOUTH: 0.1,
    Group.BROW: 0.1,
}


@dataclass(frozen=True)
class MeshTopology:
    """Names, groups, reference shape and edges of an N-node face mesh.

    Attributes:
        node_names: N node names in array order.
        groups: N anatomical groups.
        reference_shape: (N, 3) generic adult face in the face frame, metres.
        edges: (E, 2) int node index pairs of a triangulation of the frontal view.
        triangles: (T, 3) int node index triples of that triangulation.
    """

    node_names: tuple[str, ...]
    groups: tuple[Group, ...]
    reference_shape: np.ndarray
    edges: np.ndarray
    triangles: np.ndarray

    @property
    def num_nodes(self) -> int:
        """Number of nodes N."""
        return len(self.node_names)

    def index(self, name: str) -> int:
        """Index of a node by name.

        Raises:
            ConfigError: if the name is not a node of this mesh.
        """
        try:
            return self.node_names.index(name)
        except ValueError:
            msg = (
                f'unknown node name {name!r}; the {self.num_nodes}-node mesh has {self.node_names}'
            )
            raise ConfigError(msg) from None

    def group_mask(self, *groups: Group) -> np.ndarray:
        """Boolean (N,) mask of the nodes in any of ``groups``."""
        return np.array([g in groups for g in self.groups])

    def alignment_weights(self) -> np.ndarray:
        """Per-node Procrustes weights (§3.3), (N,) float: :data:`ALIGNMENT_WEIGHTS`.

        Rigid nodes (eyes, eye corners, nose) 0.9, the face edge 0.5, mouth and brows 0.1.
        """
        return np.array([ALIGNMENT_WEIGHTS[g] for g in self.groups], dtype=float)


@cache
def mesh_topology(num_nodes: int = 34) -> MeshTopology:
    """The topology of the 19-node (§3.2) or 34-node (§4.1) mesh.

    Args:
        num_nodes: 19 or 34.

    Raises:
        ConfigError: for any other node count.
    """
    if num_nodes not in SUPPORTED_NODE_COUNTS:
        msg = f'num_nodes must be one of {SUPPORTED_NODE_COUNTS}, got {num_nodes}'
        raise ConfigError(msg)
    rows = _REFERENCE_MM[:num_nodes]
    reference = np.array([xyz for _, _, xyz in rows], dtype=float) / 1000.0
    triangles = Delaunay(reference[:, :2]).simplices.astype(np.int64)
    triangles.setflags(write=False)
    reference.setflags(write=False)
    edges = _edges_of(triangles)
    return MeshTopology(
        node_names=tuple(name for name, _, _ in rows),
        groups=tuple(group for _, group, _ in rows),
        reference_shape=reference,
        edges=edges,
        triangles=triangles,
    )


def mesh_neighbours(nodes: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(N,) bool, the nodes an edge of the mesh joins to one of ``nodes``.

    Args:
        nodes: (N,) bool, the nodes whose neighbours are wanted.
        edges: (E, 2) the mesh's edges (:attr:`MeshTopology.edges`).
    """
    near = np.zeros(nodes.size, dtype=bool)
    near[edges[nodes[edges[:, 1]], 0]] = True
    near[edges[nodes[edges[:, 0]], 1]] = True
    return near


def _edges_of(triangles: np.ndarray) -> np.ndarray:
    """Unique sorted (E, 2) edges of a triangle list."""
    pairs = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [0, 2]]])
    edges = np.unique(np.sort(pairs, axis=1), axis=0)
    edges.setflags(write=False)
    return edges
