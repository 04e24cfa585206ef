"""``face-tracking learn``: learn a face model from bags of 3-D meshes and report its quality.

Input bags hold one of:

* ``face_tracking_msgs/FaceTruth`` (synthetic truth, default topic ``truth/face``): nodes in the
  camera frame, subject id and expression label per frame; frames labelled 'neutral' are the
  neutral frames of §3.4;
* ``face_tracking_msgs/FaceMesh`` or ``FaceState`` (a tracker's meshes): subject, label and
  alpha come from ``--truth`` bags (matched by header stamp) when given; otherwise the subject is
  ``--subject``, or the bag's name (the first group of ``--subject-pattern`` in it, if given),
  and the first ``--neutral-frames`` frames of each bag are taken as neutral;
* raw stereo images (left and right Image or CompressedImage, and CameraInfo): first tracked by
  the stereo tracker into FaceMesh bags (:mod:`face_tracking_ros.pipelines.stereo_meshes`),
  every mesh with the frame-1 depths refined over its whole track.

The meshes are aligned (§3.3), the model is learned by ``--method`` (default ``joint``, issue 11;
``seed`` is the paper's §3.4), the evaluation of :mod:`face_tracking_ros.learning.evaluation`
runs for every compared method, and the command writes the model file, a JSON report and, with
``--plots``, PNG figures (Figure 5-like sigma scatter per method, comparison, convergence).

The options become a :class:`~face_tracking_ros.pipelines.learn_options.LearnOptions`, run by
:func:`face_tracking_ros.pipelines.learn.learn_from_bags` (as the learner node runs it).
"""

from __future__ import annotations

import argparse
from dataclasses import fields
from pathlib import Path

from face_tracking_ros.cli.track import add_stereo_topic_options
from face_tracking_ros.learning.methods import DEFAULT_METHOD, METHODS
from face_tracking_ros.model.topology import SUPPORTED_NODE_COUNTS
from face_tracking_ros.pipelines.learn import learn_from_bags
from face_tracking_ros.pipelines.learn_options import LearnOptions
from face_tracking_ros.pipelines.mesh_bags import DEFAULT_TOPICS
from face_tracking_ros.pipelines.stereo_meshes import STEREO_PARAMS
from face_tracking_ros.synthetic.faces import PRESETS

_SEQUENCES = ('bags', 'compare', 'truth', 'tracker_params')  # tuples in LearnOptions
_NOT_GIVEN = (*_SEQUENCES, 'named')  # named: the default, the options' flags


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``learn`` subcommand's options."""
    parser.description = (
        'Align 3-D training meshes (§3.3), learn mean shape, identity basis S, '
        'expression basis A and their Gaussian prior, evaluate the methods side by side '
        '(leave-one-subject-out, truth), write the model file, a JSON report and PNG plots.'
    )
    _add_model_options(parser)
    _add_mesh_options(parser)
    _add_evaluation_options(parser)
    _add_stereo_options(parser)
    parser.set_defaults(func=run)


def _add_model_options(parser: argparse.ArgumentParser) -> None:
    """The bags, the outputs and the learners: BAG, --out, --report, --nodes ... --plots."""
    parser.add_argument(
        'bags',
        nargs='+',
        type=Path,
        metavar='BAG',
        help='bags of meshes (FaceTruth, FaceMesh, FaceState) or of raw stereo images',
    )
    parser.add_argument('--out', required=True, type=Path, help='model file to write (.npz)')
    parser.add_argument('--report', required=True, type=Path, help='JSON report to write')
    parser.add_argument(
        '--nodes',
        type=int,
        choices=SUPPORTED_NODE_COUNTS,
        help="mesh nodes: 19 keeps the first 19 of 34-node meshes (default: the bags' own)",
    )
    parser.add_argument(
        '--p', type=int, default=LearnOptions.p, help='identity dimension (%(default)s)'
    )
    parser.add_argument(
        '--explained-variance',
        type=float,
        help='choose p as the fewest identity modes explaining this share (overrides --p)',
    )
    parser.add_argument(
        '--q', type=int, default=LearnOptions.q, help='expression dimension (%(default)s)'
    )
    parser.add_argument(
        '--method',
        choices=METHODS,
        default=DEFAULT_METHOD,
        help='learner whose model is written: joint (issue 11), seed (the paper, §3.4), '
        'seed-weighted (§4.3); default %(default)s',
    )
    parser.add_argument(
        '--compare',
        nargs='*',
        choices=METHODS,
        default=list(METHODS),
        help='methods to evaluate side by side (default: all; none: only --method)',
    )
    parser.add_argument(
        '--plots', type=Path, help='directory receiving PNG figures (made if missing)'
    )


def _add_mesh_options(parser: argparse.ArgumentParser) -> None:
    """What the meshes are and show: --topic, --subject, --subject-pattern, --truth, ..."""
    parser.add_argument('--topic', help=f'mesh topic (default: first of {DEFAULT_TOPICS})')
    parser.add_argument(
        '--subject',
        help='subject id of every bag without truth (FaceMesh, FaceState, raw stereo images)',
    )
    parser.add_argument(
        '--subject-pattern',
        metavar='REGEX',
        help='bags without truth: the subject id is the first group of REGEX matched against '
        "the bag's name (a .mcap file's without .mcap; default: the whole name), e.g. "
        "'(.+)_\\d+' makes anna_1 and anna_2 two recordings of anna",
    )
    parser.add_argument(
        '--truth',
        nargs='+',
        type=Path,
        metavar='TRUTH_BAG',
        help='one bag per BAG, in the same order, whose truth/face messages label the meshes '
        'of the same stamp (subject, expression, alpha): e.g. the synthetic bags a tracker ran '
        'on (a mesh bag that records which bag it was tracked from must be paired with that one)',
    )
    parser.add_argument(
        '--neutral-frames',
        type=int,
        default=LearnOptions.neutral_frames,
        help='bags without truth (FaceMesh, FaceState, raw stereo images): the first K frames '
        'of each bag show the neutral face; required for them',
    )


def _add_evaluation_options(parser: argparse.ArgumentParser) -> None:
    """Noise on the meshes and the synthetic truth: --add-noise, --seed, --truth-population, ..."""
    parser.add_argument(
        '--add-noise',
        type=float,
        default=LearnOptions.add_noise,
        help='white noise added to every node coordinate, m (e.g. 0.0005 for the issue-4 '
        'protocol on exact truth meshes); seeded by --seed',
    )
    parser.add_argument('--seed', type=int, default=LearnOptions.seed, help='seed of --add-noise')
    parser.add_argument(
        '--truth-population',
        metavar='PRESET[:SEED]',
        help=f'synthetic population of the bags ({", ".join(PRESETS)}) and the seed synth '
        'rendered them with (default 0): adds the comparison with the true subspaces to the '
        'report',
    )
    parser.add_argument(
        '--truth-samples',
        type=int,
        default=LearnOptions.truth_samples,
        help='population faces drawn to estimate the true identity axes (%(default)s)',
    )


def _add_stereo_options(parser: argparse.ArgumentParser) -> None:
    """The tracking of raw stereo bags: --from-images, --init-dir, ... --tracker-param."""
    stereo = parser.add_argument_group(
        'raw stereo bags', 'bags of left/right images are first tracked by the stereo tracker'
    )
    stereo.add_argument(
        '--from-images',
        action='store_true',
        help='track the images of stereo bags even when they also hold truth meshes',
    )
    stereo.add_argument(
        '--init-dir',
        type=Path,
        help='directory of init files <bag name>.yaml|.json (node name -> left-image pixels)',
    )
    stereo.add_argument(
        '--simulate-clicks',
        type=float,
        metavar='PX',
        help="synthetic bags: initialise from the first frame's true nodes with PX pixels of "
        'click noise (written to --init-dir, default: <meshes dir>_clicks/)',
    )
    stereo.add_argument(
        '--auto-init',
        action='store_true',
        help='bags without an init file in --init-dir: find the face with the optional landmark '
        'detector (pip install dlib-bin face_recognition_models)',
    )
    add_stereo_topic_options(stereo)
    stereo.add_argument(
        '--meshes-dir',
        type=Path,
        help='where the tracked mesh bags go (default: <report name>_meshes/ beside the report)',
    )
    stereo.add_argument(
        '--tracker-param',
        action='append',
        metavar='NAME=VALUE',
        help='a stereo_tracker parameter, as the node declares it; repeatable. Default: '
        f"{STEREO_PARAMS} (each track's final depths on all its meshes)",
    )


def run(args: argparse.Namespace) -> None:
    """Read, align, learn, evaluate, write."""
    learn_from_bags(learn_options(args), say=print)


def learn_options(args: argparse.Namespace) -> LearnOptions:
    """The command's arguments as the pipeline's options."""
    given = {
        field.name: getattr(args, field.name)
        for field in fields(LearnOptions)
        if field.name not in _NOT_GIVEN
    }
    return LearnOptions(
        **given,
        bags=tuple(args.bags),
        compare=tuple(args.compare),
        truth=None if args.truth is None else tuple(args.truth),
        tracker_params=tuple(args.tracker_param or ()),
    )
