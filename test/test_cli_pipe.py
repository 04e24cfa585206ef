"""Output piped into a reader that stops early (``| head``) ends the command quietly.

``face-tracking msgs FaceState | head -3`` printed ``error: [Errno 32] Broken pipe`` and
ended with status 2, as if the command had failed, whenever head had closed the pipe before
the definition was written.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from face_tracking_ros.cli import main as cli_main
from face_tracking_ros.cli import msgs

from repo_root import REPO


def test_a_reader_gone_from_stdout_ends_the_command_quietly_with_sigpipes_status() -> None:
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader has gone before the command writes: head -0
    try:
        done = subprocess.run(
            [sys.executable, '-m', 'face_tracking_ros.cli.main', 'msgs', 'FaceState'],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            cwd=REPO,
            check=False,
            timeout=120,
        )
    finally:
        os.close(write_end)
    assert done.stderr == ''
    assert done.returncode == cli_main.EXIT_BROKEN_PIPE == 141


def test_a_broken_pipe_elsewhere_is_still_an_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def video_writer_gone(_args: object) -> None:
        raise BrokenPipeError(32, 'Broken pipe')  # e.g. an encoder subprocess that died

    monkeypatch.setattr(msgs, 'run', video_writer_gone)  # registered by main's parser
    assert cli_main.main(['msgs']) == cli_main.EXIT_ERROR
    assert capsys.readouterr().err == 'error: [Errno 32] Broken pipe\n'
