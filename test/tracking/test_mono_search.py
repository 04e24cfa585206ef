"""The re-acquisition search's view of the face (tracking/mono_search.py), by hand."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.imaging import ImagePyramid
from face_tracking_ros.tracking.mono_search import FaceView, PendingView

# Level-0 pixels of three nodes; the last is on the face edge and left out.
NODES = np.array([[100.0, 50.0], [300.0, 150.0], [620.0, 470.0]])
INNER = np.array([True, True, False])


def test_the_view_is_the_search_levels_box_around_the_inner_nodes(texture_factory) -> None:
    """On level 1 the inner nodes span (50, 25) to (150, 75): rows 25-75, columns 50-150.

    Level 1 with two levels or more; a one-level pyramid is searched on level 0.
    """
    for levels in (4, 2):
        pyramid = ImagePyramid.build(texture_factory(), levels)
        view = FaceView.of(pyramid, NODES, INNER)
        np.testing.assert_array_equal(view.corner, [50, 25])
        np.testing.assert_array_equal(view.image, pyramid.levels[1][25:76, 50:151])
    pyramid = ImagePyramid.build(texture_factory(), 1)
    view = FaceView.of(pyramid, NODES, INNER)
    np.testing.assert_array_equal(view.corner, [100, 50])
    np.testing.assert_array_equal(view.image, pyramid.levels[0][50:151, 100:301])


def test_the_shift_is_where_the_view_correlates_best_in_level_0_px(texture_factory) -> None:
    texture = texture_factory()
    view = FaceView.of(ImagePyramid.build(texture, 4), NODES, INNER)
    moved = np.roll(texture, (-4, 6), axis=(0, 1))  # 6 px right, 4 px up
    np.testing.assert_array_equal(view.shift(ImagePyramid.build(moved, 4)), [6.0, -4.0])


def test_a_view_of_nodes_beyond_the_image_is_clipped_to_its_corner(texture_factory) -> None:
    """Inner nodes below and right of the image: level 1 (240 x 320) keeps its corner pixel."""
    pyramid = ImagePyramid.build(texture_factory(), 4)
    beyond = np.array([[700.0, 500.0], [720.0, 520.0]])
    view = FaceView.of(pyramid, beyond, np.array([True, True]))
    np.testing.assert_array_equal(view.corner, [319, 239])
    np.testing.assert_array_equal(view.image, pyramid.levels[1][239:240, 319:320])


def test_a_search_with_a_reach_looks_only_that_far_from_the_expected_shift(
    texture_factory,
) -> None:
    """A reach of 0.1 x the view's larger side (101 px on level 1: 20 level-0 px).

    The image moved 40 px right: found from an expected shift near it, not from none; a search
    centred beyond the image looks at its corner.
    """
    texture = texture_factory()
    view = FaceView.of(ImagePyramid.build(texture, 4), NODES, INNER)
    pyramid = ImagePyramid.build(np.roll(texture, 40, axis=1), 4)
    np.testing.assert_array_equal(view.shift(pyramid, np.array([36.0, 2.0]), 0.1), [40.0, 0.0])
    near = view.shift(pyramid, np.zeros(2), 0.1)
    assert np.abs(near).max() <= 20.0
    corner = view.shift(pyramid, np.array([-1000.0, -1000.0]), 0.1)
    np.testing.assert_array_equal(corner, -2.0 * view.corner)


def test_a_pending_view_is_cropped_once_when_asked_for(texture_factory) -> None:
    pyramid = ImagePyramid.build(texture_factory(), 4)
    pending = PendingView(pyramid, NODES, INNER)
    assert pending.reads(pyramid)
    view = pending.view()
    assert not pending.reads(pyramid)
    assert pending.view() is view
    expected = FaceView.of(pyramid, NODES, INNER)
    np.testing.assert_array_equal(view.image, expected.image)
    np.testing.assert_array_equal(view.corner, expected.corner)
