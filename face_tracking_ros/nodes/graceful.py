"""Run a node until SIGINT, SIGTERM or its own end, then let it finish its work before shutdown.

rclpy's own signal handlers shut the context down at once, so messages DDS has already delivered
to a subscription but the executor has not yet taken are lost, a node still being built fails
on its invalid context with a traceback, and the KeyboardInterrupt they raise may land in a
callback that an executor calls from C++, which aborts the process. Here a signal only
requests a stop: the node is built, the spin loop ends, the node's ``finish`` runs while the
executor still works (the recorder takes what is left in its subscriptions and closes its bag),
then the node is destroyed and rclpy shut down; the process exits with 0. A node that works
long while it is built (the learner learns then) may be interrupted instead: KeyboardInterrupt
stops it as Ctrl-C stops ``face-tracking learn``, and the process exits with 128 + the signal's
number. Used by every node of the package.

Once built, a node's start-up objects (the imported modules' and the compiled kernels', some
190 000 of them in a tracker) are frozen out of the garbage collector's sight
(:func:`freeze_start_up`): a full collection that walked them all stopped the stereo_tracker for
90-110 ms every 10-20 s, and the images queued behind it made the live latency's p99.
"""

from __future__ import annotations

from collections.abc import Callable
import gc
import signal
import threading
from typing import Protocol

import rclpy
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.impl.rcutils_logger import RcutilsLogger
import rclpy.logging
from rclpy.signals import SignalHandlerOptions

from face_tracking_ros.errors import FaceTrackingError
from face_tracking_ros.threads import limit_blas_threads

SPIN_PERIOD_S = 0.1  # longest delay between a stop request and the end of the spin loop
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
ERROR_EXIT_CODE = 2
# What a user gets wrong: a bad bag or value (ours), a parameter of the wrong type
# (e.g. rate:=2 for a float), an invalid topic name (e.g. in remap).
USER_ERRORS = (FaceTrackingError, ParameterException, NameValidationException)
# rclpy's ValueError when a node declares the parameters it was given and one is an empty list
# ('-p topics:=[]', 'topics: []' in a parameters file), which has no type.
UNTYPED_PARAMETER = 'Cannot declare a statically typed parameter with default value of type'
UNTYPED_PARAMETER_ERROR = (
    'a parameter is given as an empty list ([]), which rclpy cannot type: leave it out (every '
    "list parameter's default is empty) or give it a value"
)


def rcl_reason(error: RuntimeError) -> str:
    """The message of rclpy's RCLError without rcl's source location (', at .../x.c:73')."""
    return str(error).split(', at /')[0]


def node_logger(name: str) -> RcutilsLogger:
    """The logger of a node named ``name`` as the command line renames it (``-r __node:=...``).

    For the error of a node that failed while it was built: its log line then carries the name
    and namespace the node runs under, as every later line would, not the executable's default.
    A probe node gives them (rcl applies the remapping; rclpy does not expose it otherwise); a
    remapping rcl refuses leaves the default name.
    """
    try:
        probe = rclpy.create_node(name, start_parameter_services=False, enable_rosout=False)
    except NameValidationException:
        return rclpy.logging.get_logger(name)
    logger = probe.get_logger()
    probe.destroy_node()
    return logger


class StoppableNode(Protocol):
    """A node that may end by itself and has work to finish before it is destroyed."""

    def finished(self) -> bool:
        """Whether the node has done its job and the process may end."""
        ...

    def finish(self, executor: Executor) -> None:
        """Complete the node's work after the spin loop (the executor can still spin it).

        Raises:
            FaceTrackingError: if the node's job failed; the process exits with code 2.
        """
        ...

    def destroy_node(self) -> None:
        """Release the node's resources."""
        ...


class Endless:
    """For a node that runs until it is stopped and leaves nothing to finish then."""

    def finished(self) -> bool:
        """Never by itself."""
        return False

    def finish(self, executor: Executor) -> None:
        """Nothing is left: every message was handled as it came."""


def freeze_start_up() -> None:
    """Collect the garbage of a node's start-up, then freeze what is left (``gc.freeze``).

    Frozen objects are never collected, nor walked by a collection: the modules, compiled
    kernels and the node itself live as long as the process does. Without it, the collector's
    full (generation-2) collections walked them all: measured on the live benchmark's
    stereo_tracker (640x480 pairs at 30 Hz), one every 10-20 s took 90-110 ms and delayed the
    4-5 pairs queued behind it.
    """
    gc.collect()
    gc.freeze()


class _StopSignals:
    """What SIGINT and SIGTERM do: request the spin's end, or interrupt the node's building."""

    def __init__(self, interrupt_start: bool) -> None:
        """With ``interrupt_start``, a signal interrupts until :attr:`spinning` is set."""
        self.requested = threading.Event()
        self.spinning = not interrupt_start
        self.signum = 0

    def __call__(self, signum: int, _frame: object) -> None:
        """Handle a stop signal.

        Raises:
            KeyboardInterrupt: while an interruptible node is being built.
        """
        self.signum = signum
        self.requested.set()
        if not self.spinning:
            raise KeyboardInterrupt


def run_until_stopped(
    name: str,
    make_node: Callable[[], StoppableNode],
    args: list[str] | None = None,
    executor_type: Callable[[], Executor] = SingleThreadedExecutor,
    interrupt_start: bool = False,
) -> None:
    """Init rclpy, spin the node until a stop signal or its end, finish it and shut down.

    BLAS is limited to one thread (:mod:`face_tracking_ros.threads`), as in ``face-tracking``:
    the learner node computes as ``face-tracking learn`` does.

    Args:
        name: node name, for the log line of an error raised while building the node.
        make_node: builds the node (after ``rclpy.init``).
        args: command-line arguments (``--ros-args ...``); default ``sys.argv``.
        executor_type: makes the executor that spins the node.
        interrupt_start: a stop signal interrupts the building of the node (KeyboardInterrupt)
            instead of ending it once built.

    Raises:
        SystemExit: with code 2 after logging one of :data:`USER_ERRORS`, a command line rcl
            cannot parse or an empty list given as a parameter; with 128 + the signal's
            number for a stop signal that interrupted the node's building.
    """
    limit_blas_threads()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RuntimeError as error:  # rclpy's RCLError, e.g. for '-p output:=' (no value)
        rclpy.logging.get_logger(name).error(rcl_reason(error))
        raise SystemExit(ERROR_EXIT_CODE) from None
    stop = _StopSignals(interrupt_start)
    previous = {sig: signal.signal(sig, stop) for sig in STOP_SIGNALS}
    executor = None
    node = None
    try:
        node = make_node()
        freeze_start_up()
        executor = executor_type()
        executor.add_node(node)  # type: ignore[arg-type]
        stop.spinning = True
        while not (stop.requested.is_set() or node.finished()):
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
        node.finish(executor)
    except KeyboardInterrupt:
        raise SystemExit(128 + stop.signum) from None
    except USER_ERRORS as error:
        node_logger(name).error(str(error))
        raise SystemExit(ERROR_EXIT_CODE) from None
    except ValueError as error:
        if not str(error).startswith(UNTYPED_PARAMETER):
            raise
        node_logger(name).error(UNTYPED_PARAMETER_ERROR)
        raise SystemExit(ERROR_EXIT_CODE) from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
