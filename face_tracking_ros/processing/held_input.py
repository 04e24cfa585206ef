"""The input a tracking processor holds while the calibration it needs has not come yet.

A camera driver may publish the first image before its camera_info. The mono and stereo
processors hold the latest input (an image, a left and right pair) and track it as soon as the
calibration arrives: the first one quietly, each later one in its place with a warning that the
one before was dropped. What they hold, and when they must hold it, differ: the mono processor
holds an image (its header and grey pixels) while there is no camera_info; the stereo processor
a pair of messages while it has no tracker (a calibration missing, or refused).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, TypeVar

from face_tracking_ros.errors import InputError
from face_tracking_ros.processing.base import Output
from face_tracking_ros.processing.track_counts import NO_REASON

Held = TypeVar('Held')


class HeldInput(Generic[Held]):
    """The latest input that came before its calibration, until the calibration comes."""

    def __init__(self, awaited: str, unit: str, until: str = '') -> None:
        """Hold inputs called ``unit`` (``image``, ``pair``) while nothing came on ``awaited``.

        Args:
            awaited: the camera_info topics the calibration comes on, as messages name them.
            unit: what an input is, in messages.
            until: the words that follow 'holding the latest <unit>' in the warning (the mono
                processor's ' until it comes').
        """
        self._awaited = awaited
        self._unit = unit
        self._until = until
        self._held: Held | None = None

    def hold(self, item: Held) -> str:
        """Hold ``item`` in place of the one held before, if any.

        Returns:
            '' for the first one held (a driver may send the camera_info just after it), else
            the warning that the one before was dropped.
        """
        dropped, self._held = self._held, item
        if dropped is None:
            return ''
        return (
            f'no calibration on {self._awaited} yet: holding the latest {self._unit}{self._until} '
            '(the one before dropped)'
        )

    def release(self, track: Callable[[Held], list[Output]]) -> list[Output]:
        """Track the held input, if any, now that the calibration is there; it is held no more.

        Raises:
            InputError: the held input's own problem (from ``track``), named as the held one's,
                not the calibration's.
        """
        if self._held is None:
            return []
        item, self._held = self._held, None
        try:
            return track(item)
        except InputError as error:
            msg = f'the {self._unit} held until the calibration came: {error}'
            raise InputError(msg) from None

    def reason(self, last_reason: str) -> str:
        """The status's ``last_reason``: that an input is held, while nothing went untracked."""
        if self._held is None or last_reason != NO_REASON:
            return last_reason
        article = 'an' if self._unit[0] in 'aeiou' else 'a'
        return f'no calibration on {self._awaited} yet: {article} {self._unit} is held'
