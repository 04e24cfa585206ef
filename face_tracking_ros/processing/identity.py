"""Message-in, message-out identity recognition: the identity_recognizer node and its replay.

Inputs: ``face/shape`` (ShapeParams) of one tracked face, its tracker's ``face/state``
(FaceState) for the status alone, and the latched ``face/model`` its tracker may take a new model
from (:mod:`.model_agreement`: nothing is decided, or enrolled, while that is not the gallery's
model). Output: ``face/identity`` (IdentityEvent) whenever the decision
changes, stamped with the input's header. Enrolment (:meth:`IdentityProcessor.enroll`, the
``enroll_identity`` service) adds the tracked face to the gallery from its sigma estimates of the
last ``duration`` seconds and saves the gallery. A stamp not later than the previous one starts
a new track: the decision window restarts and the next decision is published even if it names
the same person. So does a state that is not TRACKING (the face lost: the next track may be
another person's), which also empties the enrolment history; a shape of an image whose state
said so (from a tracker that publishes on while the face is lost) is ignored.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import NS_PER_S, stamp_to_ns
from face_tracking_ros.io.messages import MessageFactory
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.processing.base import Output, Port
from face_tracking_ros.processing.model_agreement import MODEL_PORT, ModelAgreement
from face_tracking_ros.processing.parameters import ParameterSource
from face_tracking_ros.processing.track_status import STATE_PORT, TrackEnds
from face_tracking_ros.recognition.features import STAMP_TOLERANCE, SlidingWindow
from face_tracking_ros.recognition.identity import (
    IdentityConfig,
    IdentityDecision,
    IdentityGallery,
    IdentityRecognizer,
)

SHAPE = 'face/shape'
IDENTITY = 'face/identity'


@dataclass(frozen=True)
class IdentityNodeConfig:
    """Parameters of the identity_recognizer node besides the decision's own.

    Attributes:
        gallery_file: the enrolment gallery; read at start if it exists, written after every
            enrolment. Empty: an in-memory gallery, lost at exit.
        model_file: face model the tracker uses; a gallery of another p, or enrolled with another
            model, is refused (the gallery records its model). Empty: the packaged default
            model.
        max_enroll_duration: longest enrolment (EnrollIdentity.duration) accepted, s (finite, >
            1e-6: the sliding windows' stamp tolerance); this much sigma history is kept.
    """

    gallery_file: str = ''
    model_file: str = ''
    max_enroll_duration: float = 30.0


class IdentityProcessor:
    """Decides who the tracked face is from its sigma (§3.6) and enrols new people."""

    def __init__(
        self,
        factory: MessageFactory,
        gallery: IdentityGallery,
        config: IdentityConfig,
        node_config: IdentityNodeConfig,
    ) -> None:
        """Start from ``gallery``; decide on ``config.window`` seconds of sigma.

        Raises:
            ConfigError: if ``node_config.max_enroll_duration`` is not finite and above
                :data:`STAMP_TOLERANCE` s.
        """
        if not STAMP_TOLERANCE < node_config.max_enroll_duration < math.inf:
            limit, value = STAMP_TOLERANCE, node_config.max_enroll_duration
            msg = f'max_enroll_duration must be > {limit} s and finite, got {value}'
            raise ConfigError(msg)
        self._factory = factory
        self._node_config = node_config
        self._config = config
        self._recognizer = IdentityRecognizer(gallery, config)
        self._history = SlidingWindow(node_config.max_enroll_duration, gallery.p)
        self._last: tuple[str, str] | None = None
        self._track_ends = TrackEnds()
        self._agreement = ModelAgreement(
            gallery.model, 'the identity gallery', 'or enrol the people again with it'
        )
        self.inputs = (Port(SHAPE, 'face_tracking_msgs/msg/ShapeParams'), STATE_PORT, MODEL_PORT)
        self.outputs = (Port(IDENTITY, 'face_tracking_msgs/msg/IdentityEvent'),)

    @property
    def gallery(self) -> IdentityGallery:
        """The current gallery."""
        return self._recognizer.gallery

    def status(self) -> dict[str, str]:
        """The enrolled identities and where they are kept (see ``Reporting``).

        With an empty gallery nothing is decided (no IdentityEvent) until the first enrolment;
        a gallery_file that does not exist (the first enrolment writes it, or the path is
        misspelt) says so here.
        """
        path = self._node_config.gallery_file
        if not path:
            kept = 'none given: enrolments are not saved'
        elif Path(path).exists():
            kept = path
        elif not Path(path).parent.is_dir():
            kept = f'{path}: no directory {Path(path).parent}, enrolments cannot be saved'
        else:
            kept = f'{path} does not exist yet (the first enrolment writes it)'
        return {'identities': ', '.join(self.gallery.names) or 'none', 'gallery_file': kept}

    def warning(self) -> str:
        """Why nothing is decided, while the tracker's model is not the gallery's; else ''."""
        return self._agreement.problem

    def handle(self, topic: str, msg: Any, wanted: frozenset[str]) -> list[Output]:
        """Add a sigma estimate, or take a FaceState's status; an IdentityEvent if it changed."""
        if topic == STATE_PORT.topic:
            if self._track_ends.ended(msg):
                self._start_over()
            return []
        if topic == MODEL_PORT.topic:  # sigma from now on is of this model
            self._start_over()
            self._agreement.model(msg)
            return []
        self._agreement.check()
        stamp_ns = stamp_to_ns(msg.header.stamp)
        if self._track_ends.untracked(stamp_ns):
            return []
        sigma = conversions.finite_vector(msg.sigma, 'ShapeParams.sigma')
        stamp = stamp_ns / NS_PER_S
        if self._history.push(stamp, sigma):
            self._last = None
        decision = self._recognizer.update(stamp, sigma)
        if decision is None or (msg.face_id, decision.identity) == self._last:
            return []
        self._last = (msg.face_id, decision.identity)
        return [Output(IDENTITY, self._event_msg(msg, decision))]

    def _start_over(self) -> None:
        """The track has ended: the next is decided, and enrolled, from its own sigma."""
        self._recognizer.reset()
        self._history.clear()
        self._last = None

    def enroll(self, name: str, duration: float) -> int:
        """Enrol the tracked face as ``name`` from its sigma of the last ``duration`` seconds.

        Returns:
            The number of sigma samples used.

        Raises:
            ConfigError: for a duration out of range, no samples yet, a bad name, samples the
                gallery holds under another name (:meth:`IdentityGallery.enrolled_as`), or a
                gallery file that cannot be written (the gallery then stays as it was).
            InputError: while the tracker's face model is not the gallery's
                (:mod:`.model_agreement`).
        """
        self._agreement.check()
        if not 0 < duration <= self._node_config.max_enroll_duration:
            limit = self._node_config.max_enroll_duration
            msg = f'enrolment duration must be in (0, {limit}] s, got {duration}'
            raise ConfigError(msg)
        times, values = self._history.times, self._history.values
        recent = values[times >= times[-1] - duration] if len(times) else values
        if not len(recent):
            msg = f'cannot enrol {name!r}: no shape estimate of the tracked face yet'
            raise ConfigError(msg)
        twin = self.gallery.enrolled_as(recent)
        if twin is not None and twin != name:  # sigma is fixed in a track once adjusted
            msg = (
                f'cannot enrol {name!r}: the tracked face is enrolled as {twin!r} (the same '
                f'mean sigma): under two names the two entries would tie; enrol it as {twin!r} '
                'to replace that entry'
            )
            raise ConfigError(msg)
        gallery = self.gallery.enroll(name, recent, self._config)
        if self._node_config.gallery_file:
            try:
                gallery.save(self._node_config.gallery_file)
            except OSError as error:
                msg = f'cannot enrol {name!r}: the gallery cannot be saved ({error})'
                raise ConfigError(msg) from None
        self._recognizer = IdentityRecognizer(gallery, self._config)
        self._last = None
        return len(recent)

    def _event_msg(self, msg: Any, decision: IdentityDecision) -> Any:
        return self._factory.make(
            'face_tracking_msgs/msg/IdentityEvent',
            header=conversions.copy_header(self._factory, msg.header),
            face_id=msg.face_id,
            identity=decision.identity,
            distance=decision.distance,
            confidence=decision.confidence,
        )


def make_identity_processor(params: ParameterSource, factory: MessageFactory) -> IdentityProcessor:
    """The identity_recognizer processor configured from parameters (node or replay).

    Parameters: those of :class:`IdentityNodeConfig`, and ``identity.*`` those of
    :class:`~face_tracking_ros.recognition.identity.IdentityConfig`.

    Raises:
        ConfigError: for a bad parameter.
        ModelFileError: for an unusable model or gallery file, or a gallery of another model.
    """
    node_config = params.config(IdentityNodeConfig)
    config = params.config(IdentityConfig, prefix='identity.')
    model = load_model(node_config.model_file or default_model_path())
    gallery_file = node_config.gallery_file
    gallery = (
        IdentityGallery.load(gallery_file, model.p, model.fingerprint)
        if gallery_file and Path(gallery_file).exists()
        else IdentityGallery.empty(model.p, model.fingerprint)
    )
    return IdentityProcessor(factory, gallery, config, node_config)
