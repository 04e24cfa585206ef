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
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import check_output_path
from face_tracking_ros.pipelines.stereo_meshes import STEREO_PARAMS

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


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``demo`` subcommand's options."""
    parser.description = __doc__.split('\n\n')[0].replace('``', '')
    parser.add_argument(
        '--out',
        type=Path,
        default=Path('out'),
        help='output directory; emptied first if an earlier demo made it, refused if it holds '
        'anything else (%(default)s)',
    )
    parser.add_argument(
        '--subjects',
        type=int,
        default=DemoPlan.subjects,
        help='training subjects, >= 3 (%(default)s)',
    )
    parser.add_argument(
        '--seed', type=int, default=DemoPlan.seed, help='seed of the world (%(default)s)'
    )
    parser.add_argument(
        '--keep', action='store_true', help='write into an existing --out without emptying it'
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run every step; stop at the first that fails.

    Raises:
        ConfigError: for fewer than 3 subjects, or an ``--out`` that is not a directory or,
            without ``--keep``, holds anything but an earlier demo's output.
    """
    plan = DemoPlan(subjects=args.subjects, seed=args.seed)
    if plan.subjects < 3 or plan.known > plan.subjects:
        msg = f'the demo needs at least 3 training subjects, got {plan.subjects}'
        raise ConfigError(msg)
    out = args.out
    check_output_path(out, '--out', directory=True)
    if out.exists() and not args.keep:
        _empty_earlier_demo(out)
    made = not out.exists()  # only a directory the demo makes is marked as the demo's
    (out / 'learn').mkdir(parents=True, exist_ok=True)
    if made:
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


Step = tuple[str, list[str]]


@dataclass(frozen=True)
class DemoFiles:
    """Where the demo's steps read and write, below its ``--out``.

    Attributes:
        out: the demo's output directory.
        training: the stereo training bags, one per subject.
        meshes: the stereo tracker's mesh bags, one per training bag.
        enrolment: the monocular bags that enrol the known subjects (their sequence 0).
        known: the known subjects' monocular test bags (their sequence 1).
        stranger: a subject of another seed, never enrolled.
        tracked: each monocular bag's tracked outputs.
    """

    out: Path
    training: list[Path]
    meshes: list[Path]
    enrolment: list[Path]
    known: list[Path]
    stranger: Path
    tracked: dict[Path, Path]

    @classmethod
    def of(cls, plan: DemoPlan, out: Path) -> DemoFiles:
        """The files of ``plan``'s demo in ``out``.

        The monocular test sequences are of the first ``plan.known`` training subjects:
        sequence 0 enrols them, sequence 1 tests them; the stranger is a subject of another seed.
        """
        training = [out / 'train' / f'subject_{s:02d}_seq_00' for s in range(plan.subjects)]
        enrolment = [out / 'test' / f'subject_{s:02d}_seq_00' for s in range(plan.known)]
        known = [out / 'test' / f'subject_{s:02d}_seq_01' for s in range(plan.known)]
        stranger = out / 'stranger' / 'subject_00_seq_00'
        return cls(
            out=out,
            training=training,
            meshes=[out / 'meshes' / bag.name for bag in training],
            enrolment=enrolment,
            known=known,
            stranger=stranger,
            tracked={
                bag: out / 'tracked' / f'{bag.parent.name}_{bag.name}'
                for bag in [*known, *enrolment, stranger]
            },
        )

    @property
    def model(self) -> Path:
        """The learned face model."""
        return self.out / 'model.npz'

    @property
    def classifier(self) -> Path:
        """The expression classifier trained on the learned model."""
        return self.out / 'expressions.npz'

    @property
    def gallery(self) -> Path:
        """The identity gallery of the known subjects."""
        return self.out / 'gallery.npz'


def steps(plan: DemoPlan, out: Path) -> list[Step]:
    """The demo's commands, in order, as (title, face-tracking arguments)."""
    files = DemoFiles.of(plan, out)
    return [
        *_synthesis(plan, files),
        *_stereo_tracking(files),
        *_learning(files),
        *_monocular_tracking(files),
        *_recognition(files),
        *_pictures(files),
    ]


def _synth(
    kind: str, subjects: int, frames: int, seed: int, out: Path, sequences: int = 1
) -> list[str]:
    """``synth`` arguments: stereo training (10 fps, head still) or mono tests (30 fps, free)."""
    fps, motion = ('10', 'still') if kind == 'stereo' else ('30', 'free')
    more = ['--sequences', str(sequences)] if sequences > 1 else []
    return [
        *('synth', '--kind', kind, '--subjects', str(subjects), *more, '--frames', str(frames)),
        *('--fps', fps, '--motion', motion, '--seed', str(seed), '--out', str(out)),
    ]


def _synthesis(plan: DemoPlan, files: DemoFiles) -> list[Step]:
    """Step 1: the stereo training set, the known subjects' mono test sequences, a stranger."""
    training, tests = files.training[0].parent, files.known[0].parent
    return [
        (
            '1a. synthetic stereo training set',
            _synth('stereo', plan.subjects, plan.training_frames, plan.seed, training),
        ),
        (
            '1b. synthetic monocular test sequences (free head motion)',
            _synth('mono', plan.known, plan.test_frames, plan.seed, tests, sequences=2),
        ),
        (
            '1c. a stranger, never enrolled',
            _synth('mono', 1, plan.test_frames, plan.seed + 1000, files.stranger.parent),
        ),
    ]


def _stereo_tracking(files: DemoFiles) -> list[Step]:
    """Step 2: each training bag through the stereo tracker, to 3-D meshes."""
    return [
        (
            f'2. stereo tracking of {bag.name} (3-D meshes for learning)',
            [
                *('track', str(bag), '--simulate-clicks', '1.0', '--param', STEREO_PARAMS),
                *('--out', str(mesh), '--quiet'),
            ],
        )
        for bag, mesh in zip(files.training, files.meshes, strict=True)
    ]


def _learning(files: DemoFiles) -> list[Step]:
    """Steps 3 and 4: the face model from the meshes, the expression classifier on it."""
    out = files.out
    return [
        (
            '3. learning the face model from the tracked meshes',
            [
                *('learn', *map(str, files.meshes), '--truth', *map(str, files.training)),
                *('--out', str(files.model), '--report', str(out / 'learn.json')),
                *('--plots', str(out / 'learn'), '--compare', 'seed'),
            ],
        ),
        (
            '4. training the expression classifier on the learned model',
            [
                *('train-expressions', *map(str, files.training)),
                *('--model', str(files.model), '--out', str(files.classifier)),
            ],
        ),
    ]


def _monocular_tracking(files: DemoFiles) -> list[Step]:
    """Step 5: each monocular bag through the mono tracker, scored against its truth."""
    return [
        (
            f'5. monocular tracking of {bag.parent.name}/{bag.name}, scored against truth',
            [
                *('track', str(bag), '--model', str(files.model), '--simulate-clicks', '1.0'),
                *('--out', str(result), '--report', str(result.parent / f'{result.name}.json')),
                '--quiet',
            ],
        )
        for bag, result in files.tracked.items()
    ]


def _recognition(files: DemoFiles) -> list[Step]:
    """Step 6: enrol the known subjects, then the recognisers' events on the test tracks."""
    enrol = [
        (
            f'6a. enrolling subject_{s:02d}',
            [
                *('enroll', str(files.tracked[bag]), '--name', f'subject_{s:02d}'),
                *('--gallery', str(files.gallery)),
            ],
        )
        for s, bag in enumerate(files.enrolment)
    ]
    models = [f'model_file={files.model}', f'classifier_file={files.classifier}']
    models.append(f'gallery_file={files.gallery}')
    events = [
        (
            f'6b. expression and identity events of {bag.parent.name}/{bag.name}',
            [
                *('replay', 'expression_recognizer,identity_recognizer', str(files.tracked[bag])),
                *('--out', str(files.out / 'events' / files.tracked[bag].name)),
                *(item for model in models for item in ('--param', model)),
                *('--echo', 'face/expression', '--echo', 'face/identity', '--quiet'),
            ],
        )
        for bag in [*files.known, files.stranger]
    ]
    return enrol + events


def _pictures(files: DemoFiles) -> list[Step]:
    """Step 7: a plot and an overlay video of the first test sequence."""
    first = files.known[0]
    tracked = str(files.tracked[first])
    return [
        (
            '7a. plot of the first test sequence',
            ['plot', tracked, '--truth', str(first), '--png', str(files.out / 'tracking.png')],
        ),
        (
            '7b. overlay video of the first test sequence',
            ['overlay', str(first), tracked, '--video', str(files.out / 'tracking.mp4')],
        ),
    ]


def _banner(title: str, argv: list[str], elapsed: float) -> None:
    print(f'\n=== [{elapsed:5.0f} s] {title}\n$ face-tracking {" ".join(argv)}', flush=True)
