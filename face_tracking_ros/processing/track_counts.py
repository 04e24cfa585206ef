"""A tracking processor's running totals: its images by tracking status, and the last loss.

Each tracker result says whether the face was tracked (``TrackStatus``) and, when it was not,
why (``reason``). Someone watching a robot's /diagnostics, or reading the end of a replay, wants
the totals instead: how many images were tracked, how many lost, and why the last one was not
tracked. The tracking processors keep them here and report them as part of their status
(:class:`~face_tracking_ros.processing.base.Reporting`).
"""

from __future__ import annotations

from face_tracking_ros.tracking.result import TrackStatus

NO_REASON = '-'  # the report's last_reason before any input went untracked
UNTRACKED_WARNING = 30  # inputs in a row not tracked before the status warns (1 s at 30 Hz)


class TrackCounts:
    """Inputs (images, stereo pairs) counted by the status of their result, since the start."""

    def __init__(self, unit: str) -> None:
        """Count inputs called ``unit`` in the report (``images``, ``pairs``)."""
        self._unit = unit
        self._counts = dict.fromkeys(TrackStatus, 0)
        self._last_reason = NO_REASON
        self._untracked = 0  # inputs in a row whose result was not TRACKING

    def add(self, status: TrackStatus, reason: str) -> None:
        """Count one input's result; a non-empty ``reason`` becomes the last reason."""
        self._counts[TrackStatus(status)] += 1
        self._untracked = 0 if status == TrackStatus.TRACKING else self._untracked + 1
        if reason:
            self._last_reason = reason

    def warning(self) -> str:
        """A warning once :data:`UNTRACKED_WARNING` inputs in a row were not tracked, else ''.

        A tracker that never initialises (clicks that do not fit, no init file, a face out of
        view) says so with its last reason, instead of an OK status.
        """
        if self._untracked < UNTRACKED_WARNING:
            return ''
        return f'{self._untracked} {self._unit} in a row not tracked: {self._last_reason}'

    def report(self) -> dict[str, str]:
        """``<status>_<unit>`` per status (e.g. ``lost_images``) and ``last_reason``."""
        report = {
            f'{status.name.lower()}_{self._unit}': str(count)
            for status, count in self._counts.items()
        }
        report['last_reason'] = self._last_reason
        return report
