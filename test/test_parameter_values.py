"""Bad parameter values are refused by name before any work, as the nodes and replay read them.

The configs are built as :class:`~face_tracking_ros.processing.parameters.OverrideParameters`
builds them for ``--param`` (the live node's source goes through the same
:func:`~face_tracking_ros.processing.parameters.build_config`).
"""

from __future__ import annotations

import re

import pytest

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.stereo import StereoNodeConfig
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.pose_filter import PoseFilterConfig
from face_tracking_ros.tracking.stereo import StereoTrackerConfig

TRACKER = 'tracker.'

# (config, prefix, parameter): a float whose range check alone (> 0, >= 0) let inf through.
UNBOUNDED_FLOATS = [
    (MonoTrackerConfig, TRACKER, 'damping'),
    (MonoTrackerConfig, TRACKER, 'patch_spacing_px'),
    (MonoTrackerConfig, TRACKER, 'residual_scale_floor'),
    (MonoTrackerConfig, TRACKER, 'prior_weight'),
    (MonoTrackerConfig, TRACKER, 'max_condition'),
    (MonoTrackerConfig, TRACKER, 'bundle.weight'),
    (MonoTrackerConfig, TRACKER, 'bundle.surface_prior'),
    (StereoTrackerConfig, TRACKER, 'huber_k'),
    (StereoTrackerConfig, TRACKER, 'texture_weight'),
    (StereoTrackerConfig, TRACKER, 'model_weight_inner'),
    (StereoTrackerConfig, TRACKER, 'init.max_depth'),
    (StereoTrackerConfig, TRACKER, 'init.max_face_scale'),
    (StereoTrackerConfig, TRACKER, 'init.max_face_error'),
    (PoseFilterConfig, 'smoothing.', 'beta_rotation'),
    (StereoNodeConfig, '', 'pairing_tolerance_ms'),
]


def _refused(config: type, prefix: str, name: str, value: str) -> str:
    """The message of the ConfigError ``--param prefix+name=value`` raises."""
    with pytest.raises(ConfigError) as error:
        OverrideParameters.parse([f'{prefix}{name}={value}']).config(config, prefix)
    return str(error.value)


@pytest.mark.parametrize(('config', 'prefix', 'name'), UNBOUNDED_FLOATS)
@pytest.mark.parametrize('value', ['inf', 'nan'])
def test_a_float_parameter_that_is_not_finite_is_refused_by_name(config, prefix, name, value):
    message = _refused(config, prefix, name, value)
    assert re.fullmatch(rf'invalid parameter {prefix}{name} = {value} \(.*\)', message)
    if value != 'nan':  # NaN fails the range check itself
        assert message.endswith('(expected a finite number)')
