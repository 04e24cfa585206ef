"""The learning methods by name, as the command line, the learner node and the model file use them.

* ``joint`` (default): the within/between-subject learner of issue 11
  (:func:`~face_tracking_ros.learning.joint.learn_joint`);
* ``seed``: the seed paper's §3.4 loop (:func:`~face_tracking_ros.learning.seed.learn_seed`);
* ``seed-weighted``: §3.4 with the §4.3 eigenvalue-weighted projection.

Every learner takes an aligned :class:`~face_tracking_ros.learning.training_set.TrainingSet`
(see :func:`~face_tracking_ros.learning.alignment.align_training_set`).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.learning.joint import JointConfig, learn_joint
from face_tracking_ros.learning.result import LearningResult
from face_tracking_ros.learning.seed import SeedConfig, learn_seed
from face_tracking_ros.learning.training_set import TrainingSet

METHODS = ('joint', 'seed', 'seed-weighted')
DEFAULT_METHOD = 'joint'
DEFAULT_EXPLAINED_VARIANCE = 0.95

Learner = Callable[[TrainingSet], LearningResult]


def make_learner(
    method: str = DEFAULT_METHOD,
    p: int | None = 2,
    q: int = 5,
    explained_variance: float = DEFAULT_EXPLAINED_VARIANCE,
) -> Learner:
    """The learning function of a method name.

    Args:
        method: one of :data:`METHODS`.
        p: identity dimension; None chooses the fewest modes explaining ``explained_variance``
            of the neutral-shape variance.
        q: expression dimension.
        explained_variance: share used when p is None.

    Raises:
        ConfigError: for an unknown method.
    """
    if method == 'joint':
        config = JointConfig(p=p, q=q, explained_variance=explained_variance)
        return partial(learn_joint, config=config)
    if method in ('seed', 'seed-weighted'):
        weighted = method == 'seed-weighted'
        seed_config = SeedConfig(
            p=p, q=q, explained_variance=explained_variance, eigenvalue_weighted=weighted
        )
        return partial(learn_seed, config=seed_config)
    msg = f'unknown learning method {method!r}; choose one of {METHODS}'
    raise ConfigError(msg)
