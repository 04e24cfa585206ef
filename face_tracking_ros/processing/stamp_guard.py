"""The stamp order a tracking processor's images must keep, and the restarts when it is broken.

A tracker follows the face from one image to the next, so its images must come in stamp order.
The mono and stereo processors refuse an image whose stamp repeats the last tracked one (a
duplicated message), and restart the track on one that went back (a looped bag, a restarted
camera); ``restarts`` in their status counts those. What counts as the last stamp, and what a
stamp that went back does beyond the restart, differ: the mono processor takes an image's stamp
as soon as it passes and restarts at once; the stereo processor takes the stamp of the pair it
tracks and its pairing decides by how far the stamp went back
(:mod:`~face_tracking_ros.processing.stereo_pairing`).
"""

from __future__ import annotations

from face_tracking_ros.errors import InputError


class StampGuard:
    """The last stamp taken and the tracks restarted by a stamp that went back.

    Attributes:
        last: the last stamp taken, ns (set by :meth:`take` and :meth:`forget`); None before
            the first one and after a restart.
        restarts: tracks restarted by a stamp that went back, since the start.
    """

    def __init__(self, unit: str) -> None:
        """No stamp yet; ``unit`` names what a stamp is of in messages (``image``, ``pair``)."""
        self._unit = unit
        self.last: int | None = None
        self.restarts = 0

    def later(self, stamp_ns: int, source: str) -> bool:
        """Whether ``stamp_ns`` is later than the last stamp (or the first); False: it went back.

        Raises:
            InputError: for a stamp that repeats the last one, naming ``source`` (the image's
                topic) and the stamp: the image is skipped.
        """
        if self.last is None or stamp_ns > self.last:
            return True
        if stamp_ns == self.last:
            msg = (
                f'{source} stamp {stamp_ns} ns repeats the previous {self._unit} stamp: '
                'image skipped'
            )
            raise InputError(msg)
        return False

    def take(self, stamp_ns: int) -> None:
        """``stamp_ns`` is the last stamp now (an image or pair that passed)."""
        self.last = stamp_ns

    def forget(self) -> None:
        """The next stamp starts afresh, whatever it is (the track starts over)."""
        self.last = None

    def restart(self) -> None:
        """A stamp went back: count the restarted track; the next stamp starts afresh."""
        self.forget()
        self.restarts += 1
