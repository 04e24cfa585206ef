"""What every benchmark shares: options, timing, one-core pinning, memory, JPEG frames."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
import os
from pathlib import Path
import sys
import time

import cv2
import numpy as np

from face_tracking_ros.threads import ONE_THREAD_ENV

PROFILE = Path(__file__).resolve().parents[2] / 'config' / 'fastdds_profile.xml'


@dataclass(frozen=True)
class Cores:
    """The two cores benchmarks run on.

    Attributes:
        bench: the core the measured code runs on (a node, a tracker, the learner).
        driver: the core of live benchmarks' drivers (publisher, subscriber); ``bench`` too
            when there is only one.
    """

    bench: int
    driver: int

    @classmethod
    def of(cls, affinity: Iterable[int] | None = None) -> Cores:
        """The lowest two cores of ``affinity``, by default this process's CPU affinity.

        So ``taskset -c 2,3 face-tracking bench`` measures on core 2 and drives on core 3.
        """
        ordered = sorted(os.sched_getaffinity(0) if affinity is None else affinity)
        return cls(ordered[0], ordered[1] if len(ordered) > 1 else ordered[0])


@dataclass(frozen=True)
class BenchOptions:
    """How a benchmark runs.

    Attributes:
        quick: the smoke-test sizes (seconds, not minutes).
        work_dir: directory for the files a benchmark writes (bags, models), created if missing.
        minutes: duration of the soak run, min.
        domain_id: ROS_DOMAIN_ID of the live benchmarks' DDS traffic.
        seed: seed of every synthetic scene and random draw.
        cores: the cores to measure and to drive on (by default from the CPU affinity the
            command was started with).
    """

    quick: bool = False
    work_dir: Path = Path('out/bench')
    minutes: float = 30.0
    domain_id: int = 70
    seed: int = 0
    cores: Cores = field(default_factory=Cores.of)


def jpeg_compressed(image: np.ndarray, quality: int) -> np.ndarray:
    """``image`` JPEG-encoded at ``quality`` and decoded (OpenCV).

    What a node decodes from image_transport's compressed topic (its default quality is 95).
    """
    encoded = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1]
    return cv2.imdecode(encoded, cv2.IMREAD_UNCHANGED)


def last_lines(text: str, count: int) -> str:
    """The last ``count`` lines of ``text`` (a failed process's output), joined by ' | '."""
    return ' | '.join(text.strip().splitlines()[-count:])


def skipped(reason: str) -> dict[str, str]:
    """The JSON entry of a benchmark piece that cannot run yet, with why."""
    return {'skipped': reason}


def timing_summary(seconds: Sequence[float]) -> dict[str, float]:
    """Median and 99th percentile of per-call times, ms, with the sample count."""
    ms = 1000.0 * np.asarray(seconds, dtype=float)
    return {
        'median_ms': float(np.median(ms)),
        'p99_ms': float(np.percentile(ms, 99)),
        'mean_ms': float(ms.mean()),
        'samples': int(ms.size),
    }


def time_calls(calls: Sequence[Callable[[], object]]) -> list[float]:
    """Wall time of each call, in order, s (``time.perf_counter``)."""
    durations = []
    for call in calls:
        start = time.perf_counter()
        call()
        durations.append(time.perf_counter() - start)
    return durations


def pin_to_core(core: int) -> int:
    """Pin the calling process to one core; its id.

    ``core`` need not be in the process's affinity: a live benchmark's process, pinned to the
    bench core by the runner, moves its driver to the driver core, and starts its nodes on the
    bench core from there (:class:`Cores`). A core the process may not run on (a one-core
    machine, a cpuset without it) gives the lowest core of its affinity instead.
    """
    try:
        os.sched_setaffinity(0, {core})
    except OSError:  # no such core here
        core = min(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {core})
    return core


def process_cpu_seconds(pid: int) -> float:
    """CPU time a process has used so far, user and system, all its threads (/proc/<pid>/stat).

    Returns:
        The seconds, or NaN once the process is gone.
    """
    try:
        stat = Path(f'/proc/{pid}/stat').read_text()
    except (FileNotFoundError, ProcessLookupError):
        return float('nan')
    fields = stat.rsplit(')', 1)[1].split()  # after the command name, which may hold spaces
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')  # utime, stime


def proc_status_mb(pid: int, field: str) -> float:
    """A memory field of /proc/<pid>/status (e.g. 'VmHWM' peak RSS, 'VmRSS'), MB (2^20 bytes).

    Returns:
        The value, or NaN once the process is gone.
    """
    try:
        lines = Path(f'/proc/{pid}/status').read_text().splitlines()
    except (FileNotFoundError, ProcessLookupError):
        return float('nan')
    for line in lines:
        if line.startswith(f'{field}:'):
            return int(line.split()[1]) / 1024.0
    return float('nan')


def dds_env(domain_id: int) -> dict[str, str]:
    """The environment of a benchmark process: one BLAS thread, loopback DDS on ``domain_id``.

    The Fast DDS profile and AMENT_PREFIX_PATH already set are kept; otherwise the package's
    loopback profile and the interpreter's prefix are used.
    """
    env = dict(os.environ)
    env.update(ONE_THREAD_ENV)
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.setdefault('FASTDDS_DEFAULT_PROFILES_FILE', str(PROFILE))
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    return env
