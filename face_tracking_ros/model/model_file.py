"""The face model file: a NumPy ``.npz`` archive with a JSON header, never pickle.

Layout (format ``face_tracking_ros.face_model``, version :data:`FORMAT_VERSION`):

===========================  ==========  =========================================================
entry                        shape       content
===========================  ==========  =========================================================
``header``                   ()          UTF-8 JSON string, see below
``mean_shape``               (3N,)       mean neutral face, metres, node-major ``[x0, y0, z0, ..]``
``shape_basis``              (3N, p)     identity basis S, orthonormal columns
``action_basis``             (3N, q)     expression basis A, orthonormal columns
``shape_eigenvalues``        (p,)        variances of sigma, m^2
``action_eigenvalues``       (q,)        variances of alpha, m^2
``sigma_prior_covariance``   (p, p)      §4.1 Gaussian prior of sigma, m^2
``alpha_prior_covariance``   (q, q)      §4.1 Gaussian prior of alpha, m^2
===========================  ==========  =========================================================

The header is ``{"format": "face_tracking_ros.face_model", "format_version": 1, "units":
"metres", "node_names": [...], "method": "seed" | "seed-weighted" | "joint", "metadata": {...}}``.
Every array is float64 and the archive is read with ``allow_pickle=False``, so a model file cannot
execute code. Files are written to a temporary file in the target directory and moved into place
with :func:`os.replace`, so a crash never leaves a half-written model behind.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from face_tracking_ros.errors import ModelFileError
from face_tracking_ros.io.atomic import is_real_array, read_npz, write_npz_atomically
from face_tracking_ros.model.face_model import FaceModel
from face_tracking_ros.wording import listed

FORMAT_NAME = 'face_tracking_ros.face_model'
FORMAT_VERSION = 1
ARRAY_FIELDS = (
    'mean_shape',
    'shape_basis',
    'action_basis',
    'shape_eigenvalues',
    'action_eigenvalues',
    'sigma_prior_covariance',
    'alpha_prior_covariance',
)


def save_model(model: FaceModel, path: str | os.PathLike[str]) -> Path:
    """Write a model file atomically.

    Args:
        model: the model to save.
        path: destination (conventionally ``*.npz``); its directory must exist.

    Returns:
        The path written.

    Raises:
        ModelFileError: if the metadata is not JSON-serialisable or the file cannot be written.
    """
    path = Path(path)
    header = {
        'format': FORMAT_NAME,
        'format_version': FORMAT_VERSION,
        'units': 'metres',
        'node_names': list(model.node_names),
        'method': model.method,
        'metadata': model.metadata,
    }
    try:
        header_text = json.dumps(header, default=_json_default)
    except TypeError as error:
        msg = f'{path}: model metadata is not JSON-serialisable: {error}'
        raise ModelFileError(msg) from None
    arrays = {name: np.asarray(getattr(model, name), dtype=np.float64) for name in ARRAY_FIELDS}
    try:
        write_npz_atomically(path, {'header': np.array(header_text), **arrays})
    except OSError as error:
        msg = f'{path}: cannot write the model file: {error}'
        raise ModelFileError(msg) from None
    return path


def load_model(path: str | os.PathLike[str]) -> FaceModel:
    """Read and validate a model file.

    Args:
        path: a file written by :func:`save_model`.

    Returns:
        The validated model.

    Raises:
        ModelFileError: naming the file and the problem: missing file or field, not an npz
            archive, bad header, other format or version, wrong shape, NaN, node count or names,
            non-orthonormal basis.
    """
    path = Path(path)
    contents = read_npz(path)
    missing = [name for name in ('header', *ARRAY_FIELDS) if name not in contents]
    if missing:
        _fail(path, f'missing {listed("field", missing)}')
    header = _read_header(path, contents['header'])
    arrays = {}
    for name in ARRAY_FIELDS:
        if not is_real_array(contents[name]):
            _fail(path, f'{name} has dtype {contents[name].dtype}, expected float64')
        arrays[name] = contents[name].astype(np.float64)
    n3 = arrays['mean_shape'].size
    if n3 != 3 * len(header['node_names']):
        _fail(
            path,
            f'header names {len(header["node_names"])} nodes but mean_shape has {n3} values '
            f'({n3 / 3:g} nodes)',
        )
    try:
        return FaceModel(
            node_names=tuple(header['node_names']),
            method=header['method'],
            metadata=header['metadata'],
            **arrays,
        )
    except ModelFileError as error:
        _fail(path, str(error))


def _read_header(path: Path, raw: np.ndarray) -> dict[str, Any]:
    """Parse and check the JSON header."""
    if raw.shape != () or raw.dtype.kind != 'U':
        _fail(path, f'header must be a JSON string, got dtype {raw.dtype} shape {raw.shape}')
    try:
        header = json.loads(str(raw))
    except json.JSONDecodeError as error:
        _fail(path, f'header is not valid JSON ({error})')
    if not isinstance(header, dict):
        _fail(path, 'header is not a JSON object')
    if header.get('format') != FORMAT_NAME:
        _fail(path, f'format is {header.get("format")!r}, expected {FORMAT_NAME!r}')
    version = header.get('format_version')
    if version != FORMAT_VERSION:
        _fail(
            path,
            f'format version {version!r} is not supported: this reader reads version '
            f'{FORMAT_VERSION}',
        )
    expected_types = {'node_names': list, 'method': str, 'metadata': dict}
    for key, kind in expected_types.items():
        if not isinstance(header.get(key), kind):
            _fail(path, f'header field {key!r} is missing or not a {kind.__name__}')
    return header


def _json_default(value: Any) -> Any:
    """JSON encoding of numpy scalars and arrays in metadata."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    msg = f'{type(value).__name__} {value!r}'
    raise TypeError(msg)


def _fail(path: Path, problem: str) -> NoReturn:
    """Raise the model-file error naming the file."""
    msg = f'{path}: {problem}'
    raise ModelFileError(msg) from None
