"""Draw a tracked mesh on an image (the `face/overlay` topic and `face-tracking overlay`)."""

from __future__ import annotations

import cv2
import numpy as np

from face_tracking_ros.tracking.result import TrackStatus

_STATUS_COLOURS = {
    TrackStatus.TRACKING: (60, 220, 60),
    TrackStatus.INITIALIZING: (240, 200, 40),
    TrackStatus.LOST: (230, 50, 50),
}
_NODE_COLOUR = (255, 90, 30)


def draw_mesh(
    gray: np.ndarray,
    nodes_px: np.ndarray,
    edges: np.ndarray,
    status: TrackStatus,
    label: str = '',
    occluded: np.ndarray | None = None,
) -> np.ndarray:
    """An (H, W, 3) rgb8 copy of a grey image with the mesh drawn on it.

    Args:
        gray: (H, W) uint8 image.
        nodes_px: (N, 2) node projections, px; NaN rows are skipped.
        edges: (E, 2) node index pairs.
        status: tracking status, which sets the colour (green tracking, red lost).
        label: text drawn in the top-left corner.
        occluded: (N,) bool, nodes judged covered by an occluder (FaceState.occluded): rings,
            not dots.
    """
    canvas = cv2.cvtColor(gray, cv2.COLOR_GRAY2RGB)
    colour = _STATUS_COLOURS[TrackStatus(status)]
    valid = np.all(np.isfinite(nodes_px), axis=1)
    shift = 4  # sub-pixel drawing precision: coordinates in 1/16 px
    points = np.round(np.nan_to_num(nodes_px) * (1 << shift)).astype(np.int32)
    for i, j in edges:
        if valid[i] and valid[j]:
            cv2.line(canvas, points[i], points[j], colour, 1, cv2.LINE_AA, shift)
    held = np.zeros(len(points), dtype=bool) if occluded is None else occluded
    for point, ring in zip(points[valid], held[valid], strict=True):
        radius, thickness = (3, 1) if ring else (2, -1)
        cv2.circle(canvas, point, radius << shift, _NODE_COLOUR, thickness, cv2.LINE_AA, shift)
    if label:
        cv2.putText(canvas, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1, cv2.LINE_AA)
    return canvas
