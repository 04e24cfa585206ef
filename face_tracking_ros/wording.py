"""Counts in messages: '1 frame' and '2 frames', not '1 frames' or '2 frame(s)'.

The messages, log lines and summaries that state how many of something there are (errors,
loss reasons, replay and playback summaries, the command line's reports) build the phrase with
:func:`counted`.
"""

from __future__ import annotations


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
    return f'{count} {noun if count == 1 else plural or noun + "s"}'
