"""Live latency over DDS on loopback: image published to face/state received (issue 9).

Each tracker node in turn (mono_tracker, then stereo_tracker) runs in its own process on one
core; this process publishes rendered 640x480 images (image pairs, left and right with one stamp)
and their camera_info at 30 Hz with the wall-clock time as stamp, over the package's Fast DDS
profile, and times each ``face/state`` back. Then the rate is stepped up until frames
are dropped (the node's image QoS is rclpy's sensor-data profile, best effort with depth 5: a busy
tracker works through at most the 5 newest frames and drops older ones).
Target: p99 <= 10 ms at 30 Hz with no drops.

The stream is one continuous head motion as long as the warm-up and the timed 30-Hz run, so no
frame of the timed run replays an earlier one. A short sequence played forward and back (90
frames before 2026-12-04) turns the head around at full speed every 3 s, which no head does: the
constant-velocity prediction is then off by twice a frame's motion, and those 1.1 % of the frames
were the p99's. The rate steps continue the motion where the timed run stopped and play the
sequence backwards from its end.
"""

from __future__ import annotations

import math
import os
from typing import Any

from face_tracking_ros.bench.common import BenchOptions, pin_to_core
from face_tracking_ros.bench.live import Driver, NodeProcess, tracker_inputs
from face_tracking_ros.synthetic.scenes import Kind

WIDTH, HEIGHT = 640, 480
RATE_HZ = 30.0
SECONDS, QUICK_SECONDS = 60.0, 5.0
WARM_UP_S = 1.0
FRAMES = round(RATE_HZ * (WARM_UP_S + SECONDS))  # one per image of the warm-up and timed run
QUICK_FRAMES = 15
STEP_RATES = (10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0)
QUICK_STEP_RATES = (15.0, 30.0)
STEP_SECONDS, QUICK_STEP_SECONDS = 4.0, 1.5


TRACKERS = {Kind.MONO: 'mono_tracker', Kind.STEREO: 'stereo_tracker'}


def run(options: BenchOptions) -> dict[str, Any]:
    """Each tracker node's latency p50/p99 and drops at 30 Hz and highest rate without drops.

    Returns:
        ``{'mono': {...}, 'stereo': {...}}``, each as :func:`tracker_latency` returns.
    """
    pin_to_core(options.cores.driver)
    return {kind.value: tracker_latency(kind, node, options) for kind, node in TRACKERS.items()}


def tracker_latency(kind: Kind, node: str, options: BenchOptions) -> dict[str, Any]:
    """One tracker node fed its camera streams: latency at 30 Hz, then the rate stepped up.

    Returns:
        ``{'size', 'at_30hz': {...}, 'rate_steps': [...], 'max_rate_without_drops_hz': r,
        'node_cpu_ms_per_frame': c, 'node_peak_rss_mb': m, 'cores': {'node': [...], 'driver':
        [...]}, 'stream_frames': f}`` (``r`` is 0 when even the lowest step dropped frames;
        ``c`` the node process's CPU time over the 30-Hz run, all its threads, per image (pair)
        answered, NaN if none was: the node's work per frame, which the latency does not tell
        apart from the machine's delays; ``cores`` the CPU affinities the node and the driver
        ran with; ``f`` the rendered frames (pairs) the stream plays).
    """
    frames = QUICK_FRAMES if options.quick else FRAMES
    streams, params = tracker_inputs(options.work_dir, kind, WIDTH, HEIGHT, frames, options.seed)
    process = NodeProcess(node, params, options, options.work_dir / f'live_{node}.log')
    driver = Driver(streams)
    try:
        driver.wait_for([process])
        driver.run(RATE_HZ, WARM_UP_S)
        cpu_before = process.cpu_seconds()
        main = driver.run(RATE_HZ, QUICK_SECONDS if options.quick else SECONDS)
        node_cpu = process.cpu_seconds() - cpu_before
        steps = []
        for rate in QUICK_STEP_RATES if options.quick else STEP_RATES:
            steps.append(driver.run(rate, QUICK_STEP_SECONDS if options.quick else STEP_SECONDS))
            if steps[-1].dropped:
                break
        peak_rss = process.peak_rss_mb()
        cores = {'node': process.cores(), 'driver': sorted(os.sched_getaffinity(0))}
    finally:
        driver.close()
        process.stop()
    sustained = [step.rate_hz for step in steps if not step.dropped]
    return {
        'size': f'{WIDTH}x{HEIGHT}',
        'at_30hz': main.summary(),
        'rate_steps': [step.summary() for step in steps],
        'max_rate_without_drops_hz': max(sustained, default=0.0),
        'node_cpu_ms_per_frame': node_cpu / main.received * 1e3 if main.received else math.nan,
        'node_peak_rss_mb': peak_rss,
        'cores': cores,
        'stream_frames': frames,
    }
