"""Report figures of model learning: seed Figure 5 (sigma per frame), comparison, convergence.

Written as PNG with matplotlib's object API (no pyplot state, no display needed).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from matplotlib import colormaps
from matplotlib.figure import Figure
import numpy as np

from face_tracking_ros.learning.evaluation import Evaluation
from face_tracking_ros.learning.result import LearningResult

_COMPARED = (
    ('loo_shape_similarity', 'LOO sim. S'),
    ('loo_action_similarity', 'LOO sim. A'),
    ('sigma_silhouette', 'sigma silhouette'),
    ('identity_accuracy', 'identity acc.'),
    ('expression_accuracy', 'expression acc.'),
)
_COMPARED_TRUTH = (
    ('shape_similarity', 'S vs true'),
    ('action_share', 'A in true expr.'),
)


def plot_sigma_scatter(
    frame_sigma: np.ndarray,
    subject_index: np.ndarray,
    subject_ids: Sequence[str],
    path: str | Path,
    title: str = '',
) -> Path:
    """Figure 5 of the seed: the first two sigma components of every frame, one colour a subject.

    Args:
        frame_sigma: (F, p) per-frame sigma, metres (plotted in mm); p >= 1.
        subject_index: (F,) subject of each frame.
        subject_ids: names of the subjects.
        path: PNG file to write.
        title: figure title.

    Returns:
        The path written.
    """
    figure = Figure(figsize=(6.5, 5.5), layout='constrained')
    axes = figure.add_subplot()
    sigma_mm = 1000.0 * np.column_stack([frame_sigma, np.zeros(len(frame_sigma))])[:, :2]
    colours = [colormaps['tab20'](k % 20) for k in range(len(subject_ids))]
    for s, subject in enumerate(subject_ids):
        mine = sigma_mm[subject_index == s]
        axes.scatter(mine[:, 0], mine[:, 1], s=4, alpha=0.35, color=colours[s], label=subject)
        centre = mine.mean(axis=0)
        axes.annotate(subject, centre, fontsize=7, ha='center', va='center', weight='bold')
    axes.set_xlabel('sigma 1 (mm)')
    axes.set_ylabel('sigma 2 (mm)')
    axes.set_title(title or 'Shape parameters of all training frames (cf. seed Figure 5)')
    axes.set_aspect('equal', adjustable='datalim')
    axes.grid(alpha=0.3)
    return _save(figure, path)


def plot_comparison(evaluations: Mapping[str, Evaluation], path: str | Path) -> Path:
    """Grouped bars of the main figures of several learners (issue 11 comparison)."""
    rows = list(_COMPARED)
    if all(evaluation.truth is not None for evaluation in evaluations.values()):
        rows += [(f'truth.{key}', title) for key, title in _COMPARED_TRUTH]
    figure = Figure(figsize=(9.0, 4.5), layout='constrained')
    axes = figure.add_subplot()
    width = 0.8 / max(len(evaluations), 1)
    positions = np.arange(len(rows))
    for k, (name, evaluation) in enumerate(evaluations.items()):
        values = [_value(evaluation, key) for key, _ in rows]
        axes.bar(positions + k * width, values, width, label=name)
    axes.set_xticks(positions + 0.4 - width / 2, [title for _, title in rows], rotation=20)
    axes.set_ylim(0.0, 1.05)
    axes.axhline(1.0, color='grey', linewidth=0.5)
    axes.legend()
    axes.set_title('Learning methods compared (1 = best)')
    return _save(figure, path)


def plot_convergence(results: Mapping[str, LearningResult], path: str | Path) -> Path:
    """Change per iteration of each learner, log scale."""
    figure = Figure(figsize=(6.0, 4.0), layout='constrained')
    axes = figure.add_subplot()
    for name, result in results.items():
        history = np.maximum(result.history, 1e-16)
        axes.semilogy(np.arange(1, len(history) + 1), history, marker='o', label=name)
    axes.set_xlabel('iteration')
    axes.set_ylabel('change (1 - subspace similarity)')
    axes.grid(alpha=0.3)
    axes.legend()
    return _save(figure, path)


def _value(evaluation: Evaluation, key: str) -> float:
    """A (possibly 'truth.'-prefixed) figure of an evaluation; NaN plots as no bar."""
    if key.startswith('truth.'):
        return float(getattr(evaluation.truth, key.removeprefix('truth.')))
    return float(getattr(evaluation, key))


def _save(figure: Figure, path: str | Path) -> Path:
    """Write the figure as PNG."""
    path = Path(path)
    figure.savefig(path, dpi=110)
    return path
