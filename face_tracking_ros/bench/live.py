"""Live benchmarks' machinery: node processes on one core and a DDS driver on loopback.

:class:`NodeProcess` starts a node executable (``mono_tracker``, ...) as a subprocess pinned to the
bench core (:class:`~.common.Cores`) with one BLAS thread, on the benchmark's ROS domain, loopback
only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and the package's Fast DDS profile).
:class:`Driver` is the other end, in the benchmark process: it publishes pre-converted image (pair)
messages and their camera_info with the wall-clock time as stamp, at a fixed rate, and records when
each ``face/state`` of a stamp arrives, so latency = receipt time - image stamp (one clock).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import functools
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from face_tracking_ros.bench.common import (
    BenchOptions,
    dds_env,
    last_lines,
    pin_to_core,
    proc_status_mb,
    process_cpu_seconds,
)
from face_tracking_ros.bench.world import model_file, render_sequence, scene_config
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.geometry.camera import PinholeCamera
from face_tracking_ros.io import conversions
from face_tracking_ros.io.messages import RclpyMessages
from face_tracking_ros.model.model_file import load_model
from face_tracking_ros.synthetic.clicks import write_init_file
from face_tracking_ros.synthetic.recording import CAMERA_TOPICS
from face_tracking_ros.synthetic.scenes import Kind
from face_tracking_ros.tracking.result import TrackStatus

STATE_TOPIC = 'face/state'
STARTUP_TIMEOUT = 30.0  # s, for a node to subscribe and publish
STOP_TIMEOUT = 10.0  # s, for a node to exit after SIGINT
LATE_GRACE = 1.0  # s, waited after the last image for its state


class NodeProcess:
    """A node executable running in its own process on one core.

    Args:
        node: executable name (a console script next to the Python interpreter).
        params: ROS parameters, name -> value.
        options: the benchmark's ROS domain (ROS_DOMAIN_ID) and cores (the node runs on the
            bench core).
        log: file receiving the node's stdout and stderr.

    Raises:
        ConfigError: if the executable is not installed.
    """

    def __init__(
        self, node: str, params: Mapping[str, object], options: BenchOptions, log: Path
    ) -> None:
        """Start the node."""
        executable = Path(sys.executable).parent / node
        if not executable.is_file():
            msg = f'node executable {executable} is not installed (make setup)'
            raise ConfigError(msg)
        arguments = [str(executable), '--ros-args']
        for name, value in params.items():
            arguments += ['-p', f'{name}:={value}']
        log.parent.mkdir(parents=True, exist_ok=True)
        self.name = node
        self.log = log
        with log.open('w') as stream:
            self._process = subprocess.Popen(
                arguments,
                env=dds_env(options.domain_id),
                stdout=stream,
                stderr=subprocess.STDOUT,
                preexec_fn=functools.partial(pin_to_core, options.cores.bench),
            )

    @property
    def pid(self) -> int:
        """The process id."""
        return self._process.pid

    def alive(self) -> bool:
        """Whether the process is still running."""
        return self._process.poll() is None

    def cores(self) -> list[int]:
        """The cores the process may run on (its CPU affinity)."""
        return sorted(os.sched_getaffinity(self.pid))

    def peak_rss_mb(self) -> float:
        """Peak resident set size so far (VmHWM), MB."""
        return proc_status_mb(self.pid, 'VmHWM')

    def cpu_seconds(self) -> float:
        """CPU time the process has used so far, all its threads (DDS's too), s."""
        return process_cpu_seconds(self.pid)

    def rss_mb(self) -> float:
        """Current resident set size (VmRSS), MB."""
        return proc_status_mb(self.pid, 'VmRSS')

    def stop(self) -> int:
        """SIGINT, then SIGKILL if it has not exited in time; the exit status."""
        if self.alive():
            self._process.send_signal(signal.SIGINT)
            try:
                self._process.wait(STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                self._process.kill()
        return self._process.wait()

    def tail(self, lines: int = 5) -> str:
        """The last lines of its log (for error reports)."""
        return last_lines(self.log.read_text(errors='replace'), lines)


@dataclass(frozen=True)
class Stream:
    """A camera stream to publish: topics, camera and the frames.

    Attributes:
        image_topic: image topic.
        info_topic: camera_info topic.
        camera: the camera.
        frames: the images, (H, W) uint8, published in a forward-backward loop so the motion
            stays continuous.
    """

    image_topic: str
    info_topic: str
    camera: PinholeCamera
    frames: Sequence[np.ndarray]


@dataclass(frozen=True)
class RunFigures:
    """What one timed run at a fixed rate gave.

    Attributes:
        rate_hz: requested publishing rate.
        seconds: its duration.
        published: images (pairs) published.
        received: face/state messages received for them.
        latency_ms: (received,) image stamp to face/state receipt, ms, in publishing order.
        tracked: states with status TRACKING.
    """

    rate_hz: float
    seconds: float
    published: int
    received: int
    latency_ms: np.ndarray
    tracked: int

    @property
    def dropped(self) -> int:
        """Images (pairs) without a face/state."""
        return self.published - self.received

    def summary(self) -> dict[str, float | int]:
        """JSON-ready figures: latency p50 / p99 / max, counts and drops."""
        latency = self.latency_ms if self.latency_ms.size else np.array([np.nan])
        return {
            'rate_hz': self.rate_hz,
            'seconds': self.seconds,
            'published': self.published,
            'received': self.received,
            'dropped': self.dropped,
            'tracked': self.tracked,
            'latency_p50_ms': float(np.median(latency)),
            'latency_p99_ms': float(np.percentile(latency, 99)),
            'latency_max_ms': float(np.max(latency)),
        }


class Driver:
    """Publishes camera streams at a rate and times the ``face/state`` that come back.

    Args:
        streams: the camera streams (one for mono, left and right for stereo), all of the same
            length; the frames of one index are published with one stamp.
        name: the driver node's name.
    """

    def __init__(self, streams: Sequence[Stream], name: str = 'bench_driver') -> None:
        """Create the context, node, publishers, the state subscription and the spin thread."""
        self._context = Context()
        rclpy.init(context=self._context)
        self._node = rclpy.create_node(name, context=self._context)
        factory = RclpyMessages()
        self._messages = [
            [
                conversions.array_to_image(
                    factory, conversions.make_header(factory, 0, 'camera'), image
                )
                for image in stream.frames
            ]
            for stream in streams
        ]
        header = conversions.make_header(factory, 0, 'camera')
        self._infos = [conversions.camera_to_info(factory, header, s.camera) for s in streams]
        image_class = factory.message_class(conversions.IMAGE_TYPE)
        info_class = factory.message_class(conversions.CAMERA_INFO_TYPE)
        self._publishers = [
            (
                self._node.create_publisher(image_class, s.image_topic, qos_profile_sensor_data),
                self._node.create_publisher(info_class, s.info_topic, qos_profile_sensor_data),
            )
            for s in streams
        ]
        self._received: dict[int, tuple[int, int]] = {}
        self._lock = threading.Lock()
        self._node.create_subscription(
            factory.message_class('face_tracking_msgs/msg/FaceState'),
            STATE_TOPIC,
            self._on_state,
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE),
        )
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._thread = threading.Thread(target=self._executor.spin, daemon=True)
        self._thread.start()
        self._index = 0

    def _on_state(self, msg: Any) -> None:
        """Record the receipt time and status of a face/state, by its image stamp."""
        now = time.time_ns()
        with self._lock:
            self._received[conversions.stamp_to_ns(msg.header.stamp)] = (now, int(msg.status))

    def wait_for(
        self,
        nodes: Sequence[NodeProcess],
        timeout: float = STARTUP_TIMEOUT,
        state_subscribers: int = 1,
    ) -> None:
        """Wait until every publisher has a subscriber and face/state a publisher.

        ``state_subscribers`` is how many subscriptions face/state must have (this driver's
        own included), e.g. 2 with a recorder.

        Raises:
            ConfigError: if a node died or the connections did not come up in time.
        """
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            dead = [node for node in nodes if not node.alive()]
            if dead:
                msg = f'{dead[0].name} exited during start-up: {dead[0].tail()}'
                raise ConfigError(msg)
            subscribed = all(
                pub.get_subscription_count() > 0 for pair in self._publishers for pub in pair
            )
            if (
                subscribed
                and self._node.count_publishers(STATE_TOPIC) > 0
                and self._node.count_subscribers(STATE_TOPIC) >= state_subscribers
            ):
                return
            time.sleep(0.1)
        msg = f'nodes {[n.name for n in nodes]} did not connect within {timeout:g} s'
        raise ConfigError(msg)

    def run(self, rate_hz: float, seconds: float) -> RunFigures:
        """Publish at ``rate_hz`` for ``seconds`` and collect the face/state latencies.

        Frames continue the forward-backward loop where the previous run stopped. The states of
        the last images are waited for :data:`LATE_GRACE` s.
        """
        period_ns = round(1e9 / rate_hz)
        count = max(1, round(rate_hz * seconds))
        start = time.time_ns()
        stamps = []
        for k in range(count):
            due = start + k * period_ns
            delay = (due - time.time_ns()) / 1e9
            if delay > 0:
                time.sleep(delay)
            stamps.append(self._publish_next())
        time.sleep(LATE_GRACE)
        with self._lock:
            receipts = {
                stamp: self._received.pop(stamp) for stamp in stamps if stamp in self._received
            }
        got = [stamp for stamp in stamps if stamp in receipts]
        return RunFigures(
            rate_hz=rate_hz,
            seconds=seconds,
            published=count,
            received=len(got),
            latency_ms=np.array([(receipts[s][0] - s) / 1e6 for s in got]),
            tracked=sum(receipts[s][1] == TrackStatus.TRACKING for s in got),
        )

    def _publish_next(self) -> int:
        """Publish the next frame of every stream (camera_info first) stamped now; the stamp."""
        length = len(self._messages[0])
        cycle = max(1, 2 * length - 2)
        position = self._index % cycle
        frame = position if position < length else cycle - position
        self._index += 1
        stamp = time.time_ns()
        for (image_pub, info_pub), images, info in zip(
            self._publishers, self._messages, self._infos, strict=True
        ):
            message = images[frame]
            for header in (info.header, message.header):
                header.stamp.sec, header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            info_pub.publish(info)
            image_pub.publish(message)
        return stamp

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        self._executor.shutdown()
        self._node.destroy_node()
        rclpy.try_shutdown(context=self._context)
        self._thread.join(timeout=5.0)


def tracker_inputs(
    work_dir: Path, kind: Kind, width: int, height: int, frames: int, seed: int
) -> tuple[list[Stream], dict[str, str]]:
    """Rendered streams of the test subject and the tracker node parameters that go with them.

    Returns:
        The streams (``image``, or ``left/image_raw`` and ``right/image_raw``) and the node's
        ``model_file`` (learned 34-node model) and ``init_file`` (simulated clicks on frame 0).
    """
    sequence = render_sequence(scene_config(kind, width, height, frames, seed))
    model = model_file(work_dir, 34, seed)
    init = sequence.initialisation(load_model(model).node_names, seed)
    init_file = write_init_file(init, Path(work_dir) / f'init_{kind.value}_{width}x{height}.json')
    streams = [
        Stream(CAMERA_TOPICS[name][0], CAMERA_TOPICS[name][1], camera, sequence.images(name))
        for name, camera in sequence.cameras.items()
    ]
    return streams, {'model_file': str(model), 'init_file': str(init_file)}
