"""Model file round trip, atomic writes and every validation branch of load_model."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
import json
from pathlib import Path

import numpy as np
import pytest

from face_tracking_ros.errors import ModelFileError
from face_tracking_ros.model import model_file
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.model.model_file import FORMAT_VERSION, load_model, save_model
from face_tracking_ros.model.topology import Group, mesh_topology


def _model(num_nodes: int = 19, p: int = 2, q: int = 5, seed: int = 0) -> FaceModel:
    rng = np.random.default_rng(seed)
    bases, _ = np.linalg.qr(rng.normal(size=(3 * num_nodes, p + q)))
    return FaceModel(
        node_names=mesh_topology(num_nodes).node_names,
        mean_shape=mesh_topology(num_nodes).reference_shape.ravel(),
        shape_basis=bases[:, :p],
        action_basis=bases[:, p:],
        shape_eigenvalues=np.linspace(2e-4, 1e-4, p),
        action_eigenvalues=np.linspace(3e-4, 1e-5, q),
        sigma_prior_covariance=np.diag(np.linspace(2e-4, 1e-4, p)),
        alpha_prior_covariance=np.diag(np.linspace(3e-4, 1e-5, q)),
        method='joint',
        metadata={'subjects': np.int64(11), 'history': np.array([0.5, 0.1]), 'note': 'x'},
    )


def _rewrite(path: Path, **changes: object) -> None:
    """Rewrite a model archive with some entries replaced (None removes the entry)."""
    with np.load(path, allow_pickle=False) as archive:
        contents = {name: archive[name] for name in archive.files}
    for name, value in changes.items():
        if value is None:
            del contents[name]
        else:
            contents[name] = value
    with path.open('wb') as handle:
        np.savez(handle, **contents)


def _header(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as archive:
        return json.loads(str(archive['header']))


@pytest.mark.parametrize('num_nodes', [19, 34])
def test_round_trip_keeps_every_field(tmp_path, num_nodes):
    model = _model(num_nodes)
    path = save_model(model, tmp_path / 'face.npz')
    loaded = load_model(path)
    assert loaded.node_names == model.node_names
    assert loaded.method == 'joint'
    assert loaded.metadata == {'subjects': 11, 'history': [0.5, 0.1], 'note': 'x'}
    for name in model_file.ARRAY_FIELDS:
        assert np.array_equal(getattr(loaded, name), getattr(model, name)), name
    assert _header(path)['format_version'] == FORMAT_VERSION
    assert sorted(p.name for p in tmp_path.iterdir()) == ['face.npz']


def test_overwrite_replaces_the_old_model(tmp_path):
    path = tmp_path / 'face.npz'
    save_model(_model(seed=1), path)
    save_model(_model(seed=2), path)
    assert np.array_equal(load_model(path).shape_basis, _model(seed=2).shape_basis)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['face.npz']


def test_crash_while_writing_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / 'face.npz'
    save_model(_model(seed=1), path)
    before = path.read_bytes()

    def crash(handle, **arrays):
        handle.write(b'PK partial')
        raise OSError('disk full')

    monkeypatch.setattr(model_file.np, 'savez', crash)
    with pytest.raises(ModelFileError, match=r'face\.npz: cannot write the model file: disk full'):
        save_model(_model(seed=2), path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['face.npz']


def test_missing_directory_is_reported(tmp_path):
    with pytest.raises(ModelFileError, match=r'cannot write the model file'):
        save_model(_model(), tmp_path / 'absent' / 'face.npz')


def test_unserialisable_metadata_is_reported(tmp_path):
    model = _model()
    bad = FaceModel(**{**model.__dict__, 'metadata': {'when': object()}})
    with pytest.raises(ModelFileError, match=r'metadata is not JSON-serialisable'):
        save_model(bad, tmp_path / 'face.npz')


def test_missing_file(tmp_path):
    with pytest.raises(ModelFileError, match=r'nothere\.npz: no such file'):
        load_model(tmp_path / 'nothere.npz')


def test_not_an_archive(tmp_path):
    path = tmp_path / 'face.npz'
    path.write_text('hello')
    with pytest.raises(
        ModelFileError,
        match=r'face\.npz: not an \.npz archive, or a damaged one \(no zip directory\)',
    ):
        load_model(path)


def test_pickled_object_array_is_refused(tmp_path):
    path = save_model(_model(), tmp_path / 'face.npz')
    with np.load(path, allow_pickle=False) as archive:
        contents = {name: archive[name] for name in archive.files}
    contents['mean_shape'] = np.array([object()], dtype=object)
    np.savez(path, **contents)
    with pytest.raises(ModelFileError, match=r'not a readable pickle-free \.npz archive'):
        load_model(path)


@pytest.mark.parametrize(
    ('changes', 'match'),
    [
        ({'action_basis': None}, 'missing field action_basis'),
        ({'header': None, 'mean_shape': None}, 'missing fields header, mean_shape'),
        ({'header': np.array('{nope')}, r'header is not valid JSON'),
        ({'header': np.array([1.0])}, r'header must be a JSON string'),
        ({'header': np.array(['{}', '{}'])}, r'header must be a JSON string, got dtype <U2 shape'),
        ({'header': np.array('[1, 2]')}, r'header is not a JSON object'),
        ({'mean_shape': np.array(['a'] * 57)}, r'mean_shape has dtype <U1, expected float64'),
    ],
)
def test_malformed_archive(tmp_path, changes, match):
    path = save_model(_model(), tmp_path / 'face.npz')
    _rewrite(path, **changes)
    with pytest.raises(ModelFileError, match=rf'face\.npz: {match}'):
        load_model(path)


@pytest.mark.parametrize(
    ('header_changes', 'match'),
    [
        ({'format': 'other'}, r"format is 'other', expected 'face_tracking_ros\.face_model'"),
        (
            {'format_version': FORMAT_VERSION + 1},
            rf'format version {FORMAT_VERSION + 1} is not supported: this reader reads '
            rf'version {FORMAT_VERSION}',
        ),
        ({'method': 3}, r"header field 'method' is missing or not a str"),
        ({'node_names': None}, r"header field 'node_names' is missing or not a list"),
        ({'node_names': ['a'] * 34}, r'header names 34 nodes but mean_shape has 57 values'),
        (
            {'node_names': ['a'] * 19},
            r"node names differ from the 19-node topology: 'a' \(the topology: 'right_eye'\)$",
        ),
    ],
)
def test_bad_header(tmp_path, header_changes, match):
    path = save_model(_model(), tmp_path / 'face.npz')
    header = _header(path)
    header.update(header_changes)
    _rewrite(path, header=np.array(json.dumps(header)))
    with pytest.raises(ModelFileError, match=match):
        load_model(path)


def test_bad_arrays(tmp_path):
    model = _model()
    cases = {
        'shape': ({'shape_basis': model.shape_basis[:-3]}, r'shape_basis has shape \(54, 2\)'),
        'nan': (
            {'mean_shape': np.where(np.arange(57) == 4, np.nan, model.mean_shape)},
            r'mean_shape holds NaN',
        ),
        'millimetres': (
            {'mean_shape': 1000.0 * model.mean_shape},
            r'mean_shape spans 47.4 m RMS about its centroid, where a face spans about 0.05 m',
        ),
        'zero': ({'mean_shape': 0.0 * model.mean_shape}, r'mean_shape spans 0 m RMS'),
        'orthonormal': (
            {'action_basis': 1.01 * model.action_basis},
            r'action_basis is not orthonormal',
        ),
        'prior': (
            {'alpha_prior_covariance': np.eye(4)},
            r'alpha_prior_covariance has shape \(4, 4\), expected \(5, 5\)',
        ),
    }
    for changes, match in cases.values():
        path = save_model(model, tmp_path / 'face.npz')
        _rewrite(path, **changes)
        with pytest.raises(ModelFileError, match=rf'face\.npz: invalid face model: {match}'):
            load_model(path)


def test_node_count_other_than_19_or_34(tmp_path):
    path = save_model(_model(), tmp_path / 'face.npz')
    header = _header(path)
    header['node_names'] = header['node_names'][:18]
    _rewrite(
        path,
        header=np.array(json.dumps(header)),
        mean_shape=np.zeros(54),
        shape_basis=np.eye(54)[:, :2],
        action_basis=np.eye(54)[:, 2:7],
    )
    with pytest.raises(ModelFileError, match=r'node count is 18'):
        load_model(path)


def test_saving_into_a_missing_directory_names_it(tmp_path):
    with pytest.raises(ModelFileError, match=r'file: no directory .*nodir to write m\.npz in'):
        save_model(_model(), tmp_path / 'nodir' / 'm.npz')
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize('num_nodes', [19, 34])
def test_reference_shape_is_in_the_documented_face_frame(num_nodes):
    # topology.py: origin midway between the eye centres, x to the subject's left, y to the
    # chin, z into the head; 'right_' and 'left_' nodes mirror each other about x = 0.
    topology = mesh_topology(num_nodes)
    shape = dict(zip(topology.node_names, topology.reference_shape, strict=True))

    np.testing.assert_array_equal(shape['right_eye'] + shape['left_eye'], 0.0)
    np.testing.assert_array_equal(shape['left_eye'], [0.0315, 0.0, 0.0])
    for name, xyz in shape.items():
        if 'left' in name:
            np.testing.assert_array_equal(shape[name.replace('left', 'right')], xyz * [-1, 1, 1])
        elif 'right' not in name:
            assert xyz[0] == 0.0, name
    lowest = 'chin' if num_nodes == 34 else 'lower_lip'
    assert topology.node_names[np.argmax(topology.reference_shape[:, 1])] == lowest
    assert topology.node_names[np.argmin(topology.reference_shape[:, 2])] == 'nose_tip'
    counts = {Group.EYE: 2, Group.NOSE: 3, Group.MOUTH: 8, Group.BROW: 6}
    if num_nodes == 34:
        counts |= {Group.EYE_CORNER: 4, Group.EDGE: 11}
    assert Counter(topology.groups) == counts


@pytest.mark.parametrize('num_nodes', [19, 34])
def test_edges_are_the_sides_of_the_triangulation(num_nodes):
    topology = mesh_topology(num_nodes)
    sides = {
        tuple(sorted((int(a), int(b))))
        for triangle in topology.triangles
        for a, b in (
            (triangle[0], triangle[1]),
            (triangle[1], triangle[2]),
            (triangle[0], triangle[2]),
        )
    }

    assert [tuple(edge) for edge in topology.edges.tolist()] == sorted(sides)
    # Euler's formula for a triangulated disc: V - E + T = 1.
    assert num_nodes - len(topology.edges) + len(topology.triangles) == 1


def test_a_mean_shape_of_another_unit_or_size_is_refused():
    model = _model(34)  # the reference face: 0.0585 m RMS about its centroid
    for scale, spread in ((1000.0, '58.5'), (6.0, '0.351'), (0.1, '0.00585')):
        with pytest.raises(ModelFileError, match=rf'mean_shape spans {spread} m RMS'):
            replace(model, mean_shape=model.mean_shape * scale)
    for scale in (0.25, 4.0):  # 0.0146 m and 0.234 m: a child's face to a large helmet's
        assert replace(model, mean_shape=model.mean_shape * scale).num_nodes == 34


def test_prior_covariance_tolerances_are_relative_to_its_largest_entry():
    model = _model()  # sigma_prior_covariance diag(2e-4, 1e-4) m^2
    for asymmetry, symmetric in ((2e-11, False), (2e-14, True)):  # 1e-7 and 1e-10 relative
        covariance = model.sigma_prior_covariance.copy()
        covariance[0, 1] += asymmetry
        if symmetric:
            np.testing.assert_array_equal(
                replace(model, sigma_prior_covariance=covariance).sigma_prior_covariance,
                covariance,
            )
        else:
            with pytest.raises(ModelFileError, match='sigma_prior_covariance is not symmetric'):
                replace(model, sigma_prior_covariance=covariance)
