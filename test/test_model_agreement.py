"""The recognisers decide nothing while their tracker's face/model is not their file's model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import InputError
from face_tracking_ros.io import conversions
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.processing.expression import make_expression_processor
from face_tracking_ros.processing.identity import make_identity_processor
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.recognition.identity import IdentityConfig, IdentityGallery

FACTORY = RosbagsMessages(typestore())
NONE: frozenset[str] = frozenset()
NS = 1_000_000_000


def _model_msg(model):
    return conversions.model_to_msg(FACTORY, conversions.make_header(FACTORY, 0, ''), model)


def _shape(stamp_ns: int, sigma) -> object:
    header = conversions.make_header(FACTORY, stamp_ns, 'camera')
    return FACTORY.make('face_tracking_msgs/msg/ShapeParams', header=header, sigma=sigma)


def _action(stamp_ns: int, alpha) -> object:
    header = conversions.make_header(FACTORY, stamp_ns, 'camera')
    return FACTORY.make('face_tracking_msgs/msg/ActionParams', header=header, alpha=alpha)


@pytest.fixture(scope='module')
def models():
    """The packaged model (the files' own) and another of the same p and q."""
    default = load_model(default_model_path())
    return default, replace(default, shape_basis=-default.shape_basis)


def test_identity_decisions_stop_while_the_tracker_uses_another_model(tmp_path, models):
    """A learner's new model on face/model mid-run: its sigma was read as the gallery's."""
    default, other = models
    gallery = tmp_path / 'gallery.npz'
    sigma = np.array([0.01, -0.02])
    empty = IdentityGallery.empty(default.p, default.fingerprint)
    empty.enroll('ann', sigma[None], IdentityConfig()).save(gallery)
    processor = make_identity_processor(
        OverrideParameters({'gallery_file': str(gallery)}), FACTORY
    )
    decided = [
        processor.handle('face/shape', _shape(k * NS // 10, sigma), NONE) for k in range(11)
    ]
    assert [o.msg.identity for outputs in decided for o in outputs] == ['ann']
    with pytest.raises(InputError, match='now uses the face model of face/model .fingerprint'):
        processor.handle('face/model', _model_msg(other), NONE)
    with pytest.raises(InputError, match='the identity gallery was made with another'):
        processor.handle('face/shape', _shape(2 * NS, sigma), NONE)
    with pytest.raises(InputError, match='the identity gallery was made with another'):
        processor.enroll('bob', 1.0)
    assert 'the identity gallery was made with another' in processor.warning()  # the status's
    assert processor.handle('face/model', _model_msg(default), NONE) == []  # back: decided again
    assert processor.warning() == ''
    decided = [
        processor.handle('face/shape', _shape(3 * NS + k * NS // 10, sigma), NONE)
        for k in range(11)
    ]
    assert [o.msg.identity for outputs in decided for o in outputs] == ['ann']


def test_expressions_are_not_recognised_while_the_tracker_uses_another_model(models):
    default, other = models
    processor = make_expression_processor(OverrideParameters(), FACTORY)  # packaged: default's
    alpha = np.zeros(default.q)
    assert processor.handle('face/action', _action(0, alpha), NONE) == []
    with pytest.raises(InputError, match='the expression classifier was made with another'):
        processor.handle('face/model', _model_msg(other), NONE)
    with pytest.raises(InputError, match='train-expressions --model'):
        processor.handle('face/action', _action(NS // 30, alpha), NONE)
    assert processor.handle('face/model', _model_msg(default), NONE) == []  # back: recognised
    assert processor.handle('face/action', _action(2 * NS // 30, alpha), NONE) == []
