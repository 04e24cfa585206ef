"""Time-series plots of tracking results, against truth when there is one (matplotlib)."""

from __future__ import annotations

from pathlib import Path

from matplotlib.axes import Axes
from matplotlib.figure import Figure
import numpy as np

from face_tracking_ros.geometry.rotation import omega_to_angles
from face_tracking_ros.io.series import StateSeries, TruthSeries

_AXES = ('x (pitch)', 'y (yaw)', 'z (roll)')


def plot_tracking(states: StateSeries, truth: TruthSeries | None, png: Path) -> Path:
    """Draw rotation (deg), translation (mm), alpha and sigma over time into ``png``.

    Args:
        states: the tracker's outputs.
        truth: the synthetic truth of the same sequence, drawn dashed; None for real data.
        png: output file.

    Returns:
        ``png``.
    """
    start = states.stamps[0]
    seconds = (states.stamps - start) / 1e9
    figure = Figure(figsize=(10, 11), layout='constrained')
    axes = figure.subplots(4, 1, sharex=True)
    angles = np.degrees(omega_to_angles(states.omega))
    colours = ('tab:red', 'tab:green', 'tab:blue')
    for k in range(3):
        axes[0].plot(seconds, angles[:, k], color=colours[k], label=f'about {_AXES[k]}')
        axes[1].plot(seconds, 1000 * states.t[:, k], color=colours[k], label='xyz'[k])
    if truth is not None:
        truth_seconds = (truth.stamps - start) / 1e9
        truth_angles = np.degrees(omega_to_angles(truth.omega))
        for k in range(3):
            axes[0].plot(truth_seconds, truth_angles[:, k], '--', color=colours[k], alpha=0.6)
            axes[1].plot(truth_seconds, 1000 * truth.t[:, k], '--', color=colours[k], alpha=0.6)
        axes[0].set_title('rotation (solid: tracked, dashed: truth)')
    else:
        axes[0].set_title('rotation')
    axes[0].set_ylabel('deg')
    axes[1].set_ylabel('translation, mm')
    axes[1].set_yscale('symlog', linthresh=100)
    _plot_parameters(axes[2], seconds, states.alpha, 'alpha (expression)')
    _plot_parameters(axes[3], seconds, states.sigma, 'sigma (identity)')
    lost = states.status != 1
    for axis in axes:
        axis.legend(loc='upper right', fontsize=7, ncol=3)
        axis.grid(alpha=0.3)
        if lost.any():
            axis.fill_between(
                seconds,
                0,
                1,
                where=lost,
                transform=axis.get_xaxis_transform(),
                color='red',
                alpha=0.1,
                step='mid',
            )
    axes[3].set_xlabel('time, s')
    figure.savefig(png, dpi=100)
    return png


def _plot_parameters(axis: Axes, seconds: np.ndarray, values: np.ndarray, title: str) -> None:
    """One line per parameter, in mm (the bases are orthonormal in metres)."""
    for k in range(values.shape[1]):
        axis.plot(seconds, 1000 * values[:, k], label=f'{title.split()[0]}[{k}]')
    axis.set_ylabel(f'{title}, mm')
