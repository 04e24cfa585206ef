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


class TrackCounts:
    """Inputs (images, stereo pairs) counted by the status of their result, since the start."""

    def __init__(self, unit: str) -> None:
        """Count inputs called ``unit`` in the report (``images``, ``pairs``)."""
        self._unit = unit
        self._counts = dict.fromkeys(TrackStatus, 0)
        self._last_reason = NO_REASON

    def add(self, status: TrackStatus, reason: str) -> None:
        """Count one input's result; a non-empty ``reason`` becomes the last reason."""
        self._counts[TrackStatus(status)] += 1
        if reason:
            self._last_reason = reason

    def report(self) -> dict[str, str]:
        """``<status>_<unit>`` per status (e.g. ``lost_images``) and ``last_reason``."""
        report = {
            f'{status.name.lower()}_{self._unit}': str(count)
            for status, count in self._counts.items()
        }
        report['last_reason'] = self._last_reason
        return report
