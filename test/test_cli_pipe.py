"""How ``face-tracking`` ends when its output or its run is cut short.

Output piped into a reader that stops early (``| head``) ends the command quietly:
``face-tracking msgs FaceState | head -3`` printed ``error: [Errno 32] Broken pipe`` and
ended with status 2, as if the command had failed, whenever head had closed the pipe before
the definition was written. Ctrl-C or SIGTERM ends it with ``interrupted`` and status 130,
also while the parser imports the subcommands (seconds on a loaded machine), where SIGTERM
killed it with no word and Ctrl-C printed a traceback.
"""

from __future__ import annotations

import os
import signal
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


# A child process whose parser, while it is built, gets the signal given as argv[1] and takes a
# while; before the fix a SIGTERM there would have killed the test process itself.
SIGNALLED_WHILE_LOADING = """
import os, sys, time
from face_tracking_ros.cli import main as cli_main
build = cli_main.build_parser
def slow_build(*args):
    os.kill(os.getpid(), int(sys.argv[1]))
    time.sleep(60)  # the signal's KeyboardInterrupt ends this
    return build(*args)
cli_main.build_parser = slow_build
sys.exit(cli_main.main(['msgs']))
"""


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_the_subcommands_load_ends_the_command_as_interrupted(signum) -> None:
    done = subprocess.run(
        [sys.executable, '-c', SIGNALLED_WHILE_LOADING, str(int(signum))],
        capture_output=True,
        text=True,
        cwd=REPO,
        check=False,
        timeout=120,
    )
    assert (done.returncode, done.stderr, done.stdout) == (130, 'interrupted\n', '')
