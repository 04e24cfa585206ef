"""Shape checks shared by the recognition value classes."""

from __future__ import annotations

from typing import Any

import numpy as np

from face_tracking_ros.errors import InputError


def check_shapes(owner: str, value: Any, expected: dict[str, tuple[int, ...]]) -> None:
    """Check that attributes of ``value`` have the expected shapes.

    Args:
        owner: what ``value`` is, for the message (e.g. 'gallery').
        value: object whose attributes are checked.
        expected: attribute name -> expected shape.

    Raises:
        InputError: naming the owner, the attribute, its shape and the expected one.
    """
    for name, shape in expected.items():
        actual = np.shape(getattr(value, name))
        if actual != shape:
            msg = f'{owner} {name} has shape {actual}, expected {shape}'
            raise InputError(msg)
