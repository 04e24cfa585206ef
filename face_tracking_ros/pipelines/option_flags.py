"""How ``face-tracking learn`` and ``track`` spell an option field on the command line.

A module of its own: the tracking side (:mod:`.bag_inputs`) names options in its messages too,
and importing :mod:`.learn_options` for it would load the learning side (the synthetic
population's scipy.stats: 0.4 s) into every ``face-tracking track``.
"""

from __future__ import annotations


def option_flag(field: str) -> str:
    """The command-line option of an option field, as ``learn`` and ``track`` spell it.

    E.g. ``--subject-pattern`` for ``subject_pattern``, ``--left-topic`` for ``left_topic``;
    ``--tracker-param`` (repeatable) for ``tracker_params``.
    """
    return '--tracker-param' if field == 'tracker_params' else f'--{field.replace("_", "-")}'
