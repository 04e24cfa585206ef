"""Which brightness changes of a patch the mono tracker's residuals ignore (:mod:`.photometric`).

Apart from :mod:`.photometric`'s compiled kernels, so that the tracker's configuration (and
whatever reads it: a stereo track, the parameter tables) names the model without loading them.
"""

from __future__ import annotations

from enum import IntEnum


class PhotometricModel(IntEnum):
    """Which brightness change of a patch the residual ignores."""

    NONE = 0
    BIAS = 1
    GAIN_BIAS = 2
    GAIN_FIELD = 3
