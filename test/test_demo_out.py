"""`face-tracking demo --out`: it empties only a directory it made itself."""

from __future__ import annotations

import pytest

from face_tracking_ros.cli import demo
from face_tracking_ros.cli.main import main


@pytest.fixture
def no_steps(monkeypatch):
    """The demo's set-up of --out, without its steps."""
    monkeypatch.setattr(demo, 'steps', lambda plan, out: [])


def test_keep_does_not_mark_a_users_directory_as_the_demos(tmp_path, no_steps, capsys):
    mine = tmp_path / 'mine'
    mine.mkdir()
    (mine / 'keep.txt').write_text('mine')
    assert main(['demo', '--out', str(mine), '--keep']) == 0
    assert not (mine / demo.MARKER).exists()
    assert main(['demo', '--out', str(mine)]) != 0
    assert 'was not made by the demo' in capsys.readouterr().err
    assert (mine / 'keep.txt').read_text() == 'mine'


def test_a_directory_the_demo_made_is_emptied_by_the_next_demo(tmp_path, no_steps):
    out = tmp_path / 'out'
    assert main(['demo', '--out', str(out)]) == 0
    (out / 'stale.txt').write_text('from the last demo')
    assert main(['demo', '--out', str(out)]) == 0
    assert (out / demo.MARKER).exists() and not (out / 'stale.txt').exists()
