"""``face-tracking learn`` on small FaceTruth and FaceMesh bags: outputs and every error branch."""

from __future__ import annotations

from dataclasses import fields
import json
from pathlib import Path
import time

from learning_population import mesh_sequences
import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from face_tracking_ros.cli.learn import learn_options
from face_tracking_ros.cli.main import build_parser, main
from face_tracking_ros.io import conversions
from face_tracking_ros.io.bags import BagWriter, read_raw
from face_tracking_ros.io.messages import RosbagsMessages
from face_tracking_ros.io.series import load_states
from face_tracking_ros.io.typestore import typestore
from face_tracking_ros.learning.training_set import MeshSequence
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.model.topology import mesh_topology
from face_tracking_ros.pipelines.learn_options import LearnOptions
from face_tracking_ros.synthetic.faces import FacePopulation

from repo_root import REPO

TRUTH_TYPE = 'face_tracking_msgs/msg/FaceTruth'
MESH_TYPE = 'face_tracking_msgs/msg/FaceMesh'
STATE_TYPE = 'face_tracking_msgs/msg/FaceState'
START_NS = 1_700_000_000_000_000_000


def _write_bag(
    path: Path,
    sequence: MeshSequence,
    alpha: np.ndarray,
    kind: str = 'truth',
    status: np.ndarray | None = None,
    occluded: np.ndarray | None = None,
    store: Typestore | None = None,
) -> Path:
    """A bag of the sequence's truth, FaceMesh meshes or FaceState states (``kind``).

    With ``status``, each frame's tracker status: in the FaceState itself, or in a face/state
    beside the truth or meshes. A frame whose status is not TRACKING (1) is written as a tracker
    leaves it: zeros. With ``occluded`` ((F,) bool), those frames' FaceStates say node 3 was
    held under an occluder. Messages are of ``store``'s types (default: the package's).
    """
    store = typestore() if store is None else store
    factory = RosbagsMessages(store)
    names = list(mesh_topology(sequence.meshes.shape[1]).node_names)
    held = {} if occluded is None else {'occluded': np.zeros(len(names), dtype=bool)}
    with BagWriter(path, store=store) as bag:
        for f, nodes in enumerate(sequence.meshes):
            stamp = START_NS + f * 33_000_000
            header = conversions.make_header(factory, stamp, 'camera')
            tracked = 1 if status is None else int(status[f])
            points = conversions.array_to_points(factory, nodes * (tracked == 1))
            if held:
                held['occluded'][3] = occluded[f]
            if status is not None and kind != 'state':
                state = factory.make(STATE_TYPE, header=header, status=tracked, **held)
                bag.write('face/state', STATE_TYPE, state, stamp)
            if kind == 'truth':
                message = factory.make(
                    TRUTH_TYPE,
                    header=header,
                    subject_id=sequence.subject_id,
                    alpha=alpha[f],
                    node_names=names,
                    nodes=points,
                    expression_label=sequence.labels[f],
                )
                bag.write('truth/face', TRUTH_TYPE, message, stamp)
            elif kind == 'mesh':
                message = factory.make(MESH_TYPE, header=header, node_names=names, points=points)
                bag.write('face/mesh_raw', MESH_TYPE, message, stamp)
            else:
                message = factory.make(
                    STATE_TYPE, header=header, status=tracked, node_names=names, nodes=points,
                    **held,
                )  # fmt: skip
                bag.write('face/state', STATE_TYPE, message, stamp)
    return path


@pytest.fixture(scope='module')
def world() -> tuple[list[MeshSequence], np.ndarray]:
    return mesh_sequences(FacePopulation('default'), 34, subjects=4, sequences=1, frames=75)


@pytest.fixture(scope='module')
def truth_bags(tmp_path_factory, world) -> list[Path]:
    sequences, alpha = world
    directory = tmp_path_factory.mktemp('bags')
    frames = len(sequences[0].meshes)
    return [
        _write_bag(directory / s.subject_id, s, alpha[k * frames : (k + 1) * frames])
        for k, s in enumerate(sequences)
    ]


def test_learns_compares_and_writes_model_report_and_plots(tmp_path, truth_bags, capsys):
    model_path, report_path = tmp_path / 'face.npz', tmp_path / 'report.json'
    start = time.perf_counter()
    status = main(
        ['learn', *map(str, truth_bags), '--out', str(model_path), '--report', str(report_path)]
        + ['--nodes', '19', '--q', '3', '--plots', str(tmp_path / 'figures' / 'run1')]
        + ['--truth-population', 'default']
        + ['--add-noise', '0.0005', '--truth-samples', '200']
    )
    seconds = time.perf_counter() - start
    assert status == 0
    out = capsys.readouterr().out
    assert 'read 300 meshes of 19 nodes, 4 subjects' in out
    assert 'share of A in true expr. span' in out
    model = load_model(model_path)
    assert (model.method, model.num_nodes, model.p, model.q) == ('joint', 19, 2, 3)
    assert model.metadata['bags'] == [str(bag) for bag in truth_bags]
    assert f'model (joint, p=2, q=3) written to {model_path}\n' in out
    report = json.loads(report_path.read_text())
    assert report['model'] == str(model_path)
    assert 0.0 < report['align_seconds'] < seconds
    assert list(report['methods']) == ['joint', 'seed', 'seed-weighted']
    joint = report['methods']['joint']
    assert joint['truth']['action_share'] > 0.95
    assert joint['identity_accuracy'] == 1.0  # first half against second half
    assert len(joint['loo_per_subject']['neutral_rms_mm']) == 4
    assert joint['loo_per_subject']['p'] == [2, 2, 2, 2]  # each held-out subject's model's p
    assert report['subjects'] == [s.name for s in truth_bags]
    for plot in report['plots']:  # in the directory made for them
        assert Path(plot).parent == tmp_path / 'figures' / 'run1'
        assert Path(plot).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert {Path(plot).name for plot in report['plots']} >= {
        'sigma_joint.png',
        'sigma_seed.png',
        'comparison.png',
        'convergence.png',
    }


def test_seed_method_alone(tmp_path, truth_bags):
    model_path = tmp_path / 'seed.npz'
    status = main(
        ['learn', *map(str, truth_bags), '--out', str(model_path)]
        + ['--report', str(tmp_path / 'r.json'), '--method', 'seed', '--compare', '--q', '3']
    )
    assert status == 0
    assert load_model(model_path).method == 'seed'
    report = json.loads((tmp_path / 'r.json').read_text())
    assert list(report['methods']) == ['seed']
    assert report['methods']['seed']['truth'] is None


def test_mesh_bags_with_first_frames_neutral(tmp_path, world, capsys):
    sequences, alpha = world
    bags = [
        _write_bag(tmp_path / f'person{k}', s, alpha, kind='mesh') for k, s in enumerate(sequences)
    ]
    args = ['learn', *map(str, bags), '--out', str(tmp_path / 'm.npz')]
    args += ['--report', str(tmp_path / 'r.json'), '--compare', '--q', '3']
    assert main([*args, '--neutral-frames', '10']) == 0
    report = json.loads((tmp_path / 'r.json').read_text())
    assert report['subjects'] == ['person0', 'person1', 'person2', 'person3']
    assert report['methods']['joint']['expression_accuracy'] is None
    assert 'covers all its' not in capsys.readouterr().out
    main([*args, '--neutral-frames', '75'])
    assert f'{bags[0]}: --neutral-frames 75 covers all its 75 frames' in capsys.readouterr().out


def test_subject_names_every_bag_without_truth(tmp_path, world, truth_bags):
    """Two recordings of one person beside truth bags: --subject makes them one subject."""
    sequences, alpha = world
    bags = [_write_bag(tmp_path / f'rec{k}', sequences[3], alpha, kind='mesh') for k in (1, 2)]
    args = ['learn', *map(str, [*truth_bags[:3], *bags]), '--out', str(tmp_path / 'm.npz')]
    args += ['--report', str(tmp_path / 'r.json'), '--compare', '--q', '3']
    assert main([*args, '--neutral-frames', '10', '--subject', 'anna']) == 0
    report = json.loads((tmp_path / 'r.json').read_text())
    assert report['subjects'] == ['subject_00', 'subject_01', 'subject_02', 'anna']


def test_subject_options_where_truth_names_every_subject_are_refused(
    tmp_path, world, truth_bags, capsys
):
    """Truth labels every bag's meshes: --subject(-pattern) and --neutral-frames were ignored.

    The bags of truth, and bags of meshes labelled by --truth bags: the truth's subject ids and
    neutral labels were learned whatever the options said; so was --subject-pattern beside
    --subject.
    """
    sequences, alpha = world
    meshes = [
        _write_bag(tmp_path / f'rec_{k}', s, alpha, kind='mesh') for k, s in enumerate(sequences)
    ]
    out = ['--out', str(tmp_path / 'm.npz'), '--report', str(tmp_path / 'r.json')]
    labelled = [*map(str, meshes), '--truth', *map(str, truth_bags)]
    for bags, options, named in (
        (list(map(str, truth_bags)), ['--subject-pattern', r'(.+)_\d+'], '--subject-pattern'),
        (labelled, ['--subject', 'anna', '--neutral-frames', '3'], '--subject, --neutral-frames'),
        (list(map(str, truth_bags)), ['--neutral-frames', '3'], '--neutral-frames'),
    ):
        assert _error(['learn', *bags, *out, *options], capsys) == (
            f"error: {named}: for bags without truth, and truth labels every bag's meshes (its "
            "own or a truth bag's): learn keeps the truth's subject ids and neutral labels\n"
        )
    both = ['--subject', 'anna', '--subject-pattern', '(.+)', '--neutral-frames', '3']
    assert _error(['learn', *map(str, meshes), *out, *both], capsys) == (
        'error: --subject-pattern: --subject names every bag without truth\n'
    )
    assert sorted(path.name for path in tmp_path.iterdir()) == [f'rec_{k}' for k in range(4)]
    # One bag without truth: the pattern names its subject.
    bags = [*map(str, truth_bags[:3]), str(meshes[3])]
    assert (
        main(['learn', *bags, *out, '--subject-pattern', r'(.+)_\d+', '--neutral-frames', '3'])
        == 0
    )
    assert json.loads((tmp_path / 'r.json').read_text())['subjects'][-1] == 'rec'


def test_frames_a_tracker_did_not_track_are_left_out(tmp_path, world, capsys):
    """A tracker's bag: meshes of INITIALIZING or LOST frames (zeros, stale) are not learned."""
    sequences, alpha = world
    status = np.full(len(sequences[0].meshes), 1)  # FaceState.STATUS_TRACKING
    status[:5], status[40] = 0, 2  # waiting for the face, then one frame lost
    for kind in ('mesh', 'state'):  # FaceMesh beside face/state; FaceState alone
        bags = [
            _write_bag(tmp_path / kind / f'person{k}', s, alpha, kind=kind, status=status)
            for k, s in enumerate(sequences)
        ]
        args = ['learn', *map(str, bags), '--out', str(tmp_path / 'm.npz'), '--q', '3']
        args += ['--report', str(tmp_path / 'r.json'), '--compare', '--neutral-frames', '10']
        assert main(args) == 0
        assert f'{bags[0]}: 6 frames the tracker did not track' in capsys.readouterr().out
        report = json.loads((tmp_path / 'r.json').read_text())
        assert report['frames'] == 4 * (len(status) - 6)
    # A tracker publishes no mesh while INITIALIZING: the frames its face/state says
    # untracked are counted all the same (until 2026-12-06, 0 of 6 here).
    untracked = {START_NS + f * 33_000_000 for f in np.flatnonzero(status != 1)}
    sparse = tmp_path / 'sparse'
    with BagWriter(sparse) as writer:
        for message in read_raw(tmp_path / 'mesh' / 'person0'):
            if message.topic != 'face/mesh_raw' or message.stamp_ns not in untracked:
                writer.write_raw(message.topic, message.msgtype, message.data, message.stamp_ns)
    meshes = [tmp_path / 'mesh' / f'person{k}' for k in range(1, len(sequences))]
    args = ['learn', str(sparse), *map(str, meshes), '--out', str(tmp_path / 's.npz')]
    args += ['--report', str(tmp_path / 's.json'), '--q', '3', '--neutral-frames', '10']
    assert main(args) == 0
    assert f'{sparse}: 6 frames the tracker did not track' in capsys.readouterr().out
    never = _write_bag(tmp_path / 'never', sequences[0], alpha, kind='mesh', status=status * 0)
    # with the other subjects' bags, as one subject is refused for p = 2 before any is read
    err = _error(['learn', str(never), *map(str, bags[1:]), '--out', str(tmp_path / 'n.npz'),
                  '--report', str(tmp_path / 'n.json'), '--neutral-frames', '10'],
                 capsys)  # fmt: skip
    assert f'none of the {len(status)} frames on face/mesh_raw was tracked' in err


def test_frames_with_nodes_held_under_an_occluder_are_left_out(tmp_path, world, capsys):
    """FaceState.occluded: a stereo tracker held those nodes to the head's rigid motion.

    Such a mesh does not show the face's expression at those nodes, so it is not learned (on six
    rendered stereo bags with an occluder passing, 150 of 540 frames: A's similarity to the
    true expression axes 0.981 -> 0.992). A FaceState written before the field existed leaves
    nothing out.
    """
    sequences, alpha = world
    frames = len(sequences[0].meshes)
    status = np.ones(frames, dtype=int)
    status[40] = 2  # one frame lost, counted apart
    occluded = np.zeros(frames, dtype=bool)
    occluded[20:27] = True
    args = ['--out', str(tmp_path / 'm.npz'), '--report', str(tmp_path / 'r.json'), '--q', '3']
    args += ['--neutral-frames', '10']
    for kind in ('mesh', 'state'):  # FaceMesh beside face/state; FaceState alone
        bags = [
            _write_bag(tmp_path / kind / f'p{k}', s, alpha, kind, status, occluded)
            for k, s in enumerate(sequences)
        ]
        assert main(['learn', *map(str, bags), *args]) == 0
        printed = capsys.readouterr().out
        assert f'{bags[0]}: 1 frame the tracker did not track (initialising or lost)' in printed
        assert (
            f'{bags[0]}: 7 frames with nodes covered by an occluder (FaceState.occluded) left out'
            in printed
        )
        assert json.loads((tmp_path / 'r.json').read_text())['frames'] == 4 * (frames - 8)
    held = load_states(bags[0]).occluded
    assert held.shape == (frames, 34) and np.array_equal(
        np.flatnonzero(held.any(axis=1)), range(20, 27)
    )
    text, _ = typestore().generate_msgdef(STATE_TYPE)
    assert 'bool[] occluded\n' in text  # this version's FaceState has it
    earlier = get_typestore(Stores.EMPTY)
    earlier.register(get_types_from_msg(text.replace('bool[] occluded\n', ''), STATE_TYPE))
    bags = [
        _write_bag(tmp_path / 'old' / f'p{k}', s, alpha, 'state', status, store=earlier)
        for k, s in enumerate(sequences)
    ]
    assert main(['learn', *map(str, bags), *args]) == 0
    assert 'occluder' not in capsys.readouterr().out
    assert json.loads((tmp_path / 'r.json').read_text())['frames'] == 4 * (frames - 1)
    # Every frame held: none is learned, and the error says why.
    never = _write_bag(tmp_path / 'never', sequences[0], alpha, 'state', status, occluded | True)
    err = _error(['learn', str(never), *map(str, bags[1:]), *args], capsys)
    assert f'none of the {frames} frames on face/state was tracked with every node seen' in err


def test_mesh_bags_labelled_by_truth_bags(tmp_path, world, truth_bags, capsys):
    sequences, alpha = world
    bags = [
        _write_bag(tmp_path / f'tracked{k}', s, alpha, kind='mesh')
        for k, s in enumerate(sequences)
    ]
    args = ['learn', *map(str, bags), '--out', str(tmp_path / 'm.npz'), '--q', '3']
    args += ['--report', str(tmp_path / 'r.json'), '--compare', '--truth', *map(str, truth_bags)]
    assert main(args) == 0
    report = json.loads((tmp_path / 'r.json').read_text())
    assert report['subjects'] == [s.subject_id for s in sequences]
    # Labels from the truth bags: each subject plays one expression that no other subject
    # plays, so leaving a subject out, only its 27 neutral frames of 75 can be recognised.
    assert report['methods']['joint']['expression_accuracy'] == pytest.approx(4 * 27 / 300)

    err = _error([*args[:-1]], capsys)
    assert '--truth names 3 bags for 4 input bags' in err
    short = sequences[0].__class__(
        'x', sequences[0].meshes[:5], np.ones(5, bool), ('neutral',) * 5
    )
    short_truth = _write_bag(tmp_path / 'short', short, alpha)
    out = ['--out', str(tmp_path / 'm2.npz'), '--report', str(tmp_path / 'r2.json')]
    err = _error(['learn', str(bags[1]), *out, '--truth', str(short_truth)], capsys)
    assert f'{short_truth}: no truth/face message stamped' in err


def _error(args: list[str], capsys) -> str:
    assert main(args) == 2
    return capsys.readouterr().err


def test_errors_name_the_bag_topic_or_subject(tmp_path, truth_bags, world, capsys):
    sequences, alpha = world
    out = ['--out', str(tmp_path / 'm.npz'), '--report', str(tmp_path / 'r.json')]
    bags = list(map(str, truth_bags))

    err = _error(['learn', *bags, *out, '--topic', 'nope'], capsys)
    assert f'{truth_bags[0]}: no topic nope in bag (topics: truth/face)' in err

    err = _error(['learn', *bags, *out, '--p', '4'], capsys)
    assert '4 subjects cannot give an identity subspace of p = 4' in err

    smiling = sequences[0].__class__(
        'grumpy', sequences[0].meshes, np.zeros(75, bool), ('smile',) * 75, ''
    )
    bag = _write_bag(tmp_path / 'grumpy', smiling, alpha)
    err = _error(['learn', str(bag), *bags, *out], capsys)
    assert f"subject 'grumpy' ({bag}) has no neutral frames" in err

    broken = sequences[1].meshes.copy()
    broken[7, 3, 1] = np.nan
    broken_sequence = sequences[1].__class__(
        'subject_01', broken, sequences[1].neutral, sequences[1].labels, ''
    )
    bag = _write_bag(tmp_path / 'broken', broken_sequence, alpha)
    err = _error(['learn', str(bag), *out], capsys)
    nan = 'FaceTruth.nodes holds NaN or Inf: 1 of 102 values, the first (nan) at [3, 1]'
    assert f'{bag}: truth/face message 7 (stamp ' in err
    assert f's): {nan}\n' in err

    small = sequences[2].__class__(
        'small', sequences[2].meshes[:, :19], sequences[2].neutral, sequences[2].labels, ''
    )
    bag = _write_bag(tmp_path / 'small', small, alpha)
    err = _error(['learn', str(bag), *bags, *out], capsys)
    assert 'different node counts' in err and f"subject 'small' ({bag}): 19" in err

    err = _error(['learn', str(bag), *out, '--nodes', '34'], capsys)
    assert f'{bag}: truth/face: --nodes 34 but the meshes have only 19 nodes' in err

    for kind, field in (('mesh', 'FaceMesh.points'), ('state', 'FaceState.nodes')):
        bag = _write_bag(tmp_path / f'broken_{kind}', broken_sequence, alpha, kind=kind)
        err = _error(['learn', str(bag), *bags, *out, '--neutral-frames', '10'], capsys)
        assert f'{field} holds NaN or Inf: 1 of 102 values, the first (nan) at [3, 1]' in err

    mesh_bag = _write_bag(tmp_path / 'anon', sequences[3], alpha, kind='mesh')
    err = _error(['learn', str(mesh_bag), *bags, *out], capsys)
    # Meshes without truth: which frames are neutral must be given, before any work.
    assert f'{mesh_bag}: no truth says which frames show the neutral face; give --neutral' in err

    err = _error(['learn', *bags, *out, '--truth-population', 'weird'], capsys)
    assert '--truth-population must be PRESET[:SEED]' in err

    packaged = [str(bag) for bag in sorted((REPO / 'bags' / 'stereo_train').glob('subject_*'))]
    learn_packaged = ['learn', *packaged, *out, '--p', '1', '--q', '2', '--truth-samples', '50']
    assert main([*learn_packaged, '--truth-population', 'default:0']) == 0  # as rendered
    err = _error([*learn_packaged, '--truth-population', 'default:1'], capsys)
    assert '--truth-population default:1: its subject_00 is not the one of the bags' in err

    err = _error(['learn', *bags, *out, '--add-noise', 'nan'], capsys)
    assert '--neutral-frames and --add-noise must not be negative' in err

    for share in ('0', '1.5'):  # a share of the identity variance: 1 is all of it
        err = _error(['learn', *bags, *out, '--explained-variance', share], capsys)
        assert f'--explained-variance must be in (0, 1], got {float(share)}' in err

    same = ['--out', str(tmp_path / 'x.npz'), '--report', str(tmp_path / 'x.npz')]
    err = _error(['learn', *bags, *same], capsys)
    assert f'--out and --report are both {tmp_path}/x.npz: the report would overwrite' in err

    (tmp_path / 'figures.png').write_bytes(b'')
    err = _error(['learn', *bags, *out, '--plots', str(tmp_path / 'figures.png')], capsys)
    assert f'--plots {tmp_path}/figures.png is a file, not a directory' in err

    err = _error(['learn', str(tmp_path / 'missing'), *out], capsys)
    assert 'missing' in err


def test_three_subjects_learn_p_2_without_the_leave_one_out_figures(tmp_path, truth_bags, capsys):
    report_path = tmp_path / 'r.json'
    args = ['learn', *map(str, truth_bags[:3]), '--out', str(tmp_path / 'm.npz')]
    assert main([*args, '--report', str(report_path), '--q', '3']) == 0
    assert 'joint: no leave-one-subject-out figures: with one subject held out, 2 subjects ' in (
        capsys.readouterr().out
    )
    assert load_model(tmp_path / 'm.npz').p == 2
    joint = json.loads(report_path.read_text())['methods']['joint']
    assert joint['loo_shape_similarity'] is None and joint['identity_accuracy'] == 1.0
    assert joint['loo_per_subject']['neutral_rms_mm'] == [None] * 3


def test_a_recorder_s_absolute_topic_names_are_read(tmp_path, world, capsys):
    """bag_recorder writes '/face/mesh_raw' and '/face/state'; learn looks for both spellings."""
    sequences, alpha = world
    status = np.full(len(sequences[0].meshes), 1)
    status[40] = 2  # one frame lost: its '/face/state' must still be found
    bags = []
    for k, sequence in enumerate(sequences):
        relative = _write_bag(tmp_path / f'rel{k}', sequence, alpha, kind='mesh', status=status)
        with BagWriter(tmp_path / f'person{k}') as writer:
            for message in read_raw(relative):
                writer.write_raw(f'/{message.topic}', message.msgtype, message.data,
                                 message.stamp_ns)  # fmt: skip
        bags.append(tmp_path / f'person{k}')
    args = ['learn', *map(str, bags), '--out', str(tmp_path / 'm.npz'), '--q', '3']
    assert main([*args, '--report', str(tmp_path / 'r.json'), '--neutral-frames', '10']) == 0
    assert f'{bags[0]}: 1 frame the tracker did not track' in capsys.readouterr().out
    assert json.loads((tmp_path / 'r.json').read_text())['frames'] == 4 * (len(status) - 1)


def test_p_chosen_by_explained_variance_is_reported_per_held_out_subject(tmp_path, truth_bags):
    argv = ['learn', *map(str, truth_bags), '--out', str(tmp_path / 'm.npz'), '--q', '3']
    argv += ['--report', str(tmp_path / 'r.json'), '--explained-variance', '0.99']
    assert main(argv) == 0
    report = json.loads((tmp_path / 'r.json').read_text())['methods']['joint']
    folds = report['loo_per_subject']['p']
    assert len(folds) == 4 and all(isinstance(p, int) and 1 <= p <= 2 for p in folds)
    assert report['p'] == load_model(tmp_path / 'm.npz').p >= max(folds)


def test_every_flag_is_a_pipeline_option_with_the_same_default():
    args = build_parser().parse_args(['learn', 'a', '--out', 'm.npz', '--report', 'r.json'])
    flags = set(vars(args)) - {'command', 'func', 'tracker_param'} | {'tracker_params'}
    assert flags | {'named'} == {field.name for field in fields(LearnOptions)}  # named: no flag
    defaults = LearnOptions(bags=(Path('a'),), out=Path('m.npz'), report=Path('r.json'))
    assert learn_options(args) == defaults


def test_an_out_that_is_not_a_face_model_is_not_written_over(tmp_path, truth_bags, capsys):
    notes = tmp_path / 'notes.txt'
    notes.write_text('not a model')
    args = [*map(str, truth_bags), '--out', str(notes), '--report', str(tmp_path / 'r.json')]
    message = _error(['learn', *args], capsys)
    assert f'--out {notes} exists and is not a face model' in message
    assert notes.read_text() == 'not a model'
