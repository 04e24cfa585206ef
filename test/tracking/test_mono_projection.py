"""FaceProjection.sample (tracking/mono_projection.py): which ROI samples count as inside."""

from __future__ import annotations

import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.imaging import ImagePyramid
from face_tracking_ros.tracking.mono_projection import FaceProjection
from face_tracking_ros.tracking.mono_rois import Params, Roi

CAMERA = PinholeCamera.ideal()  # 640 x 480, focal 600 px, centre (319.5, 239.5)
DEPTH = 0.5


def test_a_sample_is_inside_when_its_central_differences_read_the_image(model_factory) -> None:
    """A sample counts where x - 1 and x + 1 (y - 1, y + 1) read real pixels: 1 px inside.

    The solver's gradients are central differences one pixel either side of each sample
    (``sample_with_gradient_xy``); one nearer the border than 1 px reads the replicated border.
    Every node's ROI is made to land on the same hand-placed pixels on the centre row (then
    column) of a 640 x 480 image, whose last pixel is 639 (479): by hand, 0.5 and 638.5 are out
    (0.5 - 1 < 0, 638.5 + 1 > 639), 1.5, 2.5 and 637.5 in; on y 0.5 and 478.5 out, 1.5 and
    477.5 in.
    """
    model = model_factory(planar=True)
    shape = model.shape()
    xs = np.array([0.5, 1.5, 2.5, 637.5, 638.5])
    ys = np.array([0.5, 1.5, 477.5, 478.5])
    pixels = np.concatenate(
        [
            np.column_stack([xs, np.full(xs.size, 239.5)]),
            np.column_stack([np.full(ys.size, 319.5), ys]),
        ]
    )
    # Face-frame points (omega = 0, t = (0, 0, DEPTH)) seen at those pixels, as offsets from
    # every node: (3, N, M).
    points = np.column_stack([(pixels - [319.5, 239.5]) * DEPTH / 600.0, np.zeros(len(pixels))])
    offsets = np.ascontiguousarray((points[None, :, :] - shape[:, None, :]).transpose(2, 0, 1))
    p, q = model.shape_basis.shape[1], model.action_basis.shape[1]
    count, size = offsets.shape[1:]
    roi = Roi(offsets, np.zeros((q, 3, count, size)), np.zeros((p, 3, count, size)), np.zeros(p))
    params = Params(np.zeros(3), np.array([0.0, 0.0, DEPTH]), np.zeros(q), np.zeros(p))
    face = FaceProjection(model, CAMERA, num_levels=1, visibility_cos=0.2)
    pyramid = ImagePyramid.build(np.zeros((480, 640), np.float32), 1)

    sampled = face.sample(pyramid, params, 0, roi)

    _, (x, y) = face.roi_points(params, face.level_cameras[0], roi)
    assert np.allclose(x[0], pixels[:, 0], atol=1e-3)
    assert np.allclose(y[0], pixels[:, 1], atol=1e-3)
    expected = [False, True, True, True, False, False, True, True, False]
    assert sampled.inside.shape == (count, size)
    assert (sampled.inside == np.array(expected)).all()
