"""The stamp order a tracking processor's images must keep, and the restarts when it is broken.

A tracker follows the face from one image to the next, so its images must come in stamp order.
The mono and stereo processors refuse an image whose stamp repeats the last tracked one (a
duplicated message), and restart the track on one that went back (a looped bag, a restarted
camera); ``restarts`` in their status counts those. What counts as the last stamp, and what a
stamp that went back does beyond the restart, differ: the mono processor takes an image's stamp
as soon as it passes and restarts at once, its status warning of it for the next
:data:`RESTART_WARNING` images (:meth:`StampGuard.warning`); the stereo processor takes the
stamp of the pair it
tracks and its pairing decides by how far the stamp went back
(:mod:`~face_tracking_ros.processing.stereo_pairing`).
"""

from __future__ import annotations

from face_tracking_ros.errors import InputError
from face_tracking_ros.wording import counted

RESTART_WARNING = 30  # stamps after a restart while StampGuard.warning warns (1 s at 30 Hz)


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
        self._back_ns = 0  # how far the last stamp that went back went back
        self._since_restart: int | None = None  # stamps taken since the last restart, if any

    def later(self, stamp_ns: int, source: str) -> bool:
        """Whether ``stamp_ns`` is later than the last stamp (or the first); False: it went back.

        Raises:
            InputError: for a stamp that repeats the last one, naming ``source`` (the image's
                topic) and the stamp, and a driver that leaves stamps at 0: the image is skipped.
        """
        if self.last is None or stamp_ns > self.last:
            return True
        if stamp_ns == self.last:
            unset = '' if stamp_ns else ' (header.stamp unset: the driver must stamp its images)'
            msg = (
                f'{source} stamp {stamp_ns} ns repeats the previous {self._unit} stamp{unset}: '
                'image skipped'
            )
            raise InputError(msg)
        self._back_ns = self.last - stamp_ns
        return False

    def take(self, stamp_ns: int) -> None:
        """``stamp_ns`` is the last stamp now (an image or pair that passed)."""
        self.last = stamp_ns
        if self._since_restart is not None:
            self._since_restart += 1

    def forget(self) -> None:
        """The next stamp starts afresh, whatever it is (the track starts over)."""
        self.last = None

    def restart(self) -> None:
        """A stamp went back: count the restarted track; the next stamp starts afresh."""
        self.forget()
        self.restarts += 1
        self._since_restart = 0

    def warning(self) -> str:
        """That the stamps went back, for :data:`RESTART_WARNING` stamps after a restart, else ''.

        A restart now and then is a looped bag or a restarted camera; restarts that keep coming
        are two sources publishing on one topic (a bag played while the camera runs), each
        going back to the other's stamps, which no status showed but the count.
        """
        if self._since_restart is None or self._since_restart > RESTART_WARNING:
            return ''
        ago = counted(self._since_restart, self._unit)
        return (
            f'{self._unit} stamp went back by {self._back_ns / 1e9:.3f} s {ago} ago: track '
            f'restarted ({counted(self.restarts, "restart")} so far: a looped bag, a restarted '
            'camera, or two sources on one topic?)'
        )
