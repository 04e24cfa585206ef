"""Soak: live tracking over DDS on loopback for a long run, memory and latency watched (issue 10).

mono_tracker tracks rendered 640x480 images published at 30 Hz for ``--minutes`` (default 30) in
10-s windows (each followed by a 1-s pause that collects its last states), while bag_recorder
records every ``face/state``. After each window the tracker's RSS is sampled (VmRSS) and the
window's latency p50/p99 and drops are kept. Targets: RSS growth < 5 MB from the end of the
first minute (warm-up: allocator pools, DDS history) to the end, no growth in latency, and the
recorder holding every face/state this process received. Not part of the tests.
"""

from __future__ import annotations

import math
import shutil
from typing import Any

import numpy as np

from face_tracking_ros.bench.common import BenchOptions, pin_to_core
from face_tracking_ros.bench.live import Driver, NodeProcess, RunFigures, tracker_inputs
from face_tracking_ros.io.bags import read_messages
from face_tracking_ros.synthetic.scenes import Kind

WIDTH, HEIGHT = 640, 480
FRAMES = 90
RATE_HZ = 30.0
WINDOW_S = 10.0
WARM_UP_S = 60.0
QUICK_MINUTES = 0.5
STATE_TOPIC = 'face/state'
RECORDED_TOPIC = '/face/state'  # the recorder's name for it (resolved in the root namespace)


def run(options: BenchOptions) -> dict[str, Any]:
    """RSS samples and per-window latency of a long live run; the recorder's completeness.

    Returns:
        ``{'minutes', 'size', 'rate_hz', 'windows': [{t_s, rss_mb,
        latency_p50_ms, latency_p99_ms, dropped}], 'rss_growth_mb',
        'latency_p50_slope_ms_per_min', 'published', 'received', 'recorded', 'recorder_missing',
        'tracker_peak_rss_mb', 'recorder_peak_rss_mb'}``.
    """
    pin_to_core(options.cores.driver)
    minutes = min(options.minutes, QUICK_MINUTES) if options.quick else options.minutes
    work = options.work_dir
    streams, params = tracker_inputs(work, Kind.MONO, WIDTH, HEIGHT, FRAMES, options.seed)
    recording = work / 'soak_recording'
    shutil.rmtree(recording, ignore_errors=True)
    tracker = NodeProcess('mono_tracker', params, options, work / 'soak_tracker.log')
    recorder = NodeProcess(
        'bag_recorder',
        {'output': recording, 'topics': f'[{STATE_TOPIC}]'},
        options,
        work / 'soak_recorder.log',
    )
    driver = Driver(streams, name='bench_soak_driver')
    windows: list[tuple[float, float, RunFigures]] = []
    try:
        driver.wait_for([tracker, recorder], state_subscribers=2)
        elapsed = 0.0
        while elapsed < 60.0 * minutes:
            figures = driver.run(RATE_HZ, WINDOW_S)
            elapsed += WINDOW_S
            windows.append((elapsed, tracker.rss_mb(), figures))
        peaks = {'tracker': tracker.peak_rss_mb(), 'recorder': recorder.peak_rss_mb()}
    finally:
        driver.close()
        tracker.stop()
        recorder.stop()
    recorded = sum(1 for _ in read_messages(recording, topics=[RECORDED_TOPIC]))
    return _summary(windows, recorded, peaks, minutes)


def _summary(
    windows: list[tuple[float, float, RunFigures]],
    recorded: int,
    peaks: dict[str, float],
    minutes: float,
) -> dict[str, Any]:
    """Figures of the soak from its windows.

    The RSS growth is from the first window after the WARM_UP_S warm-up to the last, and NaN
    (not measured) unless two windows follow it (a quick soak's do not); the latency trend is
    NaN with one window.
    """
    times = np.array([t for t, _, _ in windows])
    rss = np.array([r for _, r, _ in windows])
    p50 = np.array([f.summary()['latency_p50_ms'] for _, _, f in windows])
    after_warm_up = rss[times >= WARM_UP_S]
    received = sum(f.received for _, _, f in windows)
    return {
        'minutes': minutes,
        'size': f'{WIDTH}x{HEIGHT}',
        'rate_hz': RATE_HZ,
        'windows': [
            {
                't_s': t,
                'rss_mb': r,
                **{k: f.summary()[k] for k in ('latency_p50_ms', 'latency_p99_ms', 'dropped')},
            }
            for t, r, f in windows
        ],
        'rss_growth_mb': float(after_warm_up[-1] - after_warm_up[0])
        if len(after_warm_up) > 1
        else math.nan,
        'latency_p50_slope_ms_per_min': float(np.polyfit(times / 60.0, p50, 1)[0])
        if len(windows) > 1
        else math.nan,
        'published': sum(f.published for _, _, f in windows),
        'received': received,
        'recorded': recorded,
        'recorder_missing': received - recorded,
        'tracker_peak_rss_mb': peaks['tracker'],
        'recorder_peak_rss_mb': peaks['recorder'],
    }
