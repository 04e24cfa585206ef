"""The stereo processor's pairing of left and right images by stamp, on its own (no images).

The processor's tests (test/hardening/test_processor_inputs.py) cover the rest through it:
equal stamps only and the error while nothing pairs, one partner within the tolerance, the
repeated stamp, the late image put aside, and the restarts on stamps that go back.
"""

from __future__ import annotations

import pytest

from face_tracking_ros.errors import InputError
from face_tracking_ros.processing.stamp_guard import StampGuard
from face_tracking_ros.processing.stereo_pairing import StereoPairing

LEFT, RIGHT = 'left/image_raw', 'right/image_raw'
T = 1_700_000_000 * 10**9  # ns
MS = 1_000_000  # ns
SECOND = 1_000_000_000  # ns: a jump back this long restarts (RESTART_JUMP_NS)


def _pairing(queue_size: int = 10, tolerance_ms: float = 0.0) -> StereoPairing[str]:
    """A pairing whose messages are names; stamps never go back in these tests."""

    def no_restart() -> None:
        raise AssertionError('no restart expected')

    return StereoPairing((LEFT, RIGHT), queue_size, tolerance_ms, StampGuard('pair'), no_restart)


def test_the_nearest_image_within_the_tolerance_pairs_never_one_beyond_it() -> None:
    pairing = _pairing(tolerance_ms=5.0)
    assert pairing.offer(RIGHT, T - 3 * MS, 'right -3 ms') is None
    assert pairing.offer(RIGHT, T + 1 * MS, 'right +1 ms') is None
    # Both are within 5 ms: the nearer pairs, the older one is dropped (it never pairs).
    assert pairing.offer(LEFT, T, 'left 0') == ('left 0', 'right +1 ms')
    assert pairing.unpaired == 1
    assert pairing.offer(LEFT, T + 100 * MS, 'left 100') is None
    assert pairing.offer(RIGHT, T + 106 * MS, 'right 106') is None  # 6 ms: not a partner
    assert pairing.offer(RIGHT, T + 200 * MS, 'right 200') is None
    assert pairing.offer(LEFT, T + 205 * MS, 'left 205') == ('left 205', 'right 200')  # at 5 ms
    assert pairing.unpaired == 3  # left 100 and right 106, older than that pair


def test_images_left_behind_count_as_unpaired_with_how_near_the_other_camera_came() -> None:
    pairing = _pairing()
    assert pairing.offer(LEFT, T, 'left 0') is None
    assert pairing.offer(LEFT, T + 100 * MS, 'left 100') is None
    assert pairing.offer(RIGHT, T + 100 * MS, 'right 100') == ('left 100', 'right 100')
    # left 0 is older than the pair made: dropped, 100 ms from the nearest right stamp.
    assert pairing.report() == {'unpaired_images': '1', 'unpaired_nearest_ms': '100.000'}
    assert pairing.never_paired() == ''  # a pair was made
    assert pairing.offer(RIGHT, T + 230 * MS, 'right 230') is None
    assert pairing.offer(LEFT, T + 200 * MS, 'left 200') is None  # 30 ms apart: no pair
    pairing.finish()  # the end of the stream: both never pair
    assert pairing.report() == {'unpaired_images': '3', 'unpaired_nearest_ms': '30.000'}
    pairing.finish()  # nothing waits any more: nothing counted twice
    assert pairing.unpaired == 3


def test_an_image_left_behind_a_pair_within_the_tolerance_is_measured_against_the_other_camera():
    pairing = _pairing(tolerance_ms=5.0)
    assert pairing.offer(LEFT, T + 100 * MS, 'left 100') is None
    assert pairing.offer(LEFT, T + 133 * MS, 'left 133') is None
    assert pairing.offer(RIGHT, T + 136 * MS, 'right 136') == ('left 133', 'right 136')
    # left 100 never pairs: the nearest right stamp was 136 (36 ms), not left 133's own 33 ms.
    assert pairing.report() == {'unpaired_images': '1', 'unpaired_nearest_ms': '36.000'}
    assert pairing.offer(RIGHT, T + 200 * MS, 'right 200') is None
    assert pairing.offer(RIGHT, T + 233 * MS, 'right 233') is None
    assert pairing.offer(LEFT, T + 236 * MS, 'left 236') == ('left 236', 'right 233')
    # right 200 never pairs either: 36 ms from left 236 (33 from its own camera's right 233).
    assert pairing.report() == {'unpaired_images': '2', 'unpaired_nearest_ms': '36.000'}


def test_a_full_queue_drops_its_oldest_and_says_why_once_the_other_camera_sends() -> None:
    pairing = _pairing(queue_size=2)
    for k in range(3):  # the right camera silent: the oldest left image dropped, no error
        assert pairing.offer(LEFT, T + k * 100 * MS, f'left {k}') is None
    assert pairing.report() == {'unpaired_images': '1'}  # no right stamp to be near
    assert pairing.never_paired() == ''
    assert pairing.offer(RIGHT, T + 202 * MS, 'right 202') is None
    with pytest.raises(InputError, match=r'have paired yet .* nearest stamps differ by 2\.000 ms'):
        pairing.offer(LEFT, T + 300 * MS, 'left 300')
    assert pairing.unpaired == 2
    assert pairing.never_paired() == (
        'no left and right images have paired yet (unpaired_images counts them): the nearest '
        'stamps differ by 102.000 ms; pairing needs equal stamps, or pairing_tolerance_ms for '
        'cameras that are not synchronised'
    )


def _tracked(queue_size: int = 10) -> tuple[StereoPairing[str], StampGuard, list[str]]:
    """A pairing whose left T and right T paired and were tracked; its restarts recorded."""
    stamps, restarts = StampGuard('pair'), []
    pairing = StereoPairing(
        (LEFT, RIGHT), queue_size, 0.0, stamps, lambda: restarts.append('restart')
    )
    assert pairing.offer(LEFT, T, 'left 0') is None
    assert pairing.offer(RIGHT, T, 'right 0') == ('left 0', 'right 0')
    stamps.take(T)  # the owner tracked the pair
    return pairing, stamps, restarts


def test_an_image_repeating_the_tracked_pair_s_stamp_is_refused() -> None:
    pairing, stamps, restarts = _tracked()
    with pytest.raises(
        InputError, match=rf'^right/image_raw stamp {T} ns repeats the previous pair'
    ):
        pairing.offer(RIGHT, T, 'right 0 again')
    assert (pairing.unpaired, restarts, stamps.last) == (0, [], T)  # skipped, nothing else
    assert pairing.offer(LEFT, T + 1, 'left +1 ns') is None  # 1 ns later: waits for its partner


def test_a_jump_back_of_one_second_restarts_and_one_of_a_nanosecond_less_is_put_aside() -> None:
    pairing, stamps, restarts = _tracked()
    assert pairing.offer(LEFT, T - SECOND + 1, 'left -1 s + 1 ns') is None
    assert (pairing.unpaired, restarts, stamps.restarts, stamps.last) == (1, [], 0, T)
    with pytest.raises(InputError, match=r'^left/image_raw stamp went back by 1\.000 s'):
        pairing.offer(LEFT, T - SECOND, 'left -1 s')
    assert (restarts, stamps.restarts, stamps.last) == (['restart'], 1, None)
    # The image that went back was kept: its partner pairs with it, the new track's first pair.
    assert pairing.offer(RIGHT, T - SECOND, 'right -1 s') == ('left -1 s', 'right -1 s')


def test_both_cameras_back_by_less_than_the_jump_restart_with_their_pair() -> None:
    pairing, stamps, restarts = _tracked()
    back = T - 500 * MS  # a bag of 0.5 s, looped
    assert pairing.offer(LEFT, back, 'left -500') is None  # put aside: counted unpaired
    assert pairing.unpaired == 1 and restarts == []
    assert pairing.offer(RIGHT, back, 'right -500') == ('left -500', 'right -500')
    assert (pairing.unpaired, restarts, stamps.restarts, stamps.last) == (0, ['restart'], 1, None)


def test_images_put_aside_are_the_newest_queue_size_ones() -> None:
    pairing, stamps, restarts = _tracked(queue_size=2)
    for k in (3, 2, 1):  # older than the pair: put aside, left -300 ms dropped from the queue
        assert pairing.offer(LEFT, T - k * 100 * MS, f'left -{k}00') is None
    assert pairing.unpaired == 3
    assert pairing.offer(RIGHT, T - 300 * MS, 'right -300') is None  # its partner is gone
    assert pairing.unpaired == 4 and restarts == []
    assert pairing.offer(RIGHT, T - 200 * MS, 'right -200') == ('left -200', 'right -200')
    assert (pairing.unpaired, restarts, stamps.restarts) == (3, ['restart'], 1)
