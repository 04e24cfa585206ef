"""Labelled parameter sequences: what recognition is trained and scored on.

One :class:`ParameterSequence` is one tracked (or true) sequence of one subject: per frame the
stamp, the shape parameters sigma and action parameters alpha of eq. 3, and the truth labels of
the synthetic world (expression label and intensity, FaceTruth).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from face_tracking_ros.errors import InputError
from face_tracking_ros.wording import counted

Parameter = Literal['sigma', 'alpha']
PARAMETERS: tuple[Parameter, ...] = ('sigma', 'alpha')


@dataclass(frozen=True)
class ParameterSequence:
    """Per-frame parameters and labels of one sequence of one subject.

    Attributes:
        subject_id: who the face is.
        times: (M,) stamps, s, strictly increasing.
        sigma: (M, p) shape parameters (eq. 3).
        alpha: (M, q) action parameters (eq. 3).
        labels: (M,) expression label per frame ('neutral' if none).
        intensity: (M,) expression intensity per frame in [0, 1] (0 for neutral frames).
    """

    subject_id: str
    times: np.ndarray
    sigma: np.ndarray
    alpha: np.ndarray
    labels: np.ndarray
    intensity: np.ndarray

    def __post_init__(self) -> None:
        """Check that every per-frame array has M rows and finite values.

        Raises:
            InputError: naming the subject and the faulty field.
        """
        frames = len(self.times)
        for name in ('times', 'sigma', 'alpha', 'labels', 'intensity'):
            value = np.asarray(getattr(self, name))
            ndim = 2 if name in PARAMETERS else 1
            if value.ndim != ndim or len(value) != frames:
                msg = (
                    f'sequence of {self.subject_id!r}: {name} has shape {value.shape}, expected '
                    f'{counted(frames, "row")} and {counted(ndim, "dimension")}'
                )
                raise InputError(msg)
            if name != 'labels' and not np.all(np.isfinite(value)):
                msg = f'sequence of {self.subject_id!r}: {name} holds NaN or Inf'
                raise InputError(msg)
        if np.any(np.diff(self.times) <= 0.0):
            msg = f'sequence of {self.subject_id!r}: stamps must increase strictly'
            raise InputError(msg)

    def values(self, parameter: Parameter) -> np.ndarray:
        """The (M, p) sigma or (M, q) alpha of the sequence."""
        return self.sigma if parameter == 'sigma' else self.alpha
