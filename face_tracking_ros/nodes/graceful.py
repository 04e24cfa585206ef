"""Run a node until SIGINT, SIGTERM or its own end, then let it finish its work before shutdown.

rclpy's own signal handlers shut the context down at once, so messages DDS has already delivered
to a subscription but the executor has not yet taken are lost. Here a signal only requests a stop:
the spin loop ends, the node's ``finish`` runs while the executor still works (the recorder takes
what is left in its subscriptions and closes its bag), then the node is destroyed and rclpy shut
down. Used by the bag_player and bag_recorder nodes.
"""

from __future__ import annotations

from collections.abc import Callable
import signal
import threading
from typing import Protocol

import rclpy
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.executors import Executor, SingleThreadedExecutor
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


def run_until_stopped(
    name: str, make_node: Callable[[], StoppableNode], args: list[str] | None = None
) -> None:
    """Init rclpy, spin the node until a stop signal or its end, finish it and shut down.

    BLAS is limited to one thread (:mod:`face_tracking_ros.threads`), as in the other nodes and
    ``face-tracking``: the learner node computes as ``face-tracking learn`` does.

    Args:
        name: node name, for the log line of an error raised while building the node.
        make_node: builds the node (after ``rclpy.init``).
        args: command-line arguments (``--ros-args ...``); default ``sys.argv``.

    Raises:
        SystemExit: with code 2 after logging one of :data:`USER_ERRORS`.
    """
    limit_blas_threads()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in STOP_SIGNALS}
    executor = SingleThreadedExecutor()
    node = None
    try:
        node = make_node()
        executor.add_node(node)  # type: ignore[arg-type]
        while not (stop.is_set() or node.finished()):
            executor.spin_once(timeout_sec=SPIN_PERIOD_S)
        node.finish(executor)
    except USER_ERRORS as error:
        rclpy.logging.get_logger(name).error(str(error))
        raise SystemExit(ERROR_EXIT_CODE) from None
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
