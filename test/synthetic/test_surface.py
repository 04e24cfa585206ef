"""Tests of the dense synthetic head surface (surface.py): its sampling of the face."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.surface import head_surface, outline_radius


def test_vertices_sample_the_inner_face_every_5_mm_and_the_rest_every_9_mm():
    tree = cKDTree(head_surface().uv)
    rng = np.random.default_rng(0)
    inner = np.column_stack([rng.uniform(-52, 52, 20000), rng.uniform(-30, 90, 20000)])
    head = np.column_stack([rng.uniform(-100, 100, 40000), rng.uniform(-150, 150, 40000)])
    # A square lattice of spacing s leaves no point farther than s / sqrt(2) from a vertex;
    # grid vertices within 1.8 mm of a node give way to the node, adding up to 1.8 mm.
    for points, spacing in ((inner, 5.0), (head, 9.0)):
        points = points[outline_radius(points) < 0.9]
        gap = tree.query(points)[0].max()
        assert spacing / np.sqrt(2) - 0.5 < gap < spacing / np.sqrt(2) + 1.8, spacing


def test_three_rims_of_64_vertices_lie_on_the_head_outline():
    radius = outline_radius(head_surface().uv)
    for fraction in (0.93, 0.97, 1.0):
        assert np.sum(np.abs(radius - fraction) < 1e-9) == 64, fraction


def test_translated_nodes_move_every_vertex_with_them():
    surface = head_surface()
    shift = np.array([0.01, -0.02, 0.03])
    moved = surface.vertices(mesh_topology(34).reference_shape + shift)
    np.testing.assert_allclose(
        moved - surface.rest_vertices, np.broadcast_to(shift, moved.shape), atol=1e-12
    )
