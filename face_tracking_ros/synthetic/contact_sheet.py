"""A contact sheet of the synthetic world: a stereo pair and mono frames with their truth nodes.

The sheet shows what the trackers face: the top row is a rectified stereo pair of a training
sequence (head still, expression at its apex) with the truth nodes of both views and horizontal
lines through a few nodes (a rectified pair puts each node on the same row in both images);
below are frames of free-motion test sequences of other subjects. Nodes the camera sees are
green dots; nodes hidden by the face itself are red crosses.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.geometry.rotation import omega_to_angles
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.synthetic.faces import FacePopulation
from face_tracking_ros.synthetic.motion import Motion
from face_tracking_ros.synthetic.scenes import Kind, SceneConfig, SequenceRenderer, SyntheticFrame

_SHEET_FRAMES = 40  # frames rendered per sequence to choose a tile from
_STEREO_WIDTH = 400  # px of each stereo tile on the sheet
_MONO_WIDTH = 266  # px of each mono tile
_MONO_COLUMNS = 3
_EPIPOLAR_NODES = ('right_eye', 'nose_tip', 'mouth_left')
_GREEN, _RED, _YELLOW, _WHITE = (60, 220, 60), (40, 40, 230), (0, 210, 255), (255, 255, 255)


def draw_truth(
    image: np.ndarray, camera: PinholeCamera, nodes_camera: np.ndarray, visible: np.ndarray
) -> np.ndarray:
    """A BGR copy of an image with the truth nodes drawn.

    Args:
        image: (H, W) mono8 or (H, W, 3) rgb8 image.
        camera: the camera that took it.
        nodes_camera: (34, 3) truth nodes in the reference camera frame, m.
        visible: (34,) bool, nodes this camera sees.

    Returns:
        (H, W, 3) uint8 BGR image.
    """
    if image.ndim == 2:
        canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    else:
        canvas = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    for (x, y), seen in zip(camera.project(nodes_camera), visible, strict=True):
        centre = (round(x * 16), round(y * 16))
        if seen:
            cv2.circle(canvas, centre, 3 * 16, (0, 0, 0), -1, cv2.LINE_AA, 4)
            cv2.circle(canvas, centre, 2 * 16, _GREEN, -1, cv2.LINE_AA, 4)
        else:
            for dx, dy in ((1, 1), (1, -1)):
                start = (centre[0] - 3 * 16 * dx, centre[1] - 3 * 16 * dy)
                end = (centre[0] + 3 * 16 * dx, centre[1] + 3 * 16 * dy)
                cv2.line(canvas, start, end, _RED, 1, cv2.LINE_AA, 4)
    return canvas


def contact_sheet(config: SceneConfig, mono_frames: int = 6) -> np.ndarray:
    """Render the contact sheet of a configuration's world (population, seed, image settings).

    Args:
        config: population preset, seed, image size, encoding, focal length, baseline and
            texture of the world to show; kind, motion and counts are set by the sheet.
        mono_frames: number of mono tiles (subjects 1, 2, ...).

    Returns:
        (H, W, 3) uint8 BGR image.
    """
    population = FacePopulation(config.population, config.seed)
    stereo = replace(config, kind=Kind.STEREO, motion=Motion.STILL, frames=_SHEET_FRAMES, fps=10.0)
    renderer = SequenceRenderer(stereo, 0, population)
    frame = max(renderer.frames(0), key=lambda f: f.truth.intensity)
    pair = [
        _tile(frame, name, renderer.cameras[name], _STEREO_WIDTH) for name in ('left', 'right')
    ]
    _epipolar_lines(pair, frame, renderer.cameras, _STEREO_WIDTH / config.width)
    rows = [np.hstack(pair)]
    mono = replace(
        config, kind=Kind.MONO, motion=Motion.FREE, frames=_SHEET_FRAMES, fps=10.0, occlusion=True
    )
    tiles = []
    for subject in range(1, mono_frames + 1):
        renderer = SequenceRenderer(mono, subject, population)
        pick = max(renderer.frames(0), key=lambda f: f.truth.intensity)
        tiles.append(_tile(pick, 'image', renderer.cameras['image'], _MONO_WIDTH))
    blank = np.zeros_like(tiles[0])
    tiles += [blank] * (-len(tiles) % _MONO_COLUMNS)
    for start in range(0, len(tiles), _MONO_COLUMNS):
        rows.append(np.hstack(tiles[start : start + _MONO_COLUMNS]))
    width = max(row.shape[1] for row in rows)
    padded = [np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0))) for row in rows]
    return np.vstack(padded)


def _tile(frame: SyntheticFrame, name: str, camera: PinholeCamera, width: int) -> np.ndarray:
    """One camera's image of a frame with nodes and a caption, scaled to ``width`` px."""
    truth = frame.truth
    canvas = draw_truth(frame.images[name], camera, truth.nodes_camera, truth.visible[name])
    height = round(canvas.shape[0] * width / canvas.shape[1])
    canvas = cv2.resize(canvas, (width, height), interpolation=cv2.INTER_AREA)
    pitch, yaw, roll = np.degrees(omega_to_angles(truth.omega))
    lines = (
        f'{truth.subject_id} {name} frame {frame.index}',
        f'{truth.label} {truth.intensity:.2f}  z {truth.t[2] * 100:.0f} cm',
        f'yaw {yaw:+.0f} pitch {pitch:+.0f} roll {roll:+.0f} deg',
    )
    box = canvas[: 8 + 15 * len(lines), : int(0.8 * width)]
    box //= 3  # darken behind the caption
    for row, text in enumerate(lines):
        origin = (5, 14 + 15 * row)
        cv2.putText(canvas, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.4, _WHITE, 1, cv2.LINE_AA)
    return canvas


def _epipolar_lines(
    pair: list[np.ndarray],
    frame: SyntheticFrame,
    cameras: dict[str, PinholeCamera],
    scale: float,
) -> None:
    """Draw, across both tiles of a rectified pair, the image rows of a few nodes (in place)."""
    topology = mesh_topology(34)
    for name in _EPIPOLAR_NODES:
        node = frame.truth.nodes_camera[topology.index(name)]
        for tile, camera in zip(pair, (cameras['left'], cameras['right']), strict=True):
            x, y = camera.project(node[None])[0] * scale
            row = round(y * 16)
            cv2.line(tile, (0, row), (tile.shape[1] * 16, row), _YELLOW, 1, cv2.LINE_AA, 4)
            cv2.circle(tile, (round(x * 16), row), 4 * 16, _YELLOW, 1, cv2.LINE_AA, 4)
