"""Atomic writes of .npz files: a crash never leaves a half-written model, gallery or classifier.

The arrays go to a temporary file beside the target, which is synced and then renamed over the
target (:func:`os.replace`, atomic on POSIX). The file gets the usual permissions of a new file
(0666 less the umask), not the private mode temporary files are created with.
"""

from __future__ import annotations

import os
from pathlib import Path
import tempfile

import numpy as np


def write_npz_atomically(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` as an uncompressed .npz at ``path``, atomically.

    Args:
        path: the target file; its directory must exist.
        arrays: members by name (plain numeric or string arrays: no pickled objects).
    """
    descriptor, name = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    temporary = Path(name)
    try:
        with os.fdopen(descriptor, 'wb') as handle:
            np.savez(handle, **arrays)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temporary, 0o666 & ~_umask())
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def _umask() -> int:
    """The process umask (reading it requires setting it; it is restored at once)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask
