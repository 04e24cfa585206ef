"""How a learning run reads what several of its steps need of a bag: its topics and its truth.

Learn's checks, the tracking of raw stereo bags and the reading of the meshes each ask for a
bag's topics and truth; :meth:`BagReads.once` reads each bag's once a run, where every step read
them again (a bag's topics cost 23 ms, its truth 25-30 ms, on the sample bags).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import functools
from pathlib import Path

from face_tracking_ros.io.bags import bag_topics
from face_tracking_ros.io.conversions import TruthSample
from face_tracking_ros.io.series import read_truth


@dataclass(frozen=True)
class BagReads:
    """How a bag's topics and the truth of its FaceTruth topic are read.

    Attributes:
        topics: a bag's topics, name -> type (:func:`~face_tracking_ros.io.bags.bag_topics`).
        truth: the truth samples of a bag's FaceTruth topic, in record order
            (:func:`~face_tracking_ros.io.series.read_truth`).
    """

    topics: Callable[[Path], dict[str, str]] = bag_topics
    truth: Callable[[Path, str], Sequence[TruthSample]] = read_truth

    @classmethod
    def once(cls) -> BagReads:
        """Reads that keep what they read: each bag's topics and truth read once (one run's).

        What a read raises is raised again by the next read of the same bag, as before.
        """
        return cls(functools.cache(bag_topics), functools.cache(read_truth))


AFRESH = BagReads()  # every read reads the bag: for a single step's use
