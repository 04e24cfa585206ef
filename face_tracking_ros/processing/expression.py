"""Message-in, message-out expression recognition: the expression_recognizer node and its replay.

Inputs: ``face/action`` (ActionParams) of one tracked face, its tracker's ``face/state``
(FaceState) for the status alone, and the latched ``face/model`` its tracker may take a new model
from (:mod:`.model_agreement`: nothing is recognised while that is not the classifier's
model). Outputs: ``face/expression`` (ExpressionEvent) at every onset
and offset, and, while subscribed, ``face/expression_scores`` (std_msgs/Float64MultiArray: one
posterior per label, the labels in the layout's dimension label, comma-separated), both stamped
with the input's header. A stamp not later than the previous one starts a new track: the feature
window, the neutral baseline and the event state restart, without an event for the old track.

A state that is not TRACKING (the face lost, or a tracker not yet initialised) ends the active
expression with an offset at that state's stamp: the trackers publish no action while the face
is lost, and an action of an image whose state said so (from a tracker that does) is ignored.
The face's neutral baseline stays, and the feature window (a sixth of a second) has dropped the
samples before the loss by the time a longer one ends.

While the states say an occluder covers mouth or brow nodes
(:class:`~.track_status.CoveredExpressions`), for at most ``occlusion_hold`` seconds from the
first such image, the active expression is held: its alpha is not classified (no scores either),
and a LOST state (the face lost behind the occluder) does not end it; one after the hold does, at
its stamp. The tracker has not measured those nodes (the mono tracker places them by the face
model fitted to the others, the stereo tracker moves them with the head), so alpha does not show
what they do: on rendered mono sequences a held expression was ended under the cover and started
again (a surprise whose brows were covered read as jaw_open), or ended at the LOST images behind
it. With no expression active, alpha of covered images is classified as before, so one that the
uncovered nodes show starts on time (no onset under a cover was wrong there).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from face_tracking_ros.data import default_classifier_path, default_model_path
from face_tracking_ros.errors import FieldError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import NS_PER_S, stamp_to_ns
from face_tracking_ros.io.messages import MessageFactory
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.processing.base import Output, Port
from face_tracking_ros.processing.model_agreement import MODEL_PORT, ModelAgreement
from face_tracking_ros.processing.parameters import ParameterSource
from face_tracking_ros.processing.track_status import STATE_PORT, CoveredExpressions, TrackEnds
from face_tracking_ros.recognition.events import (
    EventConfig,
    ExpressionEvent,
    ExpressionEventDetector,
)
from face_tracking_ros.recognition.expression import ExpressionClassifier, ExpressionRecognizer

ACTION = 'face/action'
EVENTS = 'face/expression'
SCORES = 'face/expression_scores'


@dataclass(frozen=True)
class ExpressionNodeConfig:
    """Parameters of the expression_recognizer node besides the event thresholds.

    Attributes:
        classifier_file: expression classifier file (``face-tracking train-expressions``);
            empty: the packaged default, trained on the synthetic world for the default model.
        model_file: face model the tracker uses; a classifier of another q, or trained on another
            model's alpha (``train-expressions --model``), is refused. Empty: the packaged
            default model.
        occlusion_hold: longest time, s, for which an occluder over mouth or brow nodes (the
            tracker's ``FaceState.occluded``) holds the active expression from the cover's first
            image: its alpha is not classified and a LOST state does not end it. 0: no hold (a
            covered image's alpha is classified, a LOST state ends the expression). It bounds how
            long an expression outlives a face lost behind a hand; on rendered mono sequences 1 s
            let a held surprise be ended under a brow cover (the tracker's flags lingered up to a
            second after the occluder had gone, before covered nodes took the keyframe's
            templates), 2 s and 3 s none.
    """

    classifier_file: str = ''
    model_file: str = ''
    occlusion_hold: float = 2.0

    def __post_init__(self) -> None:
        """Validate the hold.

        Raises:
            FieldError: for a hold below 0 or not finite.
        """
        if not 0.0 <= self.occlusion_hold < math.inf:
            msg = f'occlusion_hold must be >= 0 s and finite, got {self.occlusion_hold}'
            raise FieldError(msg, 'occlusion_hold', '>= 0 s and finite')


class ExpressionProcessor:
    """Turns a face's action parameters into expression events (§3.6, §4.5)."""

    def __init__(
        self,
        factory: MessageFactory,
        classifier: ExpressionClassifier,
        events: EventConfig,
        covered: CoveredExpressions,
    ) -> None:
        """Classify with ``classifier``; emit events with the ``events`` hysteresis.

        ``covered`` says at which images an occluder hides the expression: the active one is
        held there.
        """
        self._factory = factory
        self._recognizer = ExpressionRecognizer(classifier)
        self._detector = ExpressionEventDetector(classifier.labels, events)
        self._labels = ','.join(classifier.labels)
        self._last_stamp: int | None = None
        self._track_ends = TrackEnds()
        self._covered = covered
        self._agreement = ModelAgreement(
            classifier.model,
            'the expression classifier',
            'or train one on it: face-tracking train-expressions --model',
        )
        self.inputs = (
            Port(ACTION, 'face_tracking_msgs/msg/ActionParams'),
            STATE_PORT,
            MODEL_PORT,
        )
        self.outputs = (
            Port(EVENTS, 'face_tracking_msgs/msg/ExpressionEvent'),
            Port(SCORES, 'std_msgs/msg/Float64MultiArray', on_demand=True),
        )

    def handle(self, topic: str, msg: Any, wanted: frozenset[str]) -> list[Output]:
        """Classify an ActionParams message, or take a FaceState's status; return the events.

        The scores are returned too when wanted (an ActionParams message).
        """
        if topic == MODEL_PORT.topic:  # alpha from now on is of this model
            self._agreement.model(msg)
            return []
        stamp = stamp_to_ns(msg.header.stamp)
        if topic == STATE_PORT.topic:
            self._covered.update(msg)
            if self._held(stamp):  # lost behind the occluder: the expression goes on
                return []
            return self._end(msg, stamp) if self._track_ends.ended(msg) else []
        if self._track_ends.untracked(stamp) or self._held(stamp):
            return []
        self._agreement.check()
        alpha = conversions.finite_vector(msg.alpha, 'ActionParams.alpha')
        scores = self._recognizer.update(stamp / NS_PER_S, alpha)
        if self._last_stamp is not None and stamp <= self._last_stamp:
            self._detector.reset()
        self._last_stamp = stamp
        header = conversions.copy_header(self._factory, msg.header)
        outputs = [
            Output(EVENTS, self._event_msg(header, msg.face_id, event))
            for event in self._detector.update(scores)
        ]
        if SCORES in wanted:
            outputs.append(Output(SCORES, self._scores_msg(scores.probabilities)))
        return outputs

    def _held(self, stamp: int) -> bool:
        """Whether the active expression is held at the image stamped ``stamp`` (covered)."""
        return self._detector.active is not None and self._covered.held(stamp)

    def _end(self, msg: Any, stamp: int) -> list[Output]:
        """End the active expression at a state that says the face is not tracked."""
        header = conversions.copy_header(self._factory, msg.header)
        return [
            Output(EVENTS, self._event_msg(header, msg.face_id, event))
            for event in self._detector.end(stamp / NS_PER_S)
        ]

    def _event_msg(self, header: Any, face_id: str, event: ExpressionEvent) -> Any:
        return self._factory.make(
            'face_tracking_msgs/msg/ExpressionEvent',
            header=header,
            face_id=face_id,
            label=event.label,
            event=int(event.kind),
            confidence=event.confidence,
            alpha=np.asarray(event.alpha, dtype=float),
            duration=event.duration,
        )

    def _scores_msg(self, probabilities: np.ndarray) -> Any:
        dim = self._factory.make(
            'std_msgs/msg/MultiArrayDimension',
            label=self._labels,
            size=len(probabilities),
            stride=len(probabilities),
        )
        layout = self._factory.make('std_msgs/msg/MultiArrayLayout', dim=[dim], data_offset=0)
        return self._factory.make(
            'std_msgs/msg/Float64MultiArray', layout=layout, data=probabilities.astype(float)
        )


def make_expression_processor(
    params: ParameterSource, factory: MessageFactory
) -> ExpressionProcessor:
    """The expression_recognizer processor configured from parameters (node or replay).

    Parameters: those of :class:`ExpressionNodeConfig`, and ``events.*`` those of
    :class:`~face_tracking_ros.recognition.events.EventConfig`.

    Raises:
        ConfigError: for a bad parameter.
        ModelFileError: for an unusable model or classifier file, or a classifier trained for
            another model.
    """
    config = params.config(ExpressionNodeConfig)
    events = params.config(EventConfig, prefix='events.')
    model = load_model(config.model_file or default_model_path())
    classifier_file = config.classifier_file or default_classifier_path()
    return ExpressionProcessor(
        factory,
        ExpressionClassifier.load(classifier_file, model.q, model.fingerprint),
        events,
        CoveredExpressions(model.topology, config.occlusion_hold),
    )
