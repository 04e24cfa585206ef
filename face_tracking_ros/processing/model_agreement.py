"""Whether a recogniser's file still fits the face model its tracker uses.

An identity gallery holds one face model's sigma and an expression classifier one model's alpha
(each records the model's fingerprint, :attr:`~face_tracking_ros.model.face_model.FaceModel.
fingerprint`). A recogniser checks its file against its ``model_file`` at start; but a tracker
that takes a new model on the latched ``face/model`` (a learner that has just learned one) sends
sigma and alpha of that model from then on, which the file reads as another face: identities
came out 'unknown' and expression events wrong, without a word. So the recognisers listen to
``face/model`` too, and decide nothing while the model there is not the one their file was made
with, saying why.
"""

from __future__ import annotations

from typing import Any

from face_tracking_ros.errors import InputError
from face_tracking_ros.io import conversions
from face_tracking_ros.processing.base import Port, QosClass

# The latched face model a tracker takes a new model from (the trackers' input as well).
MODEL_PORT = Port('face/model', 'face_tracking_msgs/msg/FaceModel', QosClass.LATCHED)


class ModelAgreement:
    """Follows the tracker's face model against the one a recogniser's file was made with."""

    def __init__(self, made_with: str | None, what: str, remedy: str) -> None:
        """Check ``face/model`` against ``made_with``.

        Args:
            made_with: the fingerprint the file records; None (not recorded): nothing to check.
            what: the file, for the message (e.g. 'the identity gallery').
            remedy: what to do about a mismatch, for the message.
        """
        self._made_with = made_with
        self._what = what
        self._remedy = remedy
        self._problem = ''

    def model(self, msg: Any) -> None:
        """Take a FaceModel message from ``face/model``.

        Raises:
            InputError: if the file was made with another model (and from then on, see
                :meth:`check`), or the message is not a valid model.
        """
        fingerprint = conversions.model_from_msg(msg).fingerprint
        self._problem = ''
        if self._made_with is not None and fingerprint != self._made_with:
            self._problem = (
                f'the tracker now uses the face model of {MODEL_PORT.topic} (fingerprint '
                f'{fingerprint}), {self._what} was made with another ({self._made_with}): '
                f'nothing is decided until it is back ({self._remedy})'
            )
        self.check()

    @property
    def problem(self) -> str:
        """Why nothing is to be decided now; '' while the models agree."""
        return self._problem

    def check(self) -> None:
        """Raise while the tracker's model is not the file's.

        Raises:
            InputError: saying so.
        """
        if self._problem:
            raise InputError(self._problem)
