"""Atomic writes get a new file's mode; a damaged archive's library message is cut to a phrase."""

from __future__ import annotations

import os
import tempfile
from tokenize import TokenError

import pytest

from face_tracking_ros.io.atomic import (
    MAX_DAMAGE_TEXT,
    _damage,
    write_npz_atomically,
    write_text_atomically,
)


@pytest.mark.parametrize(('umask', 'mode'), [(0o022, 0o644), (0o077, 0o600), (0o000, 0o666)])
def test_an_atomic_write_has_the_mode_of_a_new_file_and_leaves_no_temporary(tmp_path, umask, mode):
    """0666 less the umask, not the 0600 of the temporary file it was written as."""
    before = os.umask(umask)
    try:
        write_text_atomically(tmp_path / 'report.txt', 'first')
        write_text_atomically(tmp_path / 'report.txt', 'second')
        write_npz_atomically(tmp_path / 'model.npz', {})
    finally:
        os.umask(before)
    assert (tmp_path / 'report.txt').read_text() == 'second'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['model.npz', 'report.txt']
    for name in ('report.txt', 'model.npz'):
        assert (tmp_path / name).stat().st_mode & 0o777 == mode


def test_a_library_s_damage_message_is_kept_up_to_its_limit_else_its_first_phrase():
    assert MAX_DAMAGE_TEXT == 120
    assert _damage(ValueError('x' * 120)) == 'x' * 120
    assert _damage(ValueError('y' * 121)) == 'y' * 120 + ' (the rest left out)'
    header = 'Cannot parse header: ' + repr(b'\x93NUMPY\x01\x00' * 20)
    assert _damage(ValueError(header)) == 'Cannot parse header (the rest left out)'
    assert _damage(ValueError('bad CRC-32\nfor member x')) == 'bad CRC-32'


def test_a_damage_without_a_message_text_is_said_by_its_type_or_meaning():
    assert _damage(OSError(5, 'Input/output error')) == '[Errno 5] Input/output error'
    assert _damage(EOFError()) == 'EOFError'
    assert _damage(ValueError('  ')) == 'ValueError'
    assert _damage(TokenError('EOF in multi-line statement', (2, 0))) == (
        'its .npy header cannot be parsed'
    )


def test_a_file_that_cannot_be_made_is_named_not_its_temporary(tmp_path, monkeypatch):
    """A directory it may not write in said "Permission denied: '.../.r.json.x1y2.tmp'"."""
    target = tmp_path / 'r.json'

    def refuse(dir: str, prefix: str, suffix: str) -> tuple[int, str]:  # noqa: A002
        raise PermissionError(13, 'Permission denied', os.path.join(dir, f'{prefix}x1y2{suffix}'))

    monkeypatch.setattr(tempfile, 'mkstemp', refuse)
    with pytest.raises(PermissionError) as error:
        write_text_atomically(target, '{}')
    assert str(error.value) == f"[Errno 13] Permission denied: '{target}'"
