"""Data files shipped with the package, made from the synthetic world by ``make default-data``.

``default_model_path(num_nodes)`` is the face model a tracker loads when no model file is given
(``face-tracking learn`` on a synthetic training population); ``default_classifier_path()`` is
the expression classifier trained for it (``face-tracking train-expressions``).
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
    return _packaged(f'default_model_{num_nodes}.npz', 'model')


def default_classifier_path() -> Path:
    """Path of the packaged default expression classifier (for the 34-node default model).

    Raises:
        ModelFileError: if the package was installed without it.
    """
    return _packaged('default_expressions.npz', 'expression classifier')


def _packaged(name: str, what: str) -> Path:
    """Path of a packaged data file, checked to exist."""
    path = Path(str(files(__name__) / name))
    if not path.is_file():
        msg = f'the packaged default {what} {path} is missing; pass a file instead'
        raise ModelFileError(msg)
    return path
