"""Work split into stages, so a tracker can spread a long computation over several frames.

A staged computation is a generator that yields between its stages and returns its result; no
frame then pays for all of it. The mono tracker runs its bundle adjustment this way
(:class:`~.bundle.BundleConfig` ``stages_per_frame``): a few stages per frame keep each frame's
extra cost to a few Levenberg-Marquardt iterations or pyramid levels' ROIs, and the result is the
same on every run, however fast the machine, because stages are counted, not timed.
"""

from __future__ import annotations

from collections.abc import Generator
import itertools
from typing import TypeVar

T = TypeVar('T')

Stages = Generator[None, None, T]
"""A staged computation: yields between stages, returns its result."""


def run_stages(stages: Stages[T], limit: int | None = None) -> tuple[bool, T | None]:
    """Run up to ``limit`` more stages (all that are left if None).

    Returns:
        ``(True, result)`` once the computation has returned, ``(False, None)`` while stages
        are left.
    """
    for _ in itertools.count() if limit is None else range(limit):
        try:
            next(stages)
        except StopIteration as end:
            return True, end.value
    return False, None
