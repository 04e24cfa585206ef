"""Bad parameter values are refused by name before any work, as the nodes and replay read them.

The configs are built as :class:`~face_tracking_ros.processing.parameters.OverrideParameters`
builds them for ``--param`` (the live node's source goes through the same
:func:`~face_tracking_ros.processing.parameters.build_config`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import re

import numpy as np
import pytest

from face_tracking_ros.errors import ConfigError, FieldError, check_fields
from face_tracking_ros.nodes.learner import LearnerConfig, learn_options
from face_tracking_ros.processing.mono import MonoNodeConfig
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.stereo import StereoNodeConfig
from face_tracking_ros.recognition.events import EventConfig
from face_tracking_ros.recognition.identity import IdentityConfig
from face_tracking_ros.tracking.detector import DetectorConfig
from face_tracking_ros.tracking.mono_config import MonoTrackerConfig
from face_tracking_ros.tracking.pose_filter import PoseFilterConfig
from face_tracking_ros.tracking.stereo_config import StereoTrackerConfig

from repo_root import REPO

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
    assert re.fullmatch(rf'invalid parameter {prefix}{name} = {value}(: | \().*', message)
    if value != 'nan':  # NaN fails the range check itself
        assert message.endswith('(expected a finite number)')


@dataclass(frozen=True)
class _Given:
    """A field of any value, for :func:`check_fields` with its range check passed."""

    value: object


@pytest.mark.parametrize(
    'value', [np.float32('inf'), np.float16('-inf'), np.longdouble('nan'), np.float64('nan')]
)
def test_a_numpy_float_field_that_is_not_finite_is_refused_by_name(value):
    refused = r'^invalid _Given\.value = .*, expected a finite number$'
    with pytest.raises(FieldError, match=refused):
        check_fields(_Given(value), {'value': True})
    with pytest.raises(FieldError, match=r'^invalid PoseFilterConfig\.beta_rotation = '):
        PoseFilterConfig(beta_rotation=value)  # a direct caller's, not a parameter's, value


@pytest.mark.parametrize(
    'value', [np.float32(2.5), np.int64(2**62), np.bool_(True), True, 3, 'inf', None]
)
def test_finite_floats_and_other_types_pass_the_finiteness_check(value):
    check_fields(_Given(value), {'value': True})  # no error


# (config, prefix, parameter, value, what the message says is expected, or ': ' and the start of
# the parameter's description when the check says no more): configs that check their fields
# with messages of their own, which named them without the parameter's prefix (on_threshold for
# events.on_threshold) or not at all (tracker.fit.*).
OWN_CHECKS = [
    (
        MonoTrackerConfig,
        TRACKER,
        'fit.pixel_noise',
        '0.0',
        r': standard deviation of the given 2-D points, px \(> 0\); scales the',
    ),
    (MonoTrackerConfig, TRACKER, 'fit.prior_weight', 'inf', 'expected a finite number'),
    (
        MonoTrackerConfig,
        TRACKER,
        'fit.max_rms_px',
        '-1.0',
        r': a fit whose RMS reprojection error exceeds this is rejected, px \(> 0\)',
    ),
    (
        StereoTrackerConfig,
        TRACKER,
        'regularisation.beta',
        '-1.0',
        r': beta_ij of the stiffest edges: cost of differential motion, grey\^2 / m\^2, >= 0\.',
    ),
    (StereoTrackerConfig, TRACKER, 'regularisation.delta', 'inf', 'expected a finite number'),
    (StereoTrackerConfig, TRACKER, 'regularisation.mouth', '2.0', r'expected in \[0, 1\]'),
    (DetectorConfig, 'detector.', 'upsample', '3', 'expected 0, 1 or 2'),
    (StereoTrackerConfig, TRACKER, 'num_nodes', '20', r': mesh size, 19 or 34\.'),
    (EventConfig, 'events.', 'on_threshold', '1.5', r'expected in \(0, 1\]'),
    (EventConfig, 'events.', 'off_threshold', '0.9', r'expected in \[0, on_threshold=0.6\)'),
    (EventConfig, 'events.', 'min_duration', 'inf', 'expected >= 0 s and finite'),
    (IdentityConfig, 'identity.', 'min_std', '2.0', r'expected in \(0, 1.0\] m'),
    (IdentityConfig, 'identity.', 'acceptance', '1.0', r'expected in \(0, 1\)'),
    (IdentityConfig, 'identity.', 'window', 'nan', 'expected > 1e-06 s and finite'),
]


@pytest.mark.parametrize(('config', 'prefix', 'name', 'value', 'expected'), OWN_CHECKS)
def test_a_value_out_of_range_is_named_as_its_parameter(config, prefix, name, value, expected):
    message = _refused(config, prefix, name, value)
    assert re.match(rf'invalid parameter {prefix}{name} = {value}{_tail(expected)}', message)


def _tail(expected: str) -> str:
    """What follows the value in the message: ' (expected ...)', or ': ' and the description."""
    return expected if expected.startswith(':') else rf' \({expected}\)$'


@pytest.mark.parametrize(
    ('name', 'value', 'expected'),
    [
        ('output', '', r': model file to write \(\.npz\)\.'),
        ('simulate_clicks', 'nan', 'expected a finite number'),  # was off, as a negative
        ('simulate_clicks', 'inf', 'expected a finite number'),
    ],
)
def test_a_learner_value_is_refused_by_name(name, value, expected):
    message = _refused(LearnerConfig, '', name, value)
    assert re.fullmatch(rf"invalid parameter {name} = '?{value}'?{_tail(expected)}", message)


@pytest.mark.parametrize('config', [MonoNodeConfig, StereoNodeConfig])
def test_an_empty_or_blank_face_id_is_refused_by_name(config):
    """``--param face_id=`` (or ``-p face_id:=' '``) tracked faces with no face_id."""
    message = _refused(config, '', 'face_id', '')  # --param strips the value
    assert message == "invalid parameter face_id = '': face_id of the outputs; not empty or blank."
    with pytest.raises(ConfigError, match=rf"invalid {config.__name__}.face_id = ' '"):
        config(face_id=' ')
    assert config(face_id=' face 1 ').face_id == ' face 1 '  # as given


def test_a_learner_bag_dir_that_is_not_a_directory_is_named(tmp_path):
    """It was a FileNotFoundError / NotADirectoryError traceback from iterdir."""
    (tmp_path / 'file').write_text('')
    for bag_dir, kind in (('absent', 'no such directory'), ('file', 'not a directory')):
        config = LearnerConfig(bag_dir=str(tmp_path / bag_dir))
        expected = (
            f'parameter bag_dir: {tmp_path / bag_dir}: {kind} (expected a directory of bags)'
        )
        with pytest.raises(ConfigError, match=re.escape(expected)):
            learn_options(config)


def _directory(path: Path, files: tuple[str, ...], directories: tuple[str, ...] = ()) -> Path:
    """``path``, made with empty ``files`` (their directories made) and empty ``directories``."""
    for file in files:
        (path / file).parent.mkdir(parents=True, exist_ok=True)
        (path / file).write_text('')
    for directory in directories:
        (path / directory).mkdir(parents=True)
    return path


def test_a_learner_bag_dir_gives_its_bags_and_names_its_other_directories(tmp_path):
    """Bags as directories (metadata.yaml or .mcap files) and as lone .mcap files.

    Sub-directories that are no bags are skipped and named; before, each was given as a bag,
    which the learning then refused. A bag given as bag_dir is named.
    """
    bags = ('b_seq/metadata.yaml', 'c_seq/c_seq_0.mcap', 'a_seq.mcap')
    mixed = _directory(tmp_path / 'mixed', (*bags, 'notes.txt', 'r_meshes/x.yaml'), ('plots',))
    said: list[str] = []
    options = learn_options(LearnerConfig(bag_dir=str(mixed)), say=said.append)
    assert options.bags == (mixed / 'a_seq.mcap', mixed / 'b_seq', mixed / 'c_seq')
    assert said == [
        f'parameter bag_dir: {mixed}: skipped plots, r_meshes (sub-directories without '
        'metadata.yaml or .mcap files)'
    ]
    others = _directory(tmp_path / 'others', ('r_meshes/x.yaml',), ('plots',))
    expected = (
        f'parameter bag_dir: {others} holds no bags (sub-directories without metadata.yaml or '
        '.mcap files: plots, r_meshes)'
    )
    with pytest.raises(ConfigError, match=re.escape(expected)):
        learn_options(LearnerConfig(bags=('a',), bag_dir=str(others)))
    empty = _directory(tmp_path / 'empty', ('notes.txt',))
    expected = f'parameter bag_dir: {empty} holds no bags (no sub-directory, no .mcap file)'
    with pytest.raises(ConfigError, match=re.escape(expected)):
        learn_options(LearnerConfig(bag_dir=str(empty)))
    bag = REPO / 'bags' / 'stereo_train' / 'subject_00_seq_00'
    expected = f'parameter bag_dir: {bag} is a bag itself, not a directory of bags: give it in'
    with pytest.raises(ConfigError, match=re.escape(expected)):
        learn_options(LearnerConfig(bag_dir=str(bag)))


@pytest.mark.parametrize('refused', ['iterdir', 'is_file'])
def test_a_learner_bag_dir_that_cannot_be_listed_is_named(tmp_path, monkeypatch, refused):
    """A directory one may not read (iterdir) or not enter (is_file of its metadata.yaml).

    Either's PermissionError was a traceback (Path.is_file raises it, as it does not mean the
    file is absent).
    """

    def refuse(path: Path) -> None:
        raise PermissionError(13, 'Permission denied', str(path))

    (tmp_path / 'bag').mkdir()
    monkeypatch.setattr(Path, refused, refuse)
    expected = f'parameter bag_dir: {tmp_path}: cannot list it: Permission denied'
    with pytest.raises(ConfigError, match=re.escape(expected)):
        learn_options(LearnerConfig(bag_dir=str(tmp_path)))


@pytest.mark.parametrize(
    ('config', 'name', 'largest'),
    [
        (MonoTrackerConfig, 'patch_half_size', 15),
        (StereoTrackerConfig, 'patch_half_size', 15),
        (StereoTrackerConfig, 'texture_subdivisions', 16),
        (StereoTrackerConfig, 'init.match_half_size', 30),
        (StereoTrackerConfig, 'init.refine_half_size', 15),
    ],
)
def test_a_patch_too_large_for_memory_is_refused_by_name(config, name, largest):
    """At 1000 the mono tracker asked for 34 GiB, the stereo matching for 69 GiB."""
    given = OverrideParameters.parse([f'{TRACKER}{name}={largest}']).config(config, TRACKER)
    for part in name.split('.'):
        given = getattr(given, part)
    assert given == largest
    message = _refused(config, TRACKER, name, str(largest + 1))
    assert message.startswith(f'invalid parameter {TRACKER}{name} = {largest + 1}')


def test_a_parameter_written_as_on_the_ros_command_line_is_refused_with_the_form_to_use():
    """``--param gallery_file:=g.npz`` said only 'unknown parameter gallery_file:'."""
    with pytest.raises(ConfigError) as error:
        OverrideParameters.parse(['tracker.epsilon=0.1', 'gallery_file:=g.npz'])
    assert str(error.value) == (
        "parameter 'gallery_file:=g.npz' must be written name=value "
        "(gallery_file=g.npz; ':=' is ros2 run's -p form)"
    )
