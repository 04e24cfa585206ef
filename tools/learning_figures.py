"""Reproduce the two figures of docs/learning.md that no ``face-tracking`` command prints.

1. Learning from a monocular tracker's meshes gives back the model it tracked with: mono
   synthetic bags of five default-population subjects (``face-tracking synth --kind mono``,
   rendered as tools/make_default_data.sh renders the packaged models' training bags, but with
   seed 1) are tracked with the packaged 34-node model (``face-tracking track --simulate-clicks
   1``), and their FaceState meshes learned from (``face-tracking learn --topic face/state``,
   joint, p = 2, q = 5, labelled by the bags' truth). Printed: how much of the learned A lies
   inside the tracking model's A, and of the learned S inside its [S A].
2. Eleven subjects do not share the population's top-2 identity axes: for each population seed
   0..DRAWS-1 of the realistic preset, the eleven subjects ``face-tracking synth --population
   realistic --subjects 11 --seed SEED`` renders (seed 0: the tests' training subjects). The
   top-2 principal subspace of their true neutral faces (unaligned, about their mean) is scored
   against the population's true top-2 identity axes (``TruthBases.identity_principal_axes``).
   Printed per node count: seed 0's score, the median, the 10th-90th percentiles and the maximum.

Both use the package's subspace similarity (``learning.subspace.subspace_similarity``: the mean
squared cosine of the principal angles). Deterministic: every draw is seeded.

Usage: ``python tools/learning_figures.py [--work DIR] [--draws 200]`` (about 20 s).
"""

from __future__ import annotations

import argparse
import contextlib
import io
from pathlib import Path
import tempfile

import numpy as np

from face_tracking_ros.cli.main import main as face_tracking_main
from face_tracking_ros.data import default_model_path
from face_tracking_ros.learning.subspace import principal_components, subspace_similarity
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.synthetic.faces import FacePopulation

# Figure 1's mono world, tracking and learning; mono_model_recovery adds the bags and outputs.
MONO_WORLD = (
    '--kind mono --motion still --subjects 5 --frames 150 --fps 10 --size 320x240 --focal 300 '
    '--seed 1'
)
TRACK = '--simulate-clicks 1 --quiet'
LEARN = '--topic face/state --p 2 --q 5 --compare'
SAMPLE_SUBJECTS = 11  # figure 2: subjects per draw
P = 2  # figure 2: the identity dimension compared


def face_tracking(*argv: str | Path) -> None:
    """Run one ``face-tracking`` command, printing it but not its output (unless it fails).

    Raises:
        SystemExit: with the command's output, if its exit status is not 0.
    """
    words = [str(word) for word in argv]
    print('$ face-tracking', ' '.join(words), flush=True)
    output = io.StringIO()
    with contextlib.redirect_stdout(output):
        status = face_tracking_main(words)
    if status != 0:
        msg = f'face-tracking {words[0]} failed (exit status {status}):\n{output.getvalue()}'
        raise SystemExit(msg.rstrip())


def mono_model_recovery(work: Path) -> tuple[float, float]:
    """Figure 1: track mono bags with the packaged model, learn from the FaceState meshes.

    Args:
        work: an empty directory receiving the bags and the learned model.

    Returns:
        ``(a_in_a, s_in_sa)``: the similarity of the learned A with the tracking model's A, and
        of the learned S with the tracking model's [S A].
    """
    model_file = default_model_path(34)
    raw, tracked = work / 'raw', work / 'tracked'
    face_tracking('synth', *MONO_WORLD.split(), '--out', raw)
    bags = sorted(path for path in raw.iterdir() if path.is_dir())
    for bag in bags:
        face_tracking(
            'track', bag, '--model', model_file, *TRACK.split(), '--out', tracked / bag.name
        )
    learned_file = work / 'learned.npz'
    meshes = [tracked / bag.name for bag in bags]
    outputs = ('--out', learned_file, '--report', work / 'learned.json')
    face_tracking('learn', *meshes, '--truth', *bags, *LEARN.split(), *outputs)
    tracking, learned = load_model(model_file), load_model(learned_file)
    both = np.hstack([tracking.shape_basis, tracking.action_basis])
    return (
        subspace_similarity(learned.action_basis, tracking.action_basis),
        subspace_similarity(learned.shape_basis, both),
    )


def sample_top_p_scores(num_nodes: int, draws: int) -> np.ndarray:
    """Figure 2: the (draws,) scores of eleven subjects' top-p against the population's.

    Draw ``s`` is the first SAMPLE_SUBJECTS subjects of the realistic population of seed ``s``.
    """
    scores = np.empty(draws)
    for seed in range(draws):
        population = FacePopulation('realistic', seed)
        true_axes, _ = population.truth(num_nodes).identity_principal_axes()
        subjects = (population.subject(i) for i in range(SAMPLE_SUBJECTS))
        faces = np.array([subject.neutral_nodes[:num_nodes].ravel() for subject in subjects])
        sample = principal_components(faces - faces.mean(axis=0), P).basis
        scores[seed] = subspace_similarity(sample, true_axes[:, :P])
    return scores


def main() -> None:
    """Parse the command line, compute both figures and print them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        '--work',
        type=Path,
        help='directory to keep the bags and models in, not one used before (default: temporary)',
    )
    parser.add_argument('--draws', type=int, default=200, help='population seeds drawn (200)')
    args = parser.parse_args()
    if args.draws < 1:
        parser.error(f'--draws must be >= 1, got {args.draws}')
    with contextlib.ExitStack() as stack:
        work = args.work or Path(stack.enter_context(tempfile.TemporaryDirectory()))
        a_in_a, s_in_sa = mono_model_recovery(work)
    print(f'mono FaceState meshes: learned A in tracking A {a_in_a:.3f}, S in [S A] {s_in_sa:.3f}')
    for num_nodes in (19, 34):
        scores = sample_top_p_scores(num_nodes, args.draws)
        low, median, high = np.percentile(scores, [10, 50, 90])
        print(
            f'{num_nodes} nodes, {args.draws} draws of {SAMPLE_SUBJECTS}: seed 0 {scores[0]:.3f}, '
            f'median {median:.3f}, 10th-90th percentile {low:.3f}-{high:.3f}, '
            f'max {scores.max():.3f}'
        )


if __name__ == '__main__':
    main()
