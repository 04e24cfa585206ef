"""``face-tracking demo --out DIR``: the whole system, end to end, on the synthetic world.

Each step runs a public ``face-tracking`` command, printed before it runs, so every step can be
repeated by hand:

1. ``synth``: stereo training sequences of several subjects (head almost still, expressions in
   turn, as in the seed's protocol) and monocular test sequences with free head motion;
2. ``track``: the stereo tracker (eq. 4, 5) turns the training sequences into 3-D meshes, each
   with the frame-1 depths refined over its whole sequence, as ``learn`` tracks raw stereo bags;
3. ``learn``: the face model (mean shape, S, A, prior) from those meshes, with the leave-one-
   subject-out table;
4. ``train-expressions``: the expression classifier on the learned model's alpha;
5. ``track``: monocular tracking (eq. 6) of the test sequences, scored against truth;
6. ``enroll`` and ``replay``: identity enrolment, then expression and identity events fired by
   the recognisers fed by the tracker's outputs, printed as they fire;
7. ``plot`` and ``overlay``: a PNG of pose, alpha and sigma over time and an MP4 of the tracked
   mesh, in ``DIR``.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
import shutil
import time

from face_tracking_ros.cli import main as cli
from face_tracking_ros.cli.learn import STEREO_PARAMS
from face_tracking_ros.errors import ConfigError

MARKER = '.face-tracking-demo'  # in an --out the demo made, which a later demo may empty


@dataclass(frozen=True)
class DemoPlan:
    """Sizes of the demo's synthetic world.

    Attributes:
        subjects: training subjects (stereo).
        training_frames: frames per stereo training sequence (10 fps).
        known: training subjects who also get monocular test sequences (enrolled).
        test_frames: frames per monocular test sequence (30 fps).
        seed: seed of the world.
    """

    subjects: int = 11
    training_frames: int = 60
    known: int = 2
    test_frames: int = 240
    seed: int = 7


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``demo`` subcommand."""
    parser = subparsers.add_parser(
        'demo',
        help='run the whole system end to end on the synthetic world',
        description=__doc__.split('\n\n')[0],
    )
    parser.add_argument(
        '--out',
        type=Path,
        default=Path('out'),
        help='output directory; emptied first if an earlier demo made it, refused if it holds '
        'anything else (%(default)s)',
    )
    parser.add_argument(
        '--subjects', type=int, default=DemoPlan.subjects, help='training subjects'
    )
    parser.add_argument('--seed', type=int, default=DemoPlan.seed, help='seed of the world')
    parser.add_argument(
        '--keep', action='store_true', help='write into an existing --out without emptying it'
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run every step; stop at the first that fails."""
    plan = DemoPlan(subjects=args.subjects, seed=args.seed)
    if plan.subjects < 3 or plan.known > plan.subjects:
        msg = f'the demo needs at least 3 training subjects, got {plan.subjects}'
        raise ConfigError(msg)
    out = args.out
    if out.exists() and not args.keep:
        _empty_earlier_demo(out)
    (out / 'learn').mkdir(parents=True, exist_ok=True)
    (out / MARKER).write_text('written by face-tracking demo: it empties this directory\n')
    start = time.perf_counter()
    for title, argv in steps(plan, out):
        _banner(title, argv, time.perf_counter() - start)
        status = cli.main(argv)
        if status:
            print(f'demo: step failed with exit status {status}: {" ".join(argv)}')
            return status
    print(f'\ndemo finished in {time.perf_counter() - start:.0f} s; results in {out}/')
    return 0


def _empty_earlier_demo(out: Path) -> None:
    """Remove ``out`` if it is empty or an earlier demo's (it holds :data:`MARKER`).

    Raises:
        ConfigError: if it holds anything else: a user's directory is not deleted.
    """
    if (out / MARKER).exists() or not any(out.iterdir()):
        shutil.rmtree(out)
        return
    msg = (
        f'--out {out} exists and was not made by the demo: not emptied (remove it, give another '
        '--out, or --keep to write into it)'
    )
    raise ConfigError(msg)


def steps(plan: DemoPlan, out: Path) -> list[tuple[str, list[str]]]:
    """The demo's commands, in order, as (title, face-tracking arguments)."""
    train, test = out / 'train', out / 'test'
    model, classifier, gallery = out / 'model.npz', out / 'expressions.npz', out / 'gallery.npz'
    training = [train / f'subject_{s:02d}_seq_00' for s in range(plan.subjects)]
    meshes = [out / 'meshes' / bag.name for bag in training]
    # Test sequences of the first `known` training subjects: sequence 0 enrols them, sequence 1
    # tests them; a stranger is a subject of another seed.
    enrolment = [test / f'subject_{s:02d}_seq_00' for s in range(plan.known)]
    known = [test / f'subject_{s:02d}_seq_01' for s in range(plan.known)]
    stranger = out / 'stranger' / 'subject_00_seq_00'
    tracked = {
        bag: out / 'tracked' / f'{bag.parent.name}_{bag.name}'
        for bag in [*known, *enrolment, stranger]
    }
    steps: list[tuple[str, list[str]]] = [
        (
            '1a. synthetic stereo training set',
            [
                'synth',
                '--kind',
                'stereo',
                '--subjects',
                str(plan.subjects),
                '--frames',
                str(plan.training_frames),
                '--fps',
                '10',
                '--motion',
                'still',
                '--seed',
                str(plan.seed),
                '--out',
                str(train),
            ],
        ),
        (
            '1b. synthetic monocular test sequences (free head motion)',
            [
                'synth',
                '--kind',
                'mono',
                '--subjects',
                str(plan.known),
                '--sequences',
                '2',
                '--frames',
                str(plan.test_frames),
                '--fps',
                '30',
                '--motion',
                'free',
                '--seed',
                str(plan.seed),
                '--out',
                str(test),
            ],
        ),
        (
            '1c. a stranger, never enrolled',
            [
                'synth',
                '--kind',
                'mono',
                '--subjects',
                '1',
                '--frames',
                str(plan.test_frames),
                '--fps',
                '30',
                '--motion',
                'free',
                '--seed',
                str(plan.seed + 1000),
                '--out',
                str(stranger.parent),
            ],
        ),
    ]
    steps += [
        (
            f'2. stereo tracking of {bag.name} (3-D meshes for learning)',
            [
                'track',
                str(bag),
                '--simulate-clicks',
                '1.0',
                '--param',
                STEREO_PARAMS,
                '--out',
                str(mesh),
                '--quiet',
            ],
        )
        for bag, mesh in zip(training, meshes, strict=True)
    ]
    steps += [
        (
            '3. learning the face model from the tracked meshes',
            [
                'learn',
                *map(str, meshes),
                '--truth',
                *map(str, training),
                '--out',
                str(model),
                '--report',
                str(out / 'learn.json'),
                '--plots',
                str(out / 'learn'),
                '--compare',
                'seed',
            ],
        ),
        (
            '4. training the expression classifier on the learned model',
            [
                'train-expressions',
                *map(str, training),
                '--model',
                str(model),
                '--out',
                str(classifier),
            ],
        ),
    ]
    steps += [
        (
            f'5. monocular tracking of {bag.parent.name}/{bag.name}, scored against truth',
            [
                'track',
                str(bag),
                '--model',
                str(model),
                '--simulate-clicks',
                '1.0',
                '--out',
                str(result),
                '--report',
                str(result.parent / f'{result.name}.json'),
                '--quiet',
            ],
        )
        for bag, result in tracked.items()
    ]
    steps += [
        (
            f'6a. enrolling subject_{s:02d}',
            [
                'enroll',
                str(tracked[bag]),
                '--name',
                f'subject_{s:02d}',
                '--gallery',
                str(gallery),
            ],
        )
        for s, bag in enumerate(enrolment)
    ]
    recognisers = 'expression_recognizer,identity_recognizer'
    steps += [
        (
            f'6b. expression and identity events of {bag.parent.name}/{bag.name}',
            [
                'replay',
                recognisers,
                str(tracked[bag]),
                '--out',
                str(out / 'events' / tracked[bag].name),
                '--param',
                f'model_file={model}',
                '--param',
                f'classifier_file={classifier}',
                '--param',
                f'gallery_file={gallery}',
                '--echo',
                'face/expression',
                '--echo',
                'face/identity',
                '--quiet',
            ],
        )
        for bag in [*known, stranger]
    ]
    first = known[0]
    steps += [
        (
            '7a. plot of the first test sequence',
            [
                'plot',
                str(tracked[first]),
                '--truth',
                str(first),
                '--png',
                str(out / 'tracking.png'),
            ],
        ),
        (
            '7b. overlay video of the first test sequence',
            [
                'overlay',
                str(first),
                str(tracked[first]),
                '--video',
                str(out / 'tracking.mp4'),
            ],
        ),
    ]
    return steps


def _banner(title: str, argv: list[str], elapsed: float) -> None:
    print(f'\n=== [{elapsed:5.0f} s] {title}\n$ face-tracking {" ".join(argv)}', flush=True)
