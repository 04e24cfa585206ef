"""A replay's provenance: the tracker's model it names, same inputs, the bag it was made from."""

from __future__ import annotations

from dataclasses import replace
import hashlib

from face_tracking_ros.io.bags import BagWriter
from face_tracking_ros.io.provenance import KEY, Provenance, other_source


def test_the_tracking_model_is_a_tracker_s_model_file_and_its_sha256(tmp_path):
    model = tmp_path / 'model.npz'
    model.write_bytes(b'a face model')
    digest = hashlib.sha256(b'a face model').hexdigest()
    bag = tmp_path / 'raw'
    with_model = {'model_file': str(model)}
    assert Provenance.of(bag, ['stereo_tracker'], with_model).tracking_model() == (
        str(model),
        digest,
    )
    assert Provenance.of(bag, ['stereo_tracker'], {}).tracking_model() is None  # meshes only
    assert Provenance.of(bag, ['mono_tracker'], {}).tracking_model() == ('', None)  # default
    gone = str(tmp_path / 'gone.npz')
    assert Provenance.of(bag, ['mono_tracker'], {'model_file': gone}).tracking_model() == (
        gone,
        None,
    )
    # A recogniser's model_file is not a tracker's model.
    assert Provenance.of(bag, ['identity_recognizer'], with_model).tracking_model() is None


def test_same_inputs_are_the_same_bag_nodes_and_parameters_complete_or_not(tmp_path):
    provenance = Provenance.of(tmp_path / 'raw', ['mono_tracker'], {'max_iterations': '5'})
    assert provenance.same_inputs(replace(provenance, complete=False))
    other = Provenance.of(tmp_path / 'raw', ['mono_tracker'], {'max_iterations': '6'})
    assert not provenance.same_inputs(other)
    assert not provenance.same_inputs(Provenance.of(tmp_path / 'raw2', ['mono_tracker'], {}))


def test_a_bag_made_from_a_bag_since_moved_is_matched_by_name(tmp_path):
    """The recorded source is gone: a bag of its name is the same, another name is not."""
    recorded = tmp_path / 'moved_away' / 'raw'
    with BagWriter(tmp_path / 'made') as bag:
        bag.set_custom_data(KEY, Provenance.of(recorded, ['mono_tracker'], {}).text())
    assert other_source(tmp_path / 'made', tmp_path / 'here' / 'raw') is None
    assert other_source(tmp_path / 'made', tmp_path / 'here' / 'raw2') == str(recorded)
