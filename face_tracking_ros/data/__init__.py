"""Data files shipped with the package: the default face models learned from the synthetic world.

``default_model_path(num_nodes)`` is the model a tracker loads when no model file is given; it is
made by ``make default-model`` (``face-tracking learn`` on a synthetic training population).
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from face_tracking_ros.errors import ModelFileError


def default_model_path(num_nodes: int = 34) -> Path:
    """Path of the packaged default model with ``num_nodes`` nodes.

    Raises:
        ModelFileError: if the package was installed without it.
    """
    path = Path(str(files(__name__) / f'default_model_{num_nodes}.npz'))
    if not path.is_file():
        msg = f'the packaged default model {path} is missing; pass a model file instead'
        raise ModelFileError(msg)
    return path
