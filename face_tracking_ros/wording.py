"""Counts in messages: '1 frame' and '2 frames', not '1 frames' or '2 frame(s)'.

The messages, log lines and summaries that state how many of something there are (errors,
loss reasons, replay and playback summaries, the command line's reports) build the phrase with
:func:`counted`, and those that name some things ('unknown nodes ear, nose') with :func:`listed`.
"""

from __future__ import annotations

from collections.abc import Sequence


def counted(count: int, noun: str, plural: str = '') -> str:
    """``count`` and ``noun``, the noun singular for a count of 1 and plural otherwise.

    Args:
        count: how many (an int or a numpy integer).
        noun: the singular, e.g. 'frame' or 'neutral frame'.
        plural: the plural where it is not ``noun`` + 's', e.g. 'meshes', 'kinds of problem'.

    Examples:
        ``counted(1, 'frame')`` is '1 frame', ``counted(0, 'frame')`` '0 frames',
        ``counted(2, 'mesh', 'meshes')`` '2 meshes'.
    """
    return f'{count} {_number(count, noun, plural)}'


def listed(noun: str, names: Sequence[str], plural: str = '') -> str:
    """``noun`` and the ``names`` after it, the noun singular for one name and plural otherwise.

    Examples:
        ``listed('node', ['ear'])`` is 'node ear', ``listed('field', ['a', 'b'])`` 'fields a, b'.
    """
    return f'{_number(len(names), noun, plural)} {", ".join(names)}'


def _number(count: int, noun: str, plural: str) -> str:
    """``noun`` for a count of 1, else ``plural`` (default ``noun`` + 's')."""
    return noun if count == 1 else plural or noun + 's'
