"""Rendered faces with one scripted expression, tracked, their outputs fed to the recogniser.

For the tests of the expression recogniser on real tracks: a synthetic sequence whose expression
script (and occluder pass) a test sets, every image's ``face/state`` and ``face/action`` as the
tracker publishes them, and the events the expression processor makes of them (the checks of
:func:`one_expression` are rewritten by pytest: conftest.py registers this module).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from itertools import islice

from face_tracking_ros.io import conversions
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.processing.base import Output
from face_tracking_ros.processing.expression import make_expression_processor
from face_tracking_ros.processing.face_outputs import face_outputs
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.recognition.evaluation import Segment, score_events
from face_tracking_ros.recognition.events import EventKind, ExpressionEvent
from face_tracking_ros.synthetic.motion import ExpressionScript, ExpressionSegment
from face_tracking_ros.synthetic.scenes import SequenceRenderer, SyntheticFrame
from face_tracking_ros.tracking.result import TrackResult

FACTORY = RosbagsMessages(typestore())
RECOGNISED = ('face/state', 'face/action')


def scripted_frames(
    renderer: SequenceRenderer,
    frames: int,
    script: ExpressionScript,
    occluder_pass: tuple[float, float] | None = None,
) -> list[SyntheticFrame]:
    """The first ``frames`` of the renderer's first sequence, with ``script``.

    ``occluder_pass``: the occluder's (start, duration), s, instead of the sequence's own.
    """
    scripted = renderer.frames(0, script=script, occluder_pass=occluder_pass)
    return list(islice(scripted, frames))


def recognised_outputs(
    frames: Sequence[SyntheticFrame],
    step: Callable[[SyntheticFrame], TrackResult],
    frame_id: str,
    model: FaceModel,
) -> list[list[Output]]:
    """Per frame, the ``face/state`` and ``face/action`` the tracker's ``step`` publishes."""
    outputs = []
    for frame in frames:
        header = conversions.make_header(FACTORY, frame.stamp_ns, frame_id)
        published = face_outputs(FACTORY, header, 'face_0', step(frame), model.topology)
        outputs.append([output for output in published if output.topic in RECOGNISED])
    return outputs


def one_expression(
    frames: Sequence[SyntheticFrame], outputs: list[list[Output]], segment: ExpressionSegment
) -> list[ExpressionEvent]:
    """The recogniser's events, checked to be the onset and the offset of ``segment`` alone."""
    start = frames[0].stamp_ns / 1e9
    truth = [Segment(segment.label, start + segment.start, start + segment.end)]
    events = expression_events(outputs, {})
    score = score_events(events, truth)
    assert (score.true_positives, score.false_positives) == (1, 0), events
    kinds = [(event.label, event.kind) for event in events]
    assert kinds == [(segment.label, EventKind.ONSET), (segment.label, EventKind.OFFSET)]
    return events


def expression_events(
    outputs: list[list[Output]], params: dict[str, str]
) -> list[ExpressionEvent]:
    """The expression processor's events (with ``params``) from the outputs, in their order."""
    processor = make_expression_processor(OverrideParameters(params), FACTORY)
    events = []
    for image in outputs:
        for output in image:
            for event in processor.handle(output.topic, output.msg, frozenset()):
                msg = event.msg
                stamp = conversions.stamp_to_ns(msg.header.stamp) / 1e9
                kind = EventKind(msg.event)
                events.append(ExpressionEvent(stamp, msg.label, kind, msg.confidence, [], 0.0))
    return events
