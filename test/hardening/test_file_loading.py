"""Model, gallery and classifier files: read without pickle, validated, versions named.

Each file kind is written by its own saver, then damaged in one way (another format version, a
pickled member, a NaN, a missing header, a cut at a random offset); loading must raise
ModelFileError naming the file and the problem, never another exception.
"""

from __future__ import annotations

from collections.abc import Callable
import json
from pathlib import Path
import re
import struct
import zipfile

from fault_scenes import smile_classifier
import numpy as np
import pytest

from face_tracking_ros.data import default_model_path
from face_tracking_ros.errors import ModelFileError
from face_tracking_ros.model.model_file import load_model, save_model
from face_tracking_ros.recognition.expression import ExpressionClassifier
from face_tracking_ros.recognition.identity import IdentityConfig, IdentityGallery


def _model_file(path: Path) -> Callable[[], object]:
    save_model(load_model(default_model_path()), path)
    return lambda: load_model(path)


def _gallery_file(path: Path) -> Callable[[], object]:
    samples = np.random.default_rng(0).normal(0.0, 1e-3, (30, 2)) + [2e-3, -1e-3]
    IdentityGallery.empty(2).enroll('alice', samples, IdentityConfig()).save(path)
    return lambda: IdentityGallery.load(path, 2)


def _classifier_file(path: Path) -> Callable[[], object]:
    smile_classifier().save(path)
    return lambda: ExpressionClassifier.load(path, 1)


KINDS = {'model': _model_file, 'gallery': _gallery_file, 'classifier': _classifier_file}


@pytest.fixture(params=sorted(KINDS))
def saved(request, tmp_path) -> tuple[Path, Callable[[], object]]:
    """(path, load) of a freshly saved file of each kind."""
    path = tmp_path / f'{request.param}.npz'
    return path, KINDS[request.param](path)


def _members(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def _rewrite(path: Path, members: dict[str, np.ndarray]) -> None:
    with path.open('wb') as handle:
        np.savez(handle, **members)


def _header(members: dict[str, np.ndarray]) -> dict:
    return json.loads(str(members['header']))


def test_every_member_is_a_plain_array_readable_without_pickle(saved):
    path, load = saved
    members = _members(path)
    assert all(array.dtype != object for array in members.values())
    assert load() is not None


def test_another_format_version_names_both_versions(saved):
    path, load = saved
    members = _members(path)
    header = _header(members)
    header['format_version'] = 7
    _rewrite(path, {**members, 'header': np.array(json.dumps(header))})
    with pytest.raises(ModelFileError, match=r'format version 7.*(version 1\b)') as error:
        load()
    assert str(path) in str(error.value)


def test_a_pickled_member_is_refused(saved):
    path, load = saved
    members = _members(path)
    name = next(n for n in members if n != 'header')
    _rewrite(path, {**members, name: np.array([{'exec': 'code'}], dtype=object)})
    with pytest.raises(ModelFileError, match='Object arrays cannot be loaded') as error:
        load()
    assert str(path) in str(error.value)


def test_a_nan_in_an_array_is_refused_naming_it(saved):
    path, load = saved
    members = _members(path)
    name = max((n for n in members if n != 'header'), key=lambda n: members[n].size)
    damaged = members[name].astype(float)
    damaged.flat[damaged.size // 2] = np.nan
    _rewrite(path, {**members, name: damaged})
    with pytest.raises(ModelFileError, match=f'{name}.*(NaN|finite)'):
        load()


def test_a_complex_array_is_refused_naming_it(saved):
    """Its imaginary part was dropped (numpy's ComplexWarning) and the real part loaded."""
    path, load = saved
    members = _members(path)
    name = max((n for n in members if n != 'header'), key=lambda n: members[n].size)
    _rewrite(path, {**members, name: members[name] + 1j})
    refusal = f"{name}'? (has dtype complex128|is not a finite real array)"
    with pytest.raises(ModelFileError, match=refusal):
        load()


def test_a_file_without_its_header_is_refused(saved):
    path, load = saved
    members = _members(path)
    del members['header']
    _rewrite(path, members)
    with pytest.raises(ModelFileError, match='header'):
        load()


@pytest.mark.parametrize('header_length', [200, 5000, 9000])
def test_a_damaged_member_header_is_named_without_its_bytes(saved, header_length):
    """The error quoted the damaged .npy header whole: ~20 KB of bytes; or raised TokenError."""
    path, load = saved
    with zipfile.ZipFile(path) as archive:
        data = {name: archive.read(name) for name in archive.namelist()}
    name = max(data, key=lambda n: len(data[n]))  # the largest member's header swallows data
    npy = data[name]
    data[name] = npy[:8] + struct.pack('<H', header_length) + npy[10:]  # .npy v1 header length
    with zipfile.ZipFile(path, 'w') as archive:
        for member, content in data.items():
            archive.writestr(member, content)
    with pytest.raises(ModelFileError) as error:
        load()
    message = str(error.value)
    assert message.startswith(f"{path}: not a readable pickle-free .npz archive (member '")
    assert name.removesuffix('.npy') in message
    assert len(message) < len(str(path)) + 200, message


def test_a_member_without_its_npy_magic_is_named(saved):
    """Such a member was read as bytes: an AttributeError traceback followed."""
    path, load = saved
    with zipfile.ZipFile(path) as archive:
        data = {name: archive.read(name) for name in archive.namelist()}
    name = next(n for n in data if n != 'header.npy')
    data[name] = b'XXXXXX' + data[name][6:]
    with zipfile.ZipFile(path, 'w') as archive:
        for member, content in data.items():
            archive.writestr(member, content)
    with pytest.raises(ModelFileError) as error:
        load()
    assert str(error.value) == (
        f"{path}: not a readable pickle-free .npz archive (member '{name[:-4]}' is not an .npy "
        'array: its header is damaged)'
    )


def test_a_file_cut_at_any_offset_is_a_model_file_error(saved):
    path, load = saved
    data = path.read_bytes()
    for cut in np.random.default_rng(3).integers(0, len(data), 25):
        path.write_bytes(data[:cut])
        with pytest.raises(ModelFileError, match=re.escape(str(path))):
            load()
