"""What ``face-tracking`` imports before it runs: the chosen subcommand's modules only.

Building the parser imported every subcommand's module, and with them OpenCV, scipy, the numba
kernels, rosbags, matplotlib and scikit-learn: ``face-tracking --help`` took 3.4-5.8 s on a
loaded 2-core machine and 313 MB, and every command paid that before doing anything.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from face_tracking_ros.cli import main as cli_main

from repo_root import REPO

# Runs main(argv[1:]) with its output discarded, then prints the names of the loaded modules.
LOADED_MODULES = """
import contextlib, io, json, sys
from face_tracking_ros.cli.main import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
    main(sys.argv[1:])
print(json.dumps(sorted(sys.modules)))
"""

# Libraries of the algorithms and the bags, imported by some subcommands only.
HEAVY = frozenset({'cv2', 'scipy', 'numba', 'rosbags', 'matplotlib', 'sklearn'})


def _modules(argv: list[str]) -> set[str]:
    """The modules loaded by ``face-tracking ARGV``."""
    done = subprocess.run(
        [sys.executable, '-c', LOADED_MODULES, *argv],
        capture_output=True,
        text=True,
        cwd=REPO,
        check=True,
        timeout=120,
    )
    return set(json.loads(done.stdout))


def _loaded(argv: list[str]) -> tuple[set[str], set[str]]:
    """The heavy libraries and the face_tracking_ros.cli modules that ``argv`` loads."""
    modules = _modules(argv)
    prefix = 'face_tracking_ros.cli.'
    cli = {name.removeprefix(prefix) for name in modules if name.startswith(prefix)}
    return modules & HEAVY, cli


def test_the_list_of_subcommands_imports_none_of_them() -> None:
    assert _loaded(['--help']) == (set(), {'main'})


def test_the_list_of_subcommands_imports_no_numpy() -> None:
    """errors.py imported numpy for one np.floating check: 65 of the 180 ms of --help."""
    assert 'numpy' not in _modules(['--help'])


def test_a_subcommand_imports_its_own_module_only() -> None:
    heavy, cli = _loaded(['msgs', '--help'])
    assert heavy == {'rosbags'}  # msgs lists the rosbags typestore's types
    assert cli == {'main', 'msgs'}


def test_tracking_loads_none_of_the_learning_side() -> None:
    """The tracking side named its options through the learning options' module."""
    learning = {'scipy.stats', 'sklearn', 'matplotlib', 'face_tracking_ros.synthetic.faces'}
    assert _modules(['track', '--help']) & learning == set()


@pytest.mark.parametrize('argv', [['bogus'], ['--foo'], []])
def test_a_wrong_command_line_imports_no_subcommand(argv: list[str]) -> None:
    assert _loaded(argv) == (set(), {'main'})


def test_the_full_parser_registers_every_subcommand_its_table_lists() -> None:
    """build_parser() (what the help and documentation tests read) has every option."""
    parser = cli_main.build_parser()
    (action,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert list(action.choices) == [name.replace('_', '-') for name in cli_main.SUBCOMMANDS]
    assert all(sub._defaults.get('func') for sub in action.choices.values())


TRACKERS = {
    'mono_test': (
        'processing.mono',
        'tracking.mono',
        'tracking.mono_kernels',
        'imaging.photometric',
    ),
    'stereo_train': ('processing.stereo', 'tracking.stereo', 'tracking.stereo_kernels'),
}


@pytest.mark.parametrize(
    ('bags', 'other'), [('mono_test', 'stereo_train'), ('stereo_train', 'mono_test')]
)
def test_a_track_imports_its_own_tracker_only(bags: str, other: str, tmp_path) -> None:
    """The port names and node configs came from both processors' modules, and their kernels.

    A mono track took 0.17-0.28 s more to start importing the stereo tracker, and a stereo one
    imported the mono tracker; then still the mono tracker's photometric kernels (0.04 s),
    through the image conversions and the mono tracker's configuration.
    """
    bag = REPO / 'bags' / bags / 'subject_00_seq_00'
    argv = ['track', str(bag), '--simulate-clicks', '0', '--out', str(tmp_path / 'o'), '--quiet']
    modules = _modules(argv)
    trackers = {name.removeprefix('face_tracking_ros.') for name in modules}
    assert trackers >= set(TRACKERS[bags])
    assert trackers.isdisjoint(TRACKERS[other])
    assert 'tqdm' not in modules  # --quiet: no progress bar to import it for (27 ms)


def test_a_recogniser_replay_loads_no_compiled_kernels(tmp_path) -> None:
    """The image conversions, which every replay imports, loaded the photometric kernels.

    With numba and its start-up, 0.3 s of a replay that runs no tracker. (The bag has no
    face/state for the recogniser: the replay stops once its inputs are checked, its modules
    loaded.)
    """
    bag = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'
    argv = ['replay', 'expression_recognizer', str(bag), '--out', str(tmp_path / 'o'), '--quiet']
    modules = _modules(argv)
    assert 'face_tracking_ros.processing.expression' in modules
    assert 'numba' not in modules


# Prints how many compiled versions each kernel has once the mono tracker's modules are imported.
LOADED_KERNELS = """
import json, sys
from face_tracking_ros.imaging import photometric
from face_tracking_ros.tracking import mono_kernels
kernels = {
    name: getattr(module, name)
    for module, names in ((mono_kernels, sys.argv[1:-1]), (photometric, sys.argv[-1:]))
    for name in names
}
print(json.dumps({name: len(kernel.overloads) for name, kernel in kernels.items()}))
"""
DEFERRED_KERNELS = [
    'weighted_gram',
    'damped_step',
    'normal_equations',
    '_iteration',
    'point_cost',
    'blended_template',
]


def test_kernels_a_replay_may_not_need_are_not_loaded_with_their_module() -> None:
    """Kernels only other kernels call (compiled into them), and those of several signatures.

    Declared with their signatures, each was compiled or loaded from the cache at the import:
    45 ms of a mono replay's start for kernels, or versions of them, it never ran.
    """
    done = subprocess.run(
        [
            sys.executable,
            '-c',
            LOADED_KERNELS,
            *DEFERRED_KERNELS,
            'projected_difference',
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        check=True,
        timeout=300,
    )
    assert set(json.loads(done.stdout).values()) == {0}
