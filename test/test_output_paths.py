"""Output paths a command cannot write are refused before any work, naming option and component.

An --out under an existing regular file gave the raw errno text ('[Errno 20] Not a directory',
'[Errno 17] File exists'), some commands only after their work (bench after its benchmarks,
plot after drawing).
"""

from __future__ import annotations

import os
from pathlib import Path
import time

import numpy as np
import pytest

from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import ConfigError, ModelFileError
from face_tracking_ros.io.atomic import check_output_path, read_npz, write_json_atomically
from face_tracking_ros.io.bags import read_messages
from face_tracking_ros.visualization.video import write_overlay_video

from repo_root import REPO

MONO = REPO / 'bags' / 'mono_test' / 'subject_00_seq_00'


def _commands(tmp_path: Path, under: Path) -> dict[str, list[str]]:
    """Each command with one output under ``under`` (its other outputs in ``tmp_path``)."""
    synth = ['synth', '--kind', 'mono', '--frames', '2']
    track = ['track', str(MONO), '--simulate-clicks', '1', '--quiet']
    return {
        '--out': [*synth, '--out', str(under / 'bags')],
        '--contact-sheet': [*synth, '--contact-sheet', str(under / 'sheet.png')],
        'track --out': [*track, '--out', str(under / 'tracked')],
        '--report': [*track, '--out', str(tmp_path / 'tracked'), '--report', str(under / 'r')],
        'replay --out': ['replay', 'mono_tracker', str(MONO), '--out', str(under / 'o')],
        'demo --out': ['demo', '--out', str(under / 'demo')],
        '--json': ['bench', '--quick', '--out', str(tmp_path), '--json', str(under / 'b.json')],
        '--png': ['plot', str(MONO), '--png', str(under / 'p.png')],
    }


CASES = ['--out', '--contact-sheet', 'track --out', '--report', 'replay --out', 'demo --out']


@pytest.mark.parametrize('case', [*CASES, '--json', '--png'])
def test_an_output_under_a_file_names_the_option_and_the_file(tmp_path, capsys, case):
    notes = tmp_path / 'notes.txt'
    notes.write_text('mine')
    argv = _commands(tmp_path, notes / 'sub')[case]
    option = case.split()[-1]
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert f'error: {option} {notes}/sub/' in error
    assert f': {notes} is a file, not a directory' in error
    assert 'Errno' not in error
    assert notes.read_text() == 'mine'
    assert sorted(path.name for path in tmp_path.iterdir()) == ['notes.txt']  # no work done


def test_an_output_of_the_wrong_kind_is_named(tmp_path, capsys):
    notes = tmp_path / 'notes.txt'
    notes.write_text('mine')
    assert main(['demo', '--out', str(notes)]) == 2
    assert f'--out {notes} is a file, not a directory' in capsys.readouterr().err
    assert main(['bench', '--out', str(tmp_path / 'b'), '--json', str(tmp_path)]) == 2
    assert f'--json {tmp_path} is a directory, not a file' in capsys.readouterr().err
    assert notes.read_text() == 'mine'
    assert not (tmp_path / 'b').exists()


def _special_file_commands(tmp_path: Path, fifo: Path) -> dict[str, list[str]]:
    """Each command with one output file at ``fifo`` (its other outputs in ``tmp_path``)."""
    track = ['track', str(MONO), '--simulate-clicks', '1', '--out', str(tmp_path / 'tracked')]
    synth = ['synth', '--kind', 'mono', '--frames', '2', '--out', str(tmp_path / 'bags')]
    return {
        '--report': [*track, '--report', str(fifo)],
        '--contact-sheet': [*synth, '--contact-sheet', str(fifo)],
        '--json': ['bench', '--quick', '--out', str(tmp_path / 'b'), '--json', str(fifo)],
        '--png': ['plot', str(MONO), '--png', str(fifo)],
        '--gallery': ['enroll', str(MONO), '--name', 'ann', '--gallery', str(fifo)],
        '--out': ['train-expressions', str(MONO), '--out', str(fifo)],
    }


@pytest.mark.parametrize(
    'option', ['--report', '--contact-sheet', '--json', '--png', '--gallery', '--out']
)
def test_an_output_that_is_a_named_pipe_is_refused_not_replaced(tmp_path, capsys, option):
    """A file renamed over a pipe, a device or a socket replaced it (as root, /dev/null too)."""
    fifo = tmp_path / 'out.png' if option in ('--png', '--contact-sheet') else tmp_path / 'out.npz'
    os.mkfifo(fifo)
    assert main(_special_file_commands(tmp_path, fifo)[option]) == 2
    assert capsys.readouterr().err == (
        f'error: {option} {fifo} is a named pipe, not a regular file: not written over\n'
    )
    assert fifo.is_fifo()
    assert sorted(path.name for path in tmp_path.iterdir()) == [fifo.name]  # no work done


def test_an_atomic_write_or_a_video_over_a_named_pipe_is_refused_and_a_pipe_read_is_named(
    tmp_path,
):
    fifo = tmp_path / 'out.mp4'
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match=f'^output {fifo} is a named pipe, not a regular file'):
        write_json_atomically(fifo, {})
    with pytest.raises(ConfigError, match=f'^video file {fifo} is a named pipe, not a regular'):
        write_overlay_video(MONO, None, fifo)  # type: ignore[arg-type]  # refused before use
    with pytest.raises(ModelFileError, match=f'^{fifo}: is a named pipe, not a regular file$'):
        read_npz(fifo)  # (not opened: reading a pipe without a writer waits for ever)
    assert fifo.is_fifo()


def test_an_output_directory_the_process_may_not_write_in_is_refused_before_learning(
    tmp_path, capsys, monkeypatch
):
    """An --out it could not write was found by learn at the write, after the learning.

    A read-only file system or a directory of another user, as os.access tells it, simulated
    here (as root, a test may write anywhere but on a read-only mount).
    """
    locked = tmp_path / 'locked'
    locked.mkdir()
    access = os.access
    monkeypatch.setattr(
        os, 'access', lambda path, mode: Path(path) != locked and access(path, mode)
    )
    bags = [str(path) for path in sorted((REPO / 'bags' / 'stereo_train').iterdir())]
    learn = ['learn', *bags, '--report', str(tmp_path / 'report.json')]
    assert main([*learn, '--out', str(locked / 'model.npz')]) == 2
    assert capsys.readouterr() == (
        '',
        f'error: --out {locked / "model.npz"}: cannot create files in {locked} (a read-only file '
        'system, or no permission to write there)\n',
    )
    assert main(['track', str(MONO), '--simulate-clicks', '1', '--out', str(locked / 't')]) == 2
    assert f'error: --out {locked / "t"}: cannot create files in {locked} (' in (
        capsys.readouterr().err
    )
    assert sorted(path.name for path in tmp_path.iterdir()) == ['locked']  # no work done
    assert list(locked.iterdir()) == []


def test_a_contact_sheet_opencv_writes_no_format_of_is_named_before_rendering(tmp_path, capsys):
    synth = ['synth', '--kind', 'mono', '--frames', '2', '--out', str(tmp_path / 'bags')]
    for name, suffix in (('sheet.txt', '.txt'), ('sheet', 'none')):
        assert main([*synth, '--contact-sheet', str(tmp_path / name)]) == 2
        assert capsys.readouterr().err == (
            f'error: --contact-sheet {tmp_path / name}: OpenCV writes no image format of its '
            f'extension ({suffix}); give a .png (or .jpg, .tif...) file name\n'
        )
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(('kind', 'images'), [('mono', 30), ('stereo', 60)])
def test_synth_says_what_it_wrote_by_default(tmp_path, capsys, kind, images):
    """One subject's sequence of 30 frames; stereo cameras not toed in (R = I)."""
    out = tmp_path / 'bags'
    start = time.perf_counter()
    assert main(['synth', '--kind', kind, '--size', '64x48', '--out', str(out)]) == 0
    wall = time.perf_counter() - start
    first, summary = capsys.readouterr().out.splitlines()
    assert first.startswith(f'{out / "subject_00_seq_00"}: subject_00 sequence 0, 30 frames, ')
    assert summary.startswith(f'1 bag, 30 frames ({images} images) in ')
    assert 0.0 <= float(summary.split(' in ')[1].split(' s ')[0]) <= wall + 0.05  # .1f
    assert sorted(path.name for path in out.iterdir()) == ['subject_00_seq_00']
    infos = [m.msg for m in read_messages(out / 'subject_00_seq_00') if 'camera_info' in m.topic]
    assert len(infos) == images
    assert all(np.array_equal(info.r, np.eye(3).ravel()) for info in infos)


def test_missing_directories_and_relative_paths_pass(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    check_output_path(tmp_path / 'a' / 'b' / 'c.json', '--json')
    check_output_path(Path('x'), '--out', directory=True)
    check_output_path(Path('.'), '--out', directory=True)
    Path('x').write_text('')
    with pytest.raises(ConfigError, match=r'--out x/y: x is a file, not a directory'):
        check_output_path(Path('x/y'), '--out', directory=True)


def test_a_file_output_into_a_missing_directory_is_refused_before_any_work(tmp_path, capsys):
    """Outputs whose writers do not make directories: said at once, not after the work.

    (``track`` makes the directories of its --report as of its --out: test_tracker_output_cli.)
    """
    absent = tmp_path / 'absent'
    commands = {
        '--png': ['plot', str(MONO), '--png', str(absent / 'p.png')],
        '--gallery': ['enroll', str(MONO), '--name', 'ada', '--gallery', str(absent / 'g.npz')],
        '--out': ['train-expressions', str(MONO), '--out', str(absent / 'c.npz')],
    }
    for option, argv in commands.items():
        assert main(argv) == 2, option
        error = capsys.readouterr().err
        assert f'error: {option} {absent}/' in error
        assert f': no directory {absent} to write it in' in error
        assert list(tmp_path.iterdir()) == [], option  # nothing tracked, written or made
