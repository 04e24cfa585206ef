"""Pickle-free files for recognition models: an ``.npz`` of arrays plus a JSON header.

Layout: every array is one ``.npy`` member of the zip; the member ``header`` is a 0-d unicode
array holding a JSON object with at least ``kind`` (what the file holds, e.g.
``'identity_gallery'``) and ``format_version`` (an integer), and, for a file made with a known
face model, that model's ``model_fingerprint``
(:attr:`~face_tracking_ros.model.face_model.FaceModel.fingerprint`). Files are read with
``allow_pickle=False``, so no file can execute code, and written atomically
(:func:`face_tracking_ros.io.atomic.write_npz_atomically`), so a crash never leaves a
half-written file behind.
"""

from __future__ import annotations

from dataclasses import dataclass
import json
import os
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from face_tracking_ros.errors import ModelFileError
from face_tracking_ros.io.atomic import is_real_array, read_npz, write_npz_atomically

HEADER_KEY = 'header'
MODEL_FIELD = 'model_fingerprint'


@dataclass(frozen=True)
class Archive:
    """The decoded content of a recognition file.

    Attributes:
        path: where it was read from.
        header: the JSON header (a dict with ``kind`` and ``format_version``).
        arrays: every other member, by name.
    """

    path: Path
    header: dict[str, Any]
    arrays: dict[str, np.ndarray]

    def array(self, name: str, shape: tuple[int | None, ...]) -> np.ndarray:
        """A finite float member of the given shape (None = any length).

        Raises:
            ModelFileError: naming the file and the member if it is missing, of another shape or
                not finite.
        """
        if name not in self.arrays:
            self.fail(f'misses the array {name!r}')
        value = self.arrays[name]
        actual = value.shape
        if len(actual) != len(shape) or any(
            e is not None and a != e for a, e in zip(actual, shape, strict=True)
        ):
            self.fail(f'array {name!r} has shape {actual}, expected {shape}')
        if not is_real_array(value) or not np.all(np.isfinite(value)):
            self.fail(f'array {name!r} is not a finite real array (dtype {value.dtype})')
        return value.astype(float)

    def field(self, name: str, kind: type) -> Any:
        """A header field of the given JSON type.

        Raises:
            ModelFileError: naming the file and the field if it is missing or of another type.
        """
        value = self.header.get(name)
        if not isinstance(value, kind):
            self.fail(f'header field {name!r} is {value!r}, expected a {kind.__name__}')
        return value

    def model(self, expected: str | None, remedy: str) -> str | None:
        """The fingerprint of the face model the file was made with (None: not recorded).

        Args:
            expected: the fingerprint of the model it is to be used with; None: not checked.
            remedy: what to do when they differ, for the error.

        Raises:
            ModelFileError: if the file records another model than ``expected``.
        """
        recorded = self.header.get(MODEL_FIELD)
        if recorded is None:
            return None
        if not isinstance(recorded, str):
            self.fail(f'header field {MODEL_FIELD!r} is {recorded!r}, expected a text')
        if expected is not None and recorded != expected:
            self.fail(
                f'was made with another face model (fingerprint {recorded}) than the one in use '
                f'({expected}): {remedy}'
            )
        return recorded

    def fail(self, problem: str) -> NoReturn:
        """Raise ModelFileError naming this file."""
        msg = f'{self.path}: {problem}'
        raise ModelFileError(msg)


def save_archive(
    path: str | os.PathLike[str],
    kind: str,
    format_version: int,
    header: dict[str, Any],
    arrays: dict[str, np.ndarray],
) -> None:
    """Write arrays and a JSON header atomically to ``path``.

    Args:
        path: target file (conventionally ``*.npz``); its directory must exist.
        kind: what the file holds; checked on loading.
        format_version: integer format version; checked on loading.
        header: further JSON-serialisable fields.
        arrays: numeric arrays by member name (not ``'header'``).
    """
    full_header = {'kind': kind, 'format_version': format_version, **header}
    members = {HEADER_KEY: np.array(json.dumps(full_header, sort_keys=True))}
    members.update({name: np.asarray(value) for name, value in arrays.items()})
    write_npz_atomically(Path(path), members)


def model_header(fingerprint: str | None) -> dict[str, str]:
    """The header field that records the face model a file was made with (none if unknown)."""
    return {} if fingerprint is None else {MODEL_FIELD: fingerprint}


def load_archive(path: str | os.PathLike[str], kind: str, format_version: int) -> Archive:
    """Read a file written by :func:`save_archive` and check its kind and version.

    Raises:
        ModelFileError: if the file is missing, not an npz, holds pickled objects, lacks or has a
            malformed header, or is of another kind or format version (both versions named).
    """
    source = Path(path)
    arrays = read_npz(source)
    archive = Archive(path=source, header={}, arrays=arrays)
    raw_header = arrays.pop(HEADER_KEY, None)
    if raw_header is None or raw_header.shape != () or raw_header.dtype.kind != 'U':
        archive.fail(f'has no JSON {HEADER_KEY!r} member')
    try:
        header = json.loads(str(raw_header))
    except json.JSONDecodeError as error:
        msg = f'{source}: header is not valid JSON ({error})'
        raise ModelFileError(msg) from None
    if not isinstance(header, dict):
        archive.fail('header is not a JSON object')
    archive = Archive(path=source, header=header, arrays=arrays)
    if header.get('kind') != kind:
        found = header.get('kind') or header.get('format') or 'file of no known kind'
        archive.fail(f'holds a {found!r}, expected a {kind!r}')
    if header.get('format_version') != format_version:
        archive.fail(
            f'has format version {header.get("format_version")!r}; this code reads version '
            f'{format_version}'
        )
    return archive
