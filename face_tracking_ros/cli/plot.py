"""``face-tracking plot OUT [--truth BAG] --png FILE``: pose, alpha and sigma over time."""

from __future__ import annotations

import argparse
from pathlib import Path

from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import check_output_path
from face_tracking_ros.io.provenance import other_source
from face_tracking_ros.io.series import has_truth, load_states, load_truth, require_parameters
from face_tracking_ros.visualization.plots import plot_tracking


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``plot`` subcommand's options."""
    parser.description = (
        'Draw the FaceState series of a tracking output bag (face-tracking track or '
        'replay, or a recorded bag) as a PNG: rotation angles, translation, alpha and sigma '
        'over time, against the truth of a synthetic bag when given.'
    )
    parser.add_argument('out', type=Path, help='bag holding face/state')
    parser.add_argument(
        '--truth', type=Path, help='synthetic bag with truth/face: the one OUT was tracked from'
    )
    parser.add_argument('--png', type=Path, required=True, help='PNG file to write')
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    """Write the plot.

    Raises:
        ConfigError: for a ``--png`` not ending in .png or in a missing directory, or a
            ``--truth`` bag without truth/face or other than the one OUT was tracked from.
        BagError: if OUT holds no face/state, or states without sigma and alpha.
    """
    if args.png.suffix.lower() != '.png':
        msg = f'--png {args.png}: give a file name ending in .png'
        raise ConfigError(msg)
    check_output_path(args.png, '--png', parent_made=False)
    if args.truth and not has_truth(args.truth):
        msg = f'--truth {args.truth} holds no truth/face (a synthetic bag has it)'
        raise ConfigError(msg)
    source = other_source(args.out, args.truth) if args.truth else None
    if source is not None:
        msg = f'--truth {args.truth}: {args.out} was tracked from {source}, not from {args.truth}'
        raise ConfigError(msg)
    truth = load_truth(args.truth) if args.truth else None
    states = load_states(args.out)
    lengths = {'sigma': states.sigma.shape[1], 'alpha': states.alpha.shape[1]}
    require_parameters(args.out, lengths)  # without them, no pose either: nothing to draw
    plot_tracking(states, truth, args.png)
    print(f'wrote {args.png}')
