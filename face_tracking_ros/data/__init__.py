"""Data files shipped with the package.

``default_model_path(num_nodes)`` is the face model a tracker loads when no model file is given
(``face-tracking learn`` on a synthetic training population); ``default_classifier_path()`` is
the expression classifier trained for it (``face-tracking train-expressions``); both are made
from the synthetic world by ``make default-data``.

``photo_face_paths()`` is a real face photo and its node positions, for rendering synthetic
sequences with real skin instead of the procedural texture (``SceneConfig.texture``): a crop of
NASA's portrait of the astronaut Eileen Collins (public domain; the copy scikit-image ships as
``skimage.data.astronaut``: columns 140-309, rows 40-219 of the 512x512 image), with 30 of the
34 nodes placed by hand (the temples and upper cheeks, under her hair, are left to the warp).
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from face_tracking_ros.errors import ModelFileError


def default_model_path(num_nodes: int = 34) -> Path:
    """Path of the packaged default face model with ``num_nodes`` nodes.

    Raises:
        ModelFileError: if the package was installed without it.
    """
    return _packaged(f'default_model_{num_nodes}.npz', 'default model')


def default_classifier_path() -> Path:
    """Path of the packaged default expression classifier (for the 34-node default model).

    Raises:
        ModelFileError: if the package was installed without it.
    """
    return _packaged('default_expressions.npz', 'default expression classifier')


def photo_face_paths() -> tuple[Path, Path]:
    """Paths of the packaged face photo (PNG) and its JSON ``{node name: [x, y]}`` pixels.

    Raises:
        ModelFileError: if the package was installed without them.
    """
    return _packaged('photo_face.png', 'face photo'), _packaged(
        'photo_face_nodes.json', 'face photo node positions'
    )


def _packaged(name: str, what: str) -> Path:
    """Path of a packaged data file, checked to exist."""
    path = Path(str(files(__name__) / name))
    if not path.is_file():
        msg = f'the packaged {what} {path} is missing; pass a file instead'
        raise ModelFileError(msg)
    return path
