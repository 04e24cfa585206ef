"""A dense, renderable head surface driven by the 34 mesh nodes.

The surface is a triangle mesh parameterised by texture coordinates ``uv`` in millimetres: on the
head, ``uv`` is the (x, y) of the reference face (topology frame, y down); the neck is a half
cylinder unrolled to its own uv strip. Every mesh node is a surface vertex whose uv is the node's
reference (x, y), so a texture feature drawn at that uv (an eye corner, a mouth corner) is carried
exactly to wherever the node goes: the node IS the feature.

Vertices move linearly with the nodes (the deformation part of eq. 3 made dense)::

    vertices[:, c] = rest_vertices[:, c] + interpolation[c] @ (nodes - reference_nodes)[:, c]

``interpolation`` (3, M, 34) is a thin-plate spline over uv through the nodes and through anchor
points on the skull rim and forehead; the anchors follow the least-squares affine motion of the
rigid nodes (eye centres, eye corners, temples, upper cheeks), so an expression deforms the face
but not the skull, while an identity change (a wider face) widens the whole head.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import Delaunay

from face_tracking_ros.model.topology import Group, mesh_topology

# Head outline in uv (mm): two half ellipses about (0, HEAD_CENTRE_Y), semi-axes (x, y above
# the centre, y below it); the eyes sit half way up the head. The surface rises from the face to
# the skull rim, where it is seen edge-on from the front.
HEAD_SEMI_AXES = (80.0, 120.0, 138.0)
HEAD_CENTRE_Y = 0.0
_RIM_DEPTH = 75.0  # z of the rim, mm (behind the face, near the ears)
_FACE_DEPTH = -5.0  # z of the ellipsoid's front pole, mm

# The neck: a half cylinder (front half) below the head; it moves with the skull.
NECK_RADII = (56.0, 48.0)  # x and z semi-axes, mm
NECK_CENTRE_Z = 64.0
NECK_Y_RANGE = (60.0, 240.0)
NECK_U_OFFSET = 200.0  # the neck's uv strip starts at u = NECK_U_OFFSET - (half circumference)

_INNER_SPACING = 5.0  # vertex spacing on the inner face, mm
_OUTER_SPACING = 9.0  # vertex spacing elsewhere on the head and neck, mm
_INNER_BOX = ((-52.0, 52.0), (-30.0, 90.0))  # (x range, y range) of the finely sampled region
_RIM_FRACTIONS = (0.93, 0.97, 1.0)  # rings of vertices near the rim, as fractions of the outline
_MIN_NODE_DISTANCE = 1.8  # grid vertices closer than this to a node are dropped, mm
_EDGE_FOLLOW_RADIUS = 20.0  # mm, reach of a face-edge node over the anchors beside it
_CRANIUM_Y, _TEMPLE_Y = (
    -40.0,
    -10.0,
)  # anchors above the first follow the skull, below the second the edge
_RIGID_NODES = (
    'right_eye',
    'left_eye',
    'right_eye_outer',
    'right_eye_inner',
    'left_eye_inner',
    'left_eye_outer',
    'right_temple',
    'left_temple',
    'right_cheek_upper',
    'left_cheek_upper',
)


@dataclass(frozen=True)
class HeadSurface:
    """The dense head-and-neck triangle mesh of the synthetic faces.

    Attributes:
        uv: (M, 2) texture coordinates of the vertices, mm.
        rest_vertices: (M, 3) vertices on the reference face, face frame, metres.
        triangles: (T, 3) vertex indices, counter-clockwise in uv (y down), i.e. front-facing
            when their projection is counter-clockwise in the image.
        node_vertices: (34,) index of the vertex that is each mesh node.
        interpolation: (3, M, 34) dense motion per unit node motion, for x, y and z.
    """

    uv: np.ndarray
    rest_vertices: np.ndarray
    triangles: np.ndarray
    node_vertices: np.ndarray
    interpolation: np.ndarray

    @property
    def num_vertices(self) -> int:
        """Number of vertices M."""
        return int(self.uv.shape[0])

    def vertices(self, nodes: np.ndarray) -> np.ndarray:
        """(M, 3) face-frame vertices (m) of a face whose 34 nodes are ``nodes`` (34, 3), m."""
        motion = nodes - mesh_topology(34).reference_shape
        return self.rest_vertices + np.einsum('cmn,nc->mc', self.interpolation, motion)


def outline_radius(uv: np.ndarray) -> np.ndarray:
    """(M,) elliptical radius of (M, 2) uv points (mm): 1 on the head outline."""
    ax, ay_top, ay_bottom = HEAD_SEMI_AXES
    dy = uv[..., 1] - HEAD_CENTRE_Y
    return np.sqrt((uv[..., 0] / ax) ** 2 + (dy / np.where(dy < 0, ay_top, ay_bottom)) ** 2)


def _base_depth(uv: np.ndarray) -> np.ndarray:
    """(M,) depth z (mm) of the smooth head before node corrections: ellipsoid plus nose ridge."""
    rho = np.clip(outline_radius(uv), 0.0, 1.0)
    ellipsoid = _RIM_DEPTH - (_RIM_DEPTH - _FACE_DEPTH) * np.sqrt(1.0 - rho**2)
    x, y = uv[:, 0], uv[:, 1]
    along = np.clip((y - 2.0) / 36.0, 0.0, 1.0)  # 0 at the bridge, 1 at the tip
    half_width = 5.0 + 7.0 * along
    height = (4.0 + 16.0 * along**1.5) * np.exp(-(((y - 2.0) / 42.0) ** 8))
    ridge = height * np.exp(-0.5 * (x / half_width) ** 2) * (y > -10.0)
    return ellipsoid - ridge


def _grid(
    spacing: float, x_range: tuple[float, float], y_range: tuple[float, float]
) -> np.ndarray:
    """(K, 2) regular grid of points, mm."""
    xs = np.arange(x_range[0], x_range[1] + 1e-9, spacing)
    ys = np.arange(y_range[0], y_range[1] + 1e-9, spacing)
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


def _ring(fraction: float, count: int) -> np.ndarray:
    """(count, 2) points on the outline scaled by ``fraction``, mm."""
    angles = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
    ax, ay_top, ay_bottom = HEAD_SEMI_AXES
    ay = np.where(np.sin(angles) < 0, ay_top, ay_bottom)
    points = fraction * np.stack([ax * np.cos(angles), ay * np.sin(angles)], axis=1)
    return points + [0.0, HEAD_CENTRE_Y]


def _head_uv(node_uv: np.ndarray) -> np.ndarray:
    """(M, 2) head vertex uv: the nodes first, then fine inner and coarse outer grids and rims."""
    (x0, x1), (y0, y1) = _INNER_BOX
    inner = _grid(_INNER_SPACING, (x0, x1), (y0, y1))
    ax, ay_top, ay_bottom = HEAD_SEMI_AXES
    outer = _grid(_OUTER_SPACING, (-ax, ax), (HEAD_CENTRE_Y - ay_top, HEAD_CENTRE_Y + ay_bottom))
    in_box = (outer[:, 0] > x0) & (outer[:, 0] < x1) & (outer[:, 1] > y0) & (outer[:, 1] < y1)
    grid = np.concatenate([inner, outer[~in_box]])
    grid = grid[outline_radius(grid) < _RIM_FRACTIONS[0] - 0.02]
    distance = np.linalg.norm(grid[:, None, :] - node_uv[None], axis=2).min(axis=1)
    grid = grid[distance > _MIN_NODE_DISTANCE]
    rims = [_ring(fraction, 64) for fraction in _RIM_FRACTIONS]
    return np.concatenate([node_uv, grid, *rims])


def _node_interpolation(
    head_uv: np.ndarray, node_uv: np.ndarray, anchor_uv: np.ndarray, anchor_motion: np.ndarray
) -> np.ndarray:
    """(3, M, 34) thin-plate-spline weights of head vertices on node motion, per coordinate.

    Args:
        head_uv: (M, 2) vertex uv, mm.
        node_uv: (34, 2) node uv, mm.
        anchor_uv: (A, 2) anchor uv, mm.
        anchor_motion: (3, A, 34) anchor motion per unit node motion.
    """
    controls = np.concatenate([node_uv, anchor_uv])
    spline = RBFInterpolator(controls, np.eye(len(controls)), kernel='thin_plate_spline')
    weights = spline(head_uv)
    return weights[:, : len(node_uv)] + weights[:, len(node_uv) :] @ anchor_motion


def _skull_motion(points: np.ndarray, reference_mm: np.ndarray) -> np.ndarray:
    """(3, K, 34) motion of points rigid with the skull per unit node motion, per coordinate.

    Each coordinate c follows the least-squares scale and shift of coordinate c of the rigid
    nodes (eye centres and corners, temples, upper cheeks) about their centroid m:
    ``d_c = b_c + s_c (p_c - m_c)``. Identity changes such as a wider or larger face move the
    points; expressions, which leave the rigid nodes alone, do not. Scale and shift only (no
    shear): the points lie far outside the rigid nodes, where a full affine fit would extrapolate
    wildly.
    """
    topology = mesh_topology(34)
    rigid = [topology.index(name) for name in _RIGID_NODES]
    centred = reference_mm[rigid] - reference_mm[rigid].mean(axis=0)  # (R, 3)
    offsets = points - reference_mm[rigid].mean(axis=0)  # (K, 3)
    motion = np.zeros((3, len(points), 34))
    for c in range(3):
        scale = centred[:, c] / np.sum(centred[:, c] ** 2)  # s_c per unit motion of each node
        motion[c][:, rigid] = 1.0 / len(rigid) + np.outer(offsets[:, c], scale)
    return motion


def _anchor_motion(anchor_xyz: np.ndarray, reference_mm: np.ndarray) -> np.ndarray:
    """(3, A, 34) motion of the skull anchors per unit node motion, per coordinate.

    Anchors beside and below the face follow the nearby face-edge nodes (Gaussian weights over
    uv distance), so the head's side follows the jaw and cheeks and never folds over them;
    anchors on the cranium follow the skull (:func:`_skull_motion`), so expressions leave it
    alone. The two blend between the temples and the forehead.
    """
    topology = mesh_topology(34)
    edge = np.flatnonzero(topology.group_mask(Group.EDGE))
    distance = np.linalg.norm(anchor_xyz[:, None, :2] - reference_mm[None, edge, :2], axis=2)
    closeness = np.exp(-0.5 * (distance / _EDGE_FOLLOW_RADIUS) ** 2)
    sides = np.zeros((len(anchor_xyz), 34))
    sides[:, edge] = closeness / closeness.sum(axis=1, keepdims=True)
    lower = np.clip((anchor_xyz[:, 1:2] - _CRANIUM_Y) / (_TEMPLE_Y - _CRANIUM_Y), 0.0, 1.0)
    return lower * sides + (1.0 - lower) * _skull_motion(anchor_xyz, reference_mm)


def _neck_mesh(first_index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The neck's uv (K, 2), rest vertices (K, 3) in mm and triangles (front half cylinder)."""
    rx, rz = NECK_RADII
    angles = np.linspace(-np.pi / 2, np.pi / 2, 15)  # -pi/2: subject's right side, 0: front
    heights = np.arange(NECK_Y_RANGE[0], NECK_Y_RANGE[1] + 1e-9, _OUTER_SPACING * 2)
    theta, y = np.meshgrid(angles, heights)
    x = rx * np.sin(theta)
    z = NECK_CENTRE_Z - rz * np.cos(theta)
    xyz = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    uv = np.stack([NECK_U_OFFSET + 0.5 * (rx + rz) * theta, y], axis=-1).reshape(-1, 2)
    rows, cols = theta.shape
    index = np.arange(rows * cols).reshape(rows, cols) + first_index
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    return uv, xyz, triangles


def _counter_clockwise(triangles: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Reorder triangles so their uv winding (y down) is counter-clockwise on screen."""
    a, b, c = (uv[triangles[:, k]] for k in range(3))
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    flipped = triangles.copy()
    flipped[cross < 0] = flipped[cross < 0][:, [0, 2, 1]]
    return flipped


@cache
def head_surface() -> HeadSurface:
    """The head surface, built once: Delaunay in uv, thin-plate fits for depth and motion."""
    topology = mesh_topology(34)
    reference_mm = 1000.0 * topology.reference_shape
    node_uv = reference_mm[:, :2]
    head_uv = _head_uv(node_uv)
    # Depth: the smooth head corrected by a thin-plate spline through the node depths, pinned to
    # the smooth head on the outline.
    anchor_uv = np.concatenate([_ring(1.0, 24), _ring(0.8, 16)[_ring(0.8, 16)[:, 1] < -60.0]])
    controls = np.concatenate([node_uv, anchor_uv])
    residual = np.concatenate(
        [reference_mm[:, 2] - _base_depth(node_uv), np.zeros(len(anchor_uv))]
    )
    depth = _base_depth(head_uv) + RBFInterpolator(controls, residual, kernel='thin_plate_spline')(
        head_uv
    )
    head_xyz = np.column_stack([head_uv, depth])
    head_xyz[: len(node_uv)] = reference_mm  # exact at the nodes
    anchor_xyz = np.column_stack([anchor_uv, _base_depth(anchor_uv)])
    head_motion = _node_interpolation(
        head_uv, node_uv, anchor_uv, _anchor_motion(anchor_xyz, reference_mm)
    )
    head_motion[:, : len(node_uv)] = np.eye(len(node_uv))
    head_triangles = Delaunay(head_uv).simplices
    centroids = head_uv[head_triangles].mean(axis=1)
    head_triangles = head_triangles[outline_radius(centroids) < 1.0]
    neck_uv, neck_xyz, neck_triangles = _neck_mesh(len(head_uv))
    uv = np.concatenate([head_uv, neck_uv])
    triangles = np.concatenate([head_triangles, neck_triangles]).astype(np.int64)
    surface = HeadSurface(
        uv=uv,
        rest_vertices=np.concatenate([head_xyz, neck_xyz]) / 1000.0,
        triangles=_counter_clockwise(triangles, uv),
        node_vertices=np.arange(len(node_uv)),
        interpolation=np.concatenate([head_motion, _skull_motion(neck_xyz, reference_mm)], 1),
    )
    for array in (surface.uv, surface.rest_vertices, surface.triangles, surface.interpolation):
        array.setflags(write=False)
    return surface
