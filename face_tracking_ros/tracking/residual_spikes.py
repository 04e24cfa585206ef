"""A node patch whose residual leaps on a pair: an expression's onset the prediction missed (§3.3).

The stereo tracker starts each pair from each node's own motion carried on, and solves it on the
two finest pyramid levels, with one coarser level when the head moves fast
(:meth:`~.stereo.StereoTracker._moving_fast`). An expression's onset is not predicted: at 10 fps a
talking jaw opens or closes by half its range from one pair to the next (rendered free motion,
seed 8: 0.79 -> 0.27 -> 0.69 of its range over pairs 64-66), beyond the two levels' reach from the
start, and the lower lip and chin settled 4-5 px off, where the frame n - 1 templates then held
them: 15.6 px off by pair 81, TRACKING. On that pair their patches' residuals leapt (the chin's
ratio to its template contrast 4.8 times its median over the pairs before). Such a pair is solved
again from one coarser level, as a fast head's is, and the second solve taken where its total
residual is clearly lower (:data:`SOLVE_GAIN`; :func:`~.stereo_loss.residual_total`: the median
the loss checks use hardly moves for a few nodes).

A patch's usual level is its ratio's median over the last :data:`MEMORY` pairs of the track: some
patches read several times the others' on every pair, and one threshold for all (the pair's median
times 5) asked for the second solve on 64-68 % of the rendered free-motion pairs. Only the inner
patches (eyes, brows, nose, mouth) are watched: the face edge's, which each camera sees turn away
differently, leap on ordinary pairs too. Watched with them, 6.4 % of the 30-fps free-motion pairs
were solved twice, for nothing there (seeds 0-7, pairs more than 3 px off 2 -> 2), against 0.09 %
(one pair) with the inner patches alone; at 10 fps, seeds 0-31, the pairs more than 3 px off went
126 -> 84 with them and 126 -> 90 without (seed 11's chin, a face-edge node, stays 5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from face_tracking_ros.tracking.robust import nanmedian_columns

SPIKE_FACTOR = 4.0  # a patch's ratio beyond this times its usual level leaps
SPIKE_FLOOR = 0.25  # and beyond this: a patch of flat skin leaps from its noise floor
MEMORY = 30  # the pairs whose median ratio is a patch's usual level (1 s at 30 fps)
MIN_PAIRS = 3  # fewer pairs since the track started tell no usual level
# The second solve is taken only below this times the first's total residual: on the pairs it
# mended at 10 fps it was 0.27-0.32 times; as an occluder left a pucker started under it (seed 4,
# test_nodes_still_flagged_as_the_occluder_leaves_are_found_again) a second solve at 0.996 times
# was taken, and the track went 26 px off where it had stayed within 5.5 px.
SOLVE_GAIN = 0.8


@dataclass
class PatchResiduals:
    """The inner node patches' residual-to-contrast ratios on a track's recent pairs.

    Attributes:
        recent: (:data:`MEMORY`, N) the ratios of the last pairs, row ``pairs % MEMORY`` the
            next to be replaced (NaN: a row not filled yet, or a patch without valid samples);
            None before the first pair.
        pairs: pairs taken in since the track started.
    """

    recent: np.ndarray | None = None
    pairs: int = 0

    def leapt(self, ratios: np.ndarray) -> bool:
        """Whether a patch's ratio on this pair leapt from its usual level.

        Beyond :data:`SPIKE_FACTOR` times the median of its recent ratios and beyond
        :data:`SPIKE_FLOOR`; never before :data:`MIN_PAIRS` pairs.

        Args:
            ratios: (N,) this pair's ratios (NaN: not compared).
        """
        if self.recent is None or self.pairs < MIN_PAIRS:
            return False
        candidates = ratios > SPIKE_FLOOR  # most pairs have none: no median to take
        if not candidates.any():
            return False
        usual = nanmedian_columns(self.recent[:, candidates])
        with np.errstate(invalid='ignore'):
            return bool(np.any(ratios[candidates] > SPIKE_FACTOR * usual))

    def add(self, ratios: np.ndarray) -> None:
        """Take a tracked pair's ratios in, in place of those :data:`MEMORY` pairs before."""
        if self.recent is None:
            self.recent = np.full((MEMORY, ratios.size), np.nan)
        self.recent[self.pairs % MEMORY] = ratios
        self.pairs += 1
