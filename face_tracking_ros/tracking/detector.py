"""Optional automatic initialisation: dlib's 68-point facial landmarks mapped to mesh nodes.

dlib is not a dependency of the package. Install it with::

    pip install dlib-bin face_recognition_models

(``face_recognition_models`` ships ``shape_predictor_68_face_landmarks.dat``; any other copy of
that file can be given instead). The 68 points follow the iBUG 300-W convention; the table below
maps them to the named mesh nodes of :mod:`face_tracking_ros.model.topology` (averages for the eye
centres). The jaw contour is a silhouette, not a point fixed on the skin, so of the face-edge
nodes only the chin is taken from it.
"""

from __future__ import annotations

from collections.abc import Callable
import copy
from dataclasses import dataclass
import importlib.util
from pathlib import Path
from typing import Any

import numpy as np

from face_tracking_ros.errors import ConfigError, FieldError, InputError
from face_tracking_ros.tracking.initialisation import MIN_INIT_NODES, Initialisation

Detector = Callable[[np.ndarray], Initialisation | None]
"""A landmark detector: (H, W) uint8 grey image -> 2-D node positions, or None if no face."""

INSTALL_HINT = 'pip install dlib-bin face_recognition_models'
MODELS_PACKAGE = 'face_recognition_models'
PREDICTOR_FILE = 'shape_predictor_68_face_landmarks.dat'

# Mesh node -> iBUG 68 landmark indices (0-based) whose mean is the node.
IBUG68_TO_NODES: dict[str, tuple[int, ...]] = {
    'right_eye': (36, 37, 38, 39, 40, 41),
    'left_eye': (42, 43, 44, 45, 46, 47),
    'nose_tip': (30,),
    'nose_right': (31,),
    'nose_left': (35,),
    'mouth_right': (48,),
    'mouth_left': (54,),
    'upper_lip_right': (50,),
    'upper_lip': (51,),
    'upper_lip_left': (52,),
    'lower_lip_right': (58,),
    'lower_lip': (57,),
    'lower_lip_left': (56,),
    'right_brow_inner': (21,),
    'right_brow_middle': (19,),
    'right_brow_outer': (17,),
    'left_brow_inner': (22,),
    'left_brow_middle': (24,),
    'left_brow_outer': (26,),
    'right_eye_outer': (36,),
    'right_eye_inner': (39,),
    'left_eye_inner': (42,),
    'left_eye_outer': (45,),
    'chin': (8,),
}


@dataclass(frozen=True)
class DetectorConfig:
    """Tunables of the landmark detector.

    Attributes:
        predictor_path: dlib 68-point shape predictor file; empty: the one of
            ``face_recognition_models``.
        upsample: times dlib's face detector upsamples the image (0-2; more finds smaller
            faces, slower).
    """

    predictor_path: str = ''
    upsample: int = 0

    def __post_init__(self) -> None:
        """Validate the upsampling count."""
        if not 0 <= self.upsample <= 2:
            msg = f'invalid DetectorConfig.upsample = {self.upsample}; use 0, 1 or 2'
            raise FieldError(msg, 'upsample', '0, 1 or 2')


class DlibLandmarkDetector:
    """Finds the largest face and returns its landmarks as 2-D mesh-node positions.

    Usable as the ``detector`` of :class:`~face_tracking_ros.tracking.mono.MonoTracker`.

    Args:
        node_names: the model's node names; landmarks of other nodes are dropped.
        config: tunables; defaults to :class:`DetectorConfig()`.

    Raises:
        ConfigError: if dlib or the predictor file is missing (the message says how to install
            them), or the model has too few nodes with landmarks.
    """

    def __init__(self, node_names: tuple[str, ...], config: DetectorConfig | None = None) -> None:
        """Load dlib's face detector and shape predictor."""
        self._config = config or DetectorConfig()
        dlib = _import('dlib')
        path = self._config.predictor_path or _packaged_predictor()
        try:
            self._predictor = dlib.shape_predictor(str(path))
        except RuntimeError as error:
            msg = f'cannot load the dlib shape predictor {path}: {error}'
            raise ConfigError(msg) from None
        self._face_detector = dlib.get_frontal_face_detector()
        self._nodes = _landmark_nodes(node_names)

    def for_nodes(self, node_names: tuple[str, ...]) -> DlibLandmarkDetector:
        """The same detector (dlib's models shared, not loaded again) for another mesh's nodes.

        Raises:
            ConfigError: if that mesh has too few nodes with landmarks.
        """
        detector = copy.copy(self)
        detector._nodes = _landmark_nodes(node_names)
        return detector

    def landmarks(self, gray: np.ndarray) -> np.ndarray | None:
        """(68, 2) landmark pixels of the largest face in a uint8 grey image, or None.

        Raises:
            InputError: if the image is not a 2-D uint8 array.
        """
        gray = np.asarray(gray)
        if gray.ndim != 2 or gray.dtype != np.uint8:
            msg = f'the detector needs a (H, W) uint8 grey image, got {gray.shape} {gray.dtype}'
            raise InputError(msg)
        faces = self._face_detector(np.ascontiguousarray(gray), self._config.upsample)
        if len(faces) == 0:
            return None
        face = max(faces, key=lambda box: box.width() * box.height())
        shape = self._predictor(gray, face)
        return np.array([[shape.part(i).x, shape.part(i).y] for i in range(68)], dtype=float)

    def __call__(self, gray: np.ndarray) -> Initialisation | None:
        """Mesh-node positions of the largest face, or None if there is no face."""
        points = self.landmarks(gray)
        if points is None:
            return None
        positions = np.array(
            [points[list(IBUG68_TO_NODES[name])].mean(axis=0) for name in self._nodes]
        )
        return Initialisation(node_names=self._nodes, points=positions)


def _landmark_nodes(node_names: tuple[str, ...]) -> tuple[str, ...]:
    """The nodes among ``node_names`` that have landmarks.

    Raises:
        ConfigError: if fewer than an initialisation needs.
    """
    nodes = tuple(name for name in node_names if name in IBUG68_TO_NODES)
    if len(nodes) < MIN_INIT_NODES:
        msg = f'only {len(nodes)} of the model nodes have dlib landmarks'
        raise ConfigError(msg)
    return nodes


def _packaged_predictor() -> str:
    """The 68-point predictor file that ``face_recognition_models`` ships.

    Found without importing the package: its ``__init__`` needs ``pkg_resources``, which recent
    setuptools no longer has.

    Raises:
        ConfigError: if the package is not installed.
    """
    spec = importlib.util.find_spec(MODELS_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        msg = (
            f'automatic initialisation needs {MODELS_PACKAGE!r} (the landmark model), which is '
            f'not installed: {INSTALL_HINT}'
        )
        raise ConfigError(msg)
    return str(Path(spec.submodule_search_locations[0]) / 'models' / PREDICTOR_FILE)


def _import(module: str) -> Any:
    """Import an optional dependency, or raise ConfigError saying how to install it."""
    try:
        return __import__(module)
    except ImportError:
        msg = f'automatic initialisation needs {module!r}, which is not installed: {INSTALL_HINT}'
        raise ConfigError(msg) from None
