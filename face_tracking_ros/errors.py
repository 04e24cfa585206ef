"""Error and warning types of face_tracking_ros.

Every error the package raises on bad input derives from :class:`FaceTrackingError`, so callers
(nodes, the command line) can catch one type and report its message, which always names the
offending file, topic, field or parameter. Its warnings (a damaged bag used as far as it is
readable) derive from :class:`FaceTrackingWarning`, which :func:`warnings_to` sends to the
command line's stderr or a node's log.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import contextlib
import math
from numbers import Integral, Real
import re
from typing import TextIO
import warnings

_NUMBER = re.compile(r'\d+(\.\d+)?(e[-+]?\d+)?')


class FaceTrackingError(Exception):
    """Base class of every error raised by face_tracking_ros."""


class InputError(FaceTrackingError):
    """An input array, image or message is malformed (shape, dtype, encoding, NaN, size)."""


class ConfigError(FaceTrackingError):
    """A parameter or command-line argument is out of range or inconsistent."""


class FieldError(ConfigError):
    """A configuration dataclass's field is out of range.

    Attributes:
        field: the field's name (a parameter source names it as its parameter).
        expected: what the field takes, when the check says more than the field's description
            (e.g. 'a finite number'); '' otherwise.
    """

    def __init__(self, message: str, field: str, expected: str = '') -> None:
        """An error ``message`` about ``field``, which takes ``expected``."""
        super().__init__(message)
        self.field = field
        self.expected = expected


def check_fields(config: object, checks: dict[str, bool]) -> None:
    """Raise a ConfigError naming the first field of ``config`` whose check is False.

    A float field checked (a Python float or a numpy floating scalar such as ``np.float32``,
    which is no float; not a bool or an int) is also refused when it is not finite: a range
    check such as ``value > 0`` lets inf through (NaN fails every comparison), and no tunable
    means anything at infinity.

    Args:
        config: a configuration dataclass (its class name and the field's value go in the
            message).
        checks: field name -> whether its value is valid.
    """
    for name, ok in checks.items():
        value = getattr(config, name)
        finite = not _is_float(value) or math.isfinite(value)
        if not (ok and finite):
            expected = '' if finite else 'a finite number'
            msg = f'invalid {type(config).__name__}.{name} = {value!r}'
            raise FieldError(f'{msg}, expected {expected}' if expected else msg, name, expected)


def _is_float(value: object) -> bool:
    """Whether ``value`` is a real number other than an integer: a float, or a numpy floating.

    numpy registers its floating scalars as :class:`numbers.Real` and its integers (and bool)
    as :class:`numbers.Integral`, so this needs no numpy import.
    """
    return isinstance(value, Real) and not isinstance(value, Integral)


class ModelFileError(FaceTrackingError):
    """A model, gallery or classifier file is missing, malformed or of another format version."""


class BagError(FaceTrackingError):
    """A bag is missing, truncated, corrupt or lacks the topics asked for."""


class DamagedBagError(BagError):
    """A bag damaged part way: the messages before the damage (or around it) have been read.

    Attributes:
        cut_off: whether the damage is the end of an MCAP file part way (a bag cut off: a
            recording or a track killed, or a full disk), not damage inside the file.
    """

    def __init__(self, message: str, cut_off: bool) -> None:
        """An error ``message`` naming the file and the damage."""
        super().__init__(message)
        self.cut_off = cut_off


class FaceTrackingWarning(UserWarning):
    """Base class of the warnings of face_tracking_ros.

    The ``face-tracking`` command prints them as ``warning: <message>`` on stderr, a node logs
    them as warnings (:func:`warnings_to`).
    """


class DamagedBagWarning(FaceTrackingWarning):
    """A damaged bag was read as far as it is readable, and what was read is used."""


@contextlib.contextmanager
def warnings_to(say: Callable[[str], None]) -> Iterator[None]:
    """Within the block, the package's warnings go to ``say`` as their message alone.

    Python's own form (file, line and source of the call) is for programmers; other warnings
    (a library's) keep it. Python's default filter shows a warning once per message.

    Args:
        say: where a warning's message goes (a printer, a node's logger).
    """
    with warnings.catch_warnings():  # the showwarning and filters before, restored after
        shown = warnings.showwarning

        def show(
            message: Warning | str,
            category: type[Warning],
            filename: str,
            lineno: int,
            file: TextIO | None = None,
            line: str | None = None,
        ) -> None:
            if issubclass(category, FaceTrackingWarning):
                say(str(message))
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


def problem_kind(message: str) -> str:
    """The kind of problem ``message`` tells: the message with its numbers as '#'.

    A camera that repeats every stamp gives one message per image, each naming its stamp; a
    replay's summary counts them as one, and the live node logs one of a kind per period.
    """
    return _NUMBER.sub('#', message)
