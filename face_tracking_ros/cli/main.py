"""Entry point of the ``face-tracking`` command.

Each subcommand lives in its own module ``face_tracking_ros.cli.<name>`` that exposes::

    def register(parser: argparse.ArgumentParser) -> None:
        parser.description = '...'
        ...
        parser.set_defaults(func=run)  # run(args: argparse.Namespace) -> int | None

Add a subcommand by writing that module and adding its module name, with the one-line help that
``face-tracking --help`` lists, to :data:`SUBCOMMANDS`. Only the chosen subcommand's module is
imported (with what it runs: OpenCV, scipy, numba kernels, rosbags: seconds on a loaded
machine, for all of them together), once parsing has chosen it.

A :class:`~face_tracking_ros.errors.FaceTrackingError` raised by a subcommand, or an OSError
(a file or directory that is missing or cannot be written: the user's or the machine's matter),
is printed as ``error: <message>`` on stderr with exit status 2; other exceptions propagate
(they are bugs). A :class:`~face_tracking_ros.errors.FaceTrackingWarning` (a damaged bag read
as far as it is readable) is printed as ``warning: <message>`` on stderr, once. SIGTERM
(``timeout``, CI runners, schedulers) stops a command as Ctrl-C does, so that the bags it
writes are closed and stay readable; a command that does not handle the interruption itself
ends with ``interrupted`` and exit status 130. Output piped into a reader that stops early
(``face-tracking msgs FaceState | head -3``) ends the command quietly with exit status 141, as
a tool stopped by SIGPIPE ends.
"""

from __future__ import annotations

import argparse
from collections.abc import Collection, Iterator, Sequence
import contextlib
import importlib
import os
import select
import signal
import sys
import threading
from typing import Any

from face_tracking_ros.errors import FaceTrackingError, warnings_to
from face_tracking_ros.threads import limit_blas_threads

# Module names under face_tracking_ros.cli, one per subcommand (named as its module with '-'
# for '_'), in help order, with the subcommand's one-line help.
SUBCOMMANDS: dict[str, str] = {
    'msgs': 'list the face_tracking_msgs message types known to the bag typestore',
    'synth': 'render synthetic faces (stereo or mono) with ground truth into MCAP bags',
    'learn': 'learn a face model (mean shape, S, A, prior) from bags of 3-D meshes',
    'track': 'track the face in a recorded bag (mono or stereo) and score it against truth',
    'replay': "run a node's message processing over a bag into an output bag",
    'plot': 'plot a tracking output bag (pose, alpha, sigma over time)',
    'overlay': 'write a video of the input frames with the tracked mesh drawn',
    'train_expressions': 'train the expression classifier from the truth topics of labelled bags',
    'recognition_report': (
        'identity, expression and event accuracy on tracked bags against their truth'
    ),
    'enroll': 'enrol a person in an identity gallery from tracked recordings',
    'demo': 'run the whole system end to end on the synthetic world',
    'bench': 'speed, scaling, memory and accuracy benchmarks with their baseline (JSON)',
}

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130  # 128 + SIGINT, as a shell reports Ctrl-C
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as a shell reports a writer whose reader went (| head)


def build_parser(registered: Collection[str] = tuple(SUBCOMMANDS)) -> argparse.ArgumentParser:
    """Build the argument parser: every subcommand listed, some registered now.

    Args:
        registered: Module names under ``face_tracking_ros.cli`` whose subcommands' options are
            registered (their modules imported) now; the others' are once parsing chooses them.

    Returns:
        The parser; parsed arguments carry ``func``, the subcommand's handler.
    """
    parser = argparse.ArgumentParser(
        prog='face-tracking', description='3-D face tracking: offline tools of face_tracking_ros.'
    )
    subparsers = parser.add_subparsers(
        dest='command', metavar='COMMAND', required=True, action=_Subcommands
    )
    for module, summary in SUBCOMMANDS.items():
        subparsers.add_subcommand(module, summary)
    for module in registered:
        subparsers.load(_command(module))
    return parser


def _command(module: str) -> str:
    """The subcommand implemented by a module under ``face_tracking_ros.cli``."""
    return module.replace('_', '-')


class _Subcommands(argparse._SubParsersAction):
    """The subcommands' parsers, whose options are registered when parsing chooses them."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._unregistered: dict[str, str] = {}  # subcommand -> module

    def add_subcommand(self, module: str, summary: str) -> None:
        """List a subcommand implemented by a module under ``face_tracking_ros.cli``."""
        self.add_parser(_command(module), help=summary)
        self._unregistered[_command(module)] = module

    def load(self, command: str) -> None:
        """Import a listed subcommand's module and register its options, unless done."""
        module = self._unregistered.pop(command, None)
        if module is not None:
            importlib.import_module(f'{__package__}.{module}').register(self.choices[command])

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        self.load(values[0])  # a valid subcommand: argparse has checked it
        super().__call__(parser, namespace, values, option_string)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``face-tracking`` command.

    Args:
        argv: Arguments without the program name; default ``sys.argv[1:]``.

    Returns:
        The exit status: the subcommand's (0 if it returns None), 2 on a FaceTrackingError or
        an OSError, 130 on an interruption the subcommand does not handle, 141 when standard
        output's reader has gone.
    """
    try:
        with _sigterm_as_ctrl_c(), warnings_to(_print_warning):
            # Inside: parsing imports the chosen subcommand's modules (a second or more on a
            # loaded machine), and a Ctrl-C or SIGTERM then ends the command as any other does.
            args = build_parser(()).parse_args(argv)
            limit_blas_threads()
            status = args.func(args)
            sys.stdout.flush()  # a reader gone is found here, not at the interpreter's exit
    except (FaceTrackingError, OSError) as error:
        if isinstance(error, BrokenPipeError) and _stdout_reader_gone():
            return EXIT_BROKEN_PIPE  # (another pipe broken, such as a subprocess's, is an error)
        print(f'error: {error}', file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0 if status is None else int(status)


def _stdout_reader_gone() -> bool:
    """Whether standard output is a pipe whose reader has closed it; if so, point it elsewhere.

    A pipe without a reader polls as an error. Standard output is then sent to /dev/null, so
    that what is left in its buffer does not fail again at the interpreter's exit.
    """
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # replaced by an object without a descriptor
        return False
    poll = select.poll()
    poll.register(fd, select.POLLOUT)
    if not any(events & select.POLLERR for _, events in poll.poll(0)):
        return False
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)
    return True


def _print_warning(message: str) -> None:
    """Print a warning of the package (:func:`~face_tracking_ros.errors.warnings_to`)."""
    print(f'warning: {message}', file=sys.stderr)


@contextlib.contextmanager
def _sigterm_as_ctrl_c() -> Iterator[None]:
    """Within the block, SIGTERM raises KeyboardInterrupt (in the main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == '__main__':
    sys.exit(main())
