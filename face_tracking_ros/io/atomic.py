"""Atomic writes: a crash never leaves a half-written model, gallery, classifier or report.

The arrays (or text) go to a temporary file beside the target, which is synced and then renamed
over the target (:func:`os.replace`, atomic on POSIX). The file gets the usual permissions of a
new file (0666 less the umask), not the private mode temporary files are created with.
:func:`read_npz` reads them back, refusing pickled objects, with errors that say what is wrong
with the file. :func:`check_output_path` and :func:`check_replaceable` refuse, before a
command does any work, an output it could not write or should not write over. Reports are
written as JSON proper (RFC 8259), a figure that does not apply (NaN) as null.
"""

from __future__ import annotations

from collections.abc import Callable
import json
import math
import os
from pathlib import Path
import tempfile
from tokenize import TokenError
from typing import Any, BinaryIO
import zipfile

import numpy as np

from face_tracking_ros.errors import ConfigError, ModelFileError


def check_output_path(
    path: Path, option: str, *, directory: bool = False, parent_made: bool = True
) -> None:
    """Refuse an output path that cannot be written: a component of it is not a directory.

    The nearest existing ancestor of ``path`` must be a directory (the missing ones below it
    are made by the commands that make them; for the others, ``parent_made`` False, the
    directory ``path`` goes in must exist); ``path`` itself, if it exists, must be a directory
    when ``directory`` is set, else a regular file: a device, named pipe or socket (``--report
    /dev/stdout``, a FIFO) would be replaced by the file renamed over it (:func:`os.replace`),
    as root even ``/dev/null``. The directory the output goes into must be one the process may
    write in (:func:`_check_writable`).

    Args:
        path: the output file, or directory with ``directory``.
        option: the command-line option that gave it (named in the message).
        directory: whether the output is a directory.
        parent_made: whether the command makes the missing directories above ``path``.

    Raises:
        ConfigError: naming the option, the path and the component that is of the wrong kind
            or missing.
    """
    ancestor = next((parent for parent in path.parents if parent.exists()), None)
    if ancestor is not None and not ancestor.is_dir():
        msg = f'{option} {path}: {ancestor} is a file, not a directory'
        raise ConfigError(msg)
    if not parent_made and not path.parent.is_dir():
        msg = f'{option} {path}: no directory {path.parent} to write it in'
        raise ConfigError(msg)
    if directory and path.exists() and not path.is_dir():
        msg = f'{option} {path} is a file, not a directory'
        raise ConfigError(msg)
    if not directory and path.is_dir():
        msg = f'{option} {path} is a directory, not a file'
        raise ConfigError(msg)
    if not directory:
        _check_regular(path, option)
    _check_writable(path if path.is_dir() else ancestor, path, option)


def _check_writable(directory: Path | None, path: Path, option: str) -> None:
    """Refuse an output if the process may not create files in ``directory``, where it goes.

    ``directory`` is the output's nearest existing directory; :func:`os.access` says whether
    files can be made there (not on a read-only file system, nor against its permissions).
    ``learn`` found such an ``--out`` only when it wrote the model, after the learning. As
    root, permissions pass: a directory the kernel refuses to root (such as one under
    ``/sys``) is still found at the write.

    Raises:
        ConfigError: naming the option, the path and the directory.
    """
    if directory is not None and not os.access(directory, os.W_OK | os.X_OK):
        msg = (
            f'{option} {path}: cannot create files in {directory} (a read-only file system, or '
            'no permission to write there)'
        )
        raise ConfigError(msg)


def _check_regular(path: Path, named: str) -> None:
    """Refuse to write over ``path`` (``named`` so) if it exists and is no regular file.

    Raises:
        ConfigError: naming the path and what it is.
    """
    if path.exists() and not path.is_file() and not path.is_dir():
        msg = f'{named} {path} is {_special_kind(path)}, not a regular file: not written over'
        raise ConfigError(msg)


def _special_kind(path: Path) -> str:
    """What an existing path that is neither a regular file nor a directory is."""
    if path.is_fifo():
        return 'a named pipe'
    if path.is_socket():
        return 'a socket'
    return 'a device' if path.is_char_device() or path.is_block_device() else 'a special file'


def check_replaceable(path: Path, option: str, what: str, load: Callable[[Path], object]) -> None:
    """Refuse to write over an existing file that ``load`` does not read as ``what``.

    A command that writes a model, a gallery, a classifier or an init file may replace an
    earlier one of its kind, never another file given by mistake. ``load`` raises
    ModelFileError (or, as the init file's loader, ConfigError) for a file of another kind.

    Raises:
        ConfigError: naming the option, the file and why ``load`` refused it.
    """
    if not path.exists():
        return
    try:
        load(path)
    except (ModelFileError, ConfigError) as error:
        msg = f'{option} {path} exists and is not {what} ({error}): not written over'
        raise ConfigError(msg) from None


def write_npz_atomically(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` as an uncompressed .npz at ``path``, atomically.

    Args:
        path: the target file; its directory must exist.
        arrays: members by name (plain numeric or string arrays: no pickled objects).
    """
    _write_atomically(path, lambda handle: np.savez(handle, **arrays))


def write_text_atomically(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) at ``path``, atomically: an earlier file stays whole until then.

    Args:
        path: the target file; its directory must exist.
        text: the whole content.
    """
    _write_atomically(path, lambda handle: handle.write(text.encode()))


def write_json_atomically(path: Path, value: Any, indent: int = 2) -> None:
    """Write ``value`` as JSON at ``path``, atomically (:func:`write_text_atomically`).

    NaN and infinities, which JSON lacks (Python writes them as ``NaN``, which ``jq`` and
    other parsers refuse), are written as null (:func:`finite_or_null`).
    """
    text = json.dumps(finite_or_null(value), indent=indent, allow_nan=False)
    write_text_atomically(path, text + '\n')


def finite_or_null(value: Any) -> Any:
    """A JSON-ready copy of ``value`` with NaN and infinities replaced by None."""
    if isinstance(value, dict):
        return {str(key): finite_or_null(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [finite_or_null(item) for item in value]
    if hasattr(value, 'tolist'):
        return finite_or_null(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _write_atomically(path: Path, write: Callable[[BinaryIO], object]) -> None:
    """Write ``path`` through ``write`` on a synced temporary file renamed over it.

    Raises:
        ConfigError: if ``path`` is a device, named pipe or socket (the rename would replace it).
    """
    if not path.parent.is_dir():
        msg = f'no directory {path.parent} to write {path.name} in'
        raise FileNotFoundError(msg)
    _check_regular(path, 'output')
    prefix = f'.{path.name}.'
    try:
        descriptor, name = tempfile.mkstemp(dir=path.parent, prefix=prefix, suffix='.tmp')
    except OSError as error:  # named by the file asked for, not the temporary it never made
        raise OSError(error.errno, error.strerror, str(path)) from None
    temporary = Path(name)
    try:
        with os.fdopen(descriptor, 'wb') as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temporary, 0o666 & ~_umask())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def read_npz(path: Path) -> dict[str, np.ndarray]:
    """The members of a .npz file, refusing pickled objects.

    Raises:
        ModelFileError: naming the file: missing, not an .npz (zip) archive or a damaged one
            (naming the member and the damage, without the bytes a library quotes), or holding
            pickled objects.
    """
    if not path.is_file():
        msg = f'{path}: no such file'
        if path.is_dir():
            msg = f'{path}: is a directory, not a file'
        elif path.exists():
            msg = f'{path}: is {_special_kind(path)}, not a regular file'
        raise ModelFileError(msg)
    if not zipfile.is_zipfile(path):
        msg = f'{path}: not an .npz archive, or a damaged one (no zip directory)'
        raise ModelFileError(msg)
    members: dict[str, np.ndarray] = {}
    name = None
    try:
        with np.load(path, allow_pickle=False) as archive:
            for name in archive.files:
                member = archive[name]
                if not isinstance(member, np.ndarray):  # numpy's bytes for no .npy magic
                    msg = (
                        f'{path}: not a readable pickle-free .npz archive (member {name!r} is '
                        'not an .npy array: its header is damaged)'
                    )
                    raise ModelFileError(msg)
                members[name] = member
    except _DAMAGE_ERRORS as error:
        where = f'member {name!r}: ' if name is not None else ''
        msg = f'{path}: not a readable pickle-free .npz archive ({where}{_damage(error)})'
        raise ModelFileError(msg) from None
    return members


def is_real_array(array: np.ndarray) -> bool:
    """Whether ``array`` holds real numbers (integers or floats), as every saved array does.

    ``np.number`` also takes complex numbers, whose imaginary part ``astype(float)`` drops.
    """
    return array.dtype.kind in 'iuf'


# What numpy and zipfile raise for a damaged archive or .npy member. NotImplementedError is
# zipfile's word for a damaged header's 'version needed'; SyntaxError and TokenError come out of
# numpy's parsing of a damaged .npy header.
_DAMAGE_ERRORS = (
    OSError,
    ValueError,
    EOFError,
    SyntaxError,
    TokenError,
    zipfile.BadZipFile,
    NotImplementedError,
)
MAX_DAMAGE_TEXT = 120  # characters of a library's message shown


def _damage(error: BaseException) -> str:
    """A library's word on a damage, without the bytes it may quote.

    numpy quotes a whole damaged .npy header ('Cannot parse header: ' and up to 10 KB as a
    repr); a message longer than :data:`MAX_DAMAGE_TEXT` keeps its first phrase only. The
    errors of Python's parser, which numpy runs on the header ('EOF in multi-line statement'),
    are said as what they mean.
    """
    if isinstance(error, SyntaxError | TokenError):
        return 'its .npy header cannot be parsed'
    first = error.args[0] if error.args and isinstance(error.args[0], str) else str(error)
    text = first.splitlines()[0] if first.strip() else type(error).__name__
    if len(text) > MAX_DAMAGE_TEXT:
        text = text.split(': ')[0][:MAX_DAMAGE_TEXT] + ' (the rest left out)'
    return text


def _umask() -> int:
    """The process umask (reading it requires setting it; it is restored at once)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask
