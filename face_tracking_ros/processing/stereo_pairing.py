"""Left and right images paired by stamp: the stereo_tracker processor's input pairing.

The stereo processor (:mod:`~face_tracking_ros.processing.stereo`) tracks a left and a right
image taken at the same time. They are paired by exact stamp (or the nearest within
``pairing_tolerance_ms``) in a bounded queue per camera (``pairing_queue``); a stamp that never
pairs is dropped and counted, never paired with another. While no pair has been made, an image
dropped from a full queue while the other camera's images wait is an error that says how far
apart the cameras' stamps are (one camera silent: dropped and counted only).

Stamps are compared with the last tracked pair's (a
:class:`~face_tracking_ros.processing.stamp_guard.StampGuard` the processor gives each tracked
pair's stamp). An image whose stamp repeats it is refused. A jump back of
:data:`RESTART_JUMP_NS` or more (a looped bag, restarted cameras) restarts: the queues empty,
the processor restarts its track, and the new track starts with the pair of that image. An
image a little older than the last pair (e.g. the late partner of a dropped image) is put aside
and counted as unpaired, unless the other camera's images went back too and it pairs with one
of them: a bag shorter than that jump, looped, which restarts the same way.

Messages are opaque here (the stamps come with them, in ns): no ROS types.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Iterable
from typing import Generic, TypeVar

from face_tracking_ros.errors import InputError
from face_tracking_ros.processing.stamp_guard import StampGuard

RESTART_JUMP_NS = 1_000_000_000  # an image stamp this much older than the last pair restarts

Message = TypeVar('Message')


class StereoPairing(Generic[Message]):
    """Left and right images waiting by stamp, per camera, until they pair or never will.

    Attributes:
        unpaired: images that never paired so far (dropped from a full queue, older than a pair
            made, put aside, or still waiting at :meth:`finish`).
    """

    def __init__(
        self,
        sides: tuple[str, str],
        queue_size: int,
        tolerance_ms: float,
        stamps: StampGuard,
        on_restart: Callable[[], None],
    ) -> None:
        """No image waits yet.

        Args:
            sides: the left and the right camera's image topics, as messages name them.
            queue_size: unpaired images kept per camera (``pairing_queue``, >= 1).
            tolerance_ms: the largest stamp difference that pairs (``pairing_tolerance_ms``);
                0: equal stamps only.
            stamps: the stamp of the last pair tracked, which the owner takes
                (:meth:`StampGuard.take`); restarted here when the stamps go back.
            on_restart: called when the stamps went back and the queues were emptied: the
                owner restarts its track.
        """
        self._sides = sides
        self._queue_size = queue_size
        self._tolerance_ms = tolerance_ms
        self._stamps = stamps
        self._on_restart = on_restart
        self._waiting: dict[str, OrderedDict[int, Message]] = _per_camera_queues(sides)
        self._stale: dict[str, OrderedDict[int, Message]] = _per_camera_queues(sides)  # put aside
        self.unpaired = 0
        self._unpaired_gap_ns: int | None = None  # nearest other-camera stamp to a dropped image
        self._paired = False  # whether any left and right images have paired

    def offer(self, side: str, stamp: int, msg: Message) -> tuple[Message, Message] | None:
        """The (left, right) pair completed by the image ``msg`` of ``side``, stamped ``stamp``.

        None while it waits for its partner, or when it is put aside (older than the last pair).

        Raises:
            InputError: for a repeated stamp, a jump back (the image is kept: its pair starts
                the new track), or an image dropped unpaired while no pair has been made yet and
                the other camera's images wait.
        """
        if not self._check_stamp(side, stamp, msg):
            return None
        return self._pair(side, stamp, msg)

    def finish(self) -> None:
        """The end of the input stream: the images still waiting never pair (counted)."""
        left, right = (self._waiting[side] for side in self._sides)
        self._unpair(list(left), right)
        self._unpair(list(right), left)
        left.clear()
        right.clear()

    def report(self) -> dict[str, str]:
        """``unpaired_images`` and, once an image went unpaired, ``unpaired_nearest_ms``.

        ``unpaired_nearest_ms``: how near the other camera's stamps came to an unpaired image
        (more than ``pairing_tolerance_ms`` means unsynchronised cameras).
        """
        report = {'unpaired_images': str(self.unpaired)}
        if self._unpaired_gap_ns is not None:
            report['unpaired_nearest_ms'] = f'{self._unpaired_gap_ns / 1e6:.3f}'
        return report

    def never_paired(self) -> str:
        """Why no pair was made, once images went unpaired and none has paired; else ''."""
        if self._paired or self._unpaired_gap_ns is None:
            return ''
        return _never_paired(self._unpaired_gap_ns / 1e6)

    def _other(self, side: str) -> str:
        """The other camera's side."""
        left, right = self._sides
        return right if side == left else left

    def _check_stamp(self, topic: str, stamp: int, msg: Message) -> bool:
        """Whether an image may be paired: its stamp is later than the last tracked pair's.

        A repeated stamp is refused; a jump back by :data:`RESTART_JUMP_NS` or more restarts the
        track (:meth:`_restart_stream`) and keeps the image. A smaller step back puts the image
        aside, counted as unpaired (False), unless it pairs with an image the other camera put
        aside: both cameras went back (a short bag, looped), and the track restarts with them.

        Raises:
            InputError: for a repeated stamp or a jump back.
        """
        other_topic = self._other(topic)
        if self._stamps.later(stamp, topic):
            for side in (topic, other_topic):  # not a restart: what was put aside never pairs
                self._stale[side].clear()
            return True
        back_ns = self._stamps.last - stamp
        if back_ns < RESTART_JUMP_NS:
            return self._pairs_aside(topic, other_topic, stamp, msg)
        self._restart_stream()
        self._waiting[topic][stamp] = msg
        msg_text = (
            f'{topic} stamp went back by {back_ns / 1e9:.3f} s (looped bag or restarted '
            'cameras): tracker reset, a new track starts with this pair'
        )
        raise InputError(msg_text)

    def _pairs_aside(self, topic: str, other_topic: str, stamp: int, msg: Message) -> bool:
        """Whether an image a little older than the last pair pairs with one put aside.

        If it does, both cameras went back (a short bag, looped): the track restarts with them
        (True). Else the image is put aside, counted as unpaired (False).
        """
        partner = self._partner(stamp, self._stale[other_topic])
        if partner is None:
            self._put_aside(topic, stamp, msg)
            return False
        partner_msg = self._stale[other_topic].pop(partner)
        self._restart_stream()
        self.unpaired -= 1  # (the partner, counted when put aside, pairs after all)
        self._waiting[other_topic][partner] = partner_msg
        return True

    def _put_aside(self, topic: str, stamp: int, msg: Message) -> None:
        """Keep an image older than the last pair (counted as unpaired), the newest few only."""
        self.unpaired += 1
        aside = self._stale[topic]
        aside[stamp] = msg
        while len(aside) > self._queue_size:
            aside.popitem(last=False)

    def _restart_stream(self) -> None:
        """The cameras' stamps went back: empty the queues, and the owner restarts its track."""
        self._stamps.restart()
        for queue in (*self._waiting.values(), *self._stale.values()):
            queue.clear()
        self._on_restart()

    def _pair(self, topic: str, stamp: int, msg: Message) -> tuple[Message, Message] | None:
        """The (left, right) pair completed by this image, if any; older unpaired ones dropped.

        Raises:
            InputError: when an image is dropped unpaired while no pair has been made yet and
                the other camera's images wait (the cameras' stamps do not match: the message
                says by how much).
        """
        queue = self._waiting[topic]
        other = self._waiting[self._other(topic)]
        partner = self._partner(stamp, other)
        if partner is not None:
            match = other.pop(partner)
            self._drop_older(queue, stamp, other, partner)
            self._drop_older(other, partner, queue, stamp)
            self._paired = True
            return (msg, match) if topic == self._sides[0] else (match, msg)
        queue[stamp] = msg
        dropped = len(queue) > self._queue_size
        while len(queue) > self._queue_size:
            self._unpair([queue.popitem(last=False)[0]], other)
        if dropped and not self._paired and other:
            gap_ms = min(abs(mine - theirs) for mine in queue for theirs in other) / 1e6
            raise InputError(_never_paired(gap_ms))
        return None

    def _partner(self, stamp: int, waiting: OrderedDict[int, Message]) -> int | None:
        """The stamp among ``waiting`` that pairs with ``stamp``, or None.

        An equal stamp, else the nearest one within ``pairing_tolerance_ms``.
        """
        if stamp in waiting:
            return stamp
        tolerance_ns = self._tolerance_ms * 1e6
        if not tolerance_ns:  # equal stamps only (the default): no search
            return None
        nearest = min(waiting, key=lambda other: abs(other - stamp), default=None)
        return nearest if nearest is not None and abs(nearest - stamp) <= tolerance_ns else None

    def _drop_older(
        self,
        queue: OrderedDict[int, Message],
        stamp: int,
        other: OrderedDict[int, Message],
        other_paired: int,
    ) -> None:
        """Drop (and count) the images of ``queue`` stamped before ``stamp``: they never pair.

        How near the other camera's stamps came to them is kept: those waiting in ``other`` and
        ``other_paired``, its image in the pair just made.
        """
        stale = [s for s in queue if s < stamp]
        if not stale:  # the usual case, on every pair: nothing to count
            return
        self._unpair(stale, [*other, other_paired])
        for s in stale:
            del queue[s]

    def _unpair(self, stamps: list[int], others: Iterable[int]) -> None:
        """Count images (their ``stamps``) that never pair; keep how near ``others`` came."""
        self.unpaired += len(stamps)
        gaps = [abs(mine - theirs) for mine in stamps for theirs in others]
        if gaps:
            known = self._unpaired_gap_ns
            self._unpaired_gap_ns = min(gaps) if known is None else min(known, *gaps)


def _per_camera_queues(sides: tuple[str, str]) -> dict[str, OrderedDict[int, Message]]:
    """Empty queues of images by stamp, one per camera (by its image topic)."""
    return {side: OrderedDict() for side in sides}


def _never_paired(gap_ms: float) -> str:
    """Why no pair was made: the cameras' stamps differ by at least ``gap_ms``."""
    return (
        'no left and right images have paired yet (unpaired_images counts them): the '
        f'nearest stamps differ by {gap_ms:.3f} ms; pairing needs equal stamps, or '
        'pairing_tolerance_ms for cameras that are not synchronised'
    )
