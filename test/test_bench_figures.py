"""The figures the benchmarks report, computed from by-hand inputs (no benchmark is run).

Percentiles, ratios to the baseline, frames/s and multiples of real time, dropped frames, the
highest rate without drops, scaling exponents, pooled errors and the soak's trends: the README's
Performance table is read from these. The slow parts (trackers, nodes, DDS, bags) are replaced
by fakes that return known figures.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from face_tracking_ros.bench import (
    common,
    learner_scaling,
    live,
    live_latency,
    memory,
    mono_accuracy,
    replay_throughput,
    runner,
    soak,
    stereo_accuracy,
    tracker_speed,
)
from face_tracking_ros.bench.common import (
    BenchOptions,
    Cores,
    dds_env,
    proc_status_mb,
    process_cpu_seconds,
    timing_summary,
)
from face_tracking_ros.bench.live import Driver, RunFigures
from face_tracking_ros.cli import bench as bench_cli
from face_tracking_ros.cli.bench import format_table
from face_tracking_ros.tracking.result import TrackStatus


def _run(rate_hz=30.0, published=5, latency=(2.0, 4.0, 6.0), tracked=3, seconds=2.0):
    """A RunFigures with ``published`` images and the given latencies (one per receipt)."""
    return RunFigures(rate_hz, seconds, published, len(latency), np.array(latency), tracked)


def test_timing_summary_gives_median_p99_and_mean_in_ms():
    # ms 1, 2, 3, 4, 10: p99 interpolates 96 % of the way from 4 to 10 (index 3.96).
    summary = timing_summary([0.001, 0.002, 0.003, 0.004, 0.010])
    assert summary == pytest.approx(
        {'median_ms': 3.0, 'p99_ms': 9.76, 'mean_ms': 4.0, 'samples': 5}
    )
    assert isinstance(summary['samples'], int)


def test_a_run_counts_drops_and_gives_latency_percentiles():
    summary = _run().summary()
    # 5 published, 3 received; latencies 2, 4, 6 ms: p99 at index 1.98 -> 4 + 0.98 * 2.
    assert summary == pytest.approx(
        {
            'rate_hz': 30.0,
            'seconds': 2.0,
            'published': 5,
            'received': 3,
            'dropped': 2,
            'tracked': 3,
            'latency_p50_ms': 4.0,
            'latency_p99_ms': 5.96,
            'latency_max_ms': 6.0,
        }
    )


def test_a_run_without_receipts_has_no_latency():
    summary = _run(latency=(), tracked=0).summary()
    assert summary['dropped'] == 5
    assert all(math.isnan(summary[f'latency_{k}_ms']) for k in ('p50', 'p99', 'max'))


def test_a_driver_run_times_the_states_of_its_own_images(monkeypatch):
    # A driver without DDS: its images are stamped 100..500 ns and the states of three come back
    # 2, 6 and 10 ms later (one LOST); a state of an earlier run's image is not counted.
    driver = object.__new__(Driver)
    driver._lock = threading.Lock()
    driver._received = {}
    stamps = itertools.count(100, 100)
    driver._publish_next = lambda: next(stamps)
    statuses = {100: TrackStatus.TRACKING, 300: TrackStatus.LOST, 500: TrackStatus.TRACKING}
    for stamp, status in [(50, TrackStatus.TRACKING), *statuses.items()]:
        header = SimpleNamespace(stamp=SimpleNamespace(sec=0, nanosec=stamp))
        at = stamp + 20_000 * stamp
        monkeypatch.setattr(live.time, 'time_ns', lambda at=at: at)
        driver._on_state(SimpleNamespace(header=header, status=int(status)))
    monkeypatch.undo()
    monkeypatch.setattr(live, 'LATE_GRACE', 0.0)

    figures = driver.run(1000.0, 0.005)

    assert (figures.published, figures.received, figures.tracked) == (5, 3, 2)
    assert figures.latency_ms.tolist() == [2.0, 6.0, 10.0]
    assert driver._received == {50: (50 + 20_000 * 50, int(TrackStatus.TRACKING))}
    assert driver.run(1000.0, 0.0001).published == 1  # at least one image


def test_a_driver_publishes_at_its_rate(monkeypatch):
    # A clock that only sleep advances: 200 Hz for 20 ms is 4 images 5 ms apart.
    now = [10**12]
    clock = SimpleNamespace(time_ns=lambda: now[0])
    clock.sleep = lambda seconds: now.__setitem__(0, now[0] + round(seconds * 1e9))
    monkeypatch.setattr(live, 'time', clock)
    driver = object.__new__(Driver)
    driver._lock = threading.Lock()
    driver._received = {}
    published = []
    driver._publish_next = lambda: published.append(now[0]) or now[0]

    assert driver.run(200.0, 0.02).published == 4
    assert [t - 10**12 for t in published] == [0, 5_000_000, 10_000_000, 15_000_000]
    assert now[0] == published[-1] + round(live.LATE_GRACE * 1e9)  # waited for the last state


def test_proc_status_gives_a_field_in_mb(monkeypatch):
    read = []
    status = 'Name:\tmono_tracker\nVmHWM:\t  204800 kB\nVmRSS:\t  102912 kB\n'

    def path(name):
        read.append(name)
        return SimpleNamespace(read_text=lambda: status)

    monkeypatch.setattr(common, 'Path', path)
    assert proc_status_mb(1234, 'VmHWM') == 200.0
    assert proc_status_mb(1234, 'VmRSS') == 100.5
    assert math.isnan(proc_status_mb(1234, 'NoSuchField'))
    assert read == ['/proc/1234/status'] * 3


def test_a_gone_process_has_no_memory_figure():
    assert math.isnan(proc_status_mb(2**22 + 1, 'VmHWM'))  # above pid_max: no such process


def test_process_cpu_seconds_counts_every_thread_of_a_process():
    def burn(seconds):
        end = time.thread_time() + seconds
        while time.thread_time() < end:
            pass

    before = process_cpu_seconds(os.getpid())
    worker = threading.Thread(target=burn, args=(0.2,))
    worker.start()
    burn(0.2)
    worker.join()
    used = process_cpu_seconds(os.getpid()) - before
    assert 0.38 <= used <= 0.6  # both threads' 0.2 s, in clock ticks (10 ms), and this test's
    assert math.isnan(process_cpu_seconds(2**22 + 1))  # no such process


def test_a_benchmark_process_runs_on_one_blas_thread_and_loopback_dds(monkeypatch):
    monkeypatch.setenv('FASTDDS_DEFAULT_PROFILES_FILE', '/etc/mine.xml')
    monkeypatch.delenv('AMENT_PREFIX_PATH', raising=False)
    env = dds_env(9)
    assert env['ROS_DOMAIN_ID'] == '9'
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    assert env['OMP_NUM_THREADS'] == env['OPENBLAS_NUM_THREADS'] == '1'
    assert env['FASTDDS_DEFAULT_PROFILES_FILE'] == '/etc/mine.xml'
    assert env['AMENT_PREFIX_PATH'] == sys.prefix
    monkeypatch.delenv('FASTDDS_DEFAULT_PROFILES_FILE')
    assert dds_env(9)['FASTDDS_DEFAULT_PROFILES_FILE'] == str(common.PROFILE)


def test_tracker_timing_excludes_the_first_frame_and_counts_tracked_frames(monkeypatch):
    calls = []
    statuses = {1: TrackStatus.TRACKING, 2: TrackStatus.LOST, 3: TrackStatus.TRACKING}

    def step(frame):
        calls.append(frame)
        return statuses.get(frame, TrackStatus.INITIALIZING)

    def timed(calls):
        for call in calls:
            call()
        return [0.001, 0.004, 0.002]

    monkeypatch.setattr(tracker_speed, 'time_calls', timed)
    figures = tracker_speed._timed(step, 4)
    assert calls == [0, 1, 2, 3]
    assert figures['median_ms'] == pytest.approx(2.0)
    assert figures['samples'] == 3
    assert figures['tracked'] == pytest.approx(2 / 3)


def test_learner_exponents_are_the_slopes_of_log_time_against_log_meshes(monkeypatch):
    sizes = []

    def row(population, subjects, meshes, learners, rng):
        sizes.append((subjects, meshes))
        times = {'align_s': 2e-4 * meshes, 'seed_s': 1e-8 * meshes**2, 'joint_s': meshes**0.5}
        return {'meshes': meshes, 'subjects': subjects, **times}

    monkeypatch.setattr(learner_scaling, 'FacePopulation', lambda seed: None)
    monkeypatch.setattr(learner_scaling, '_timed_row', row)
    result = learner_scaling.run(BenchOptions())
    assert result['meshes_exponent'] == pytest.approx(
        {'align_s': 1.0, 'seed_s': 2.0, 'joint_s': 0.5}
    )
    by_meshes = [(10, m) for m in (10**3, 10**4, 10**5, 10**6)]
    assert sizes == by_meshes + [(s, 20_000) for s in (5, 10, 20, 50)]
    assert [r['meshes'] for r in result['meshes']] == [m for _, m in by_meshes]
    assert [r['subjects'] for r in result['subjects']] == [5, 10, 20, 50]


class _FakeNode:
    """A node process that is never started."""

    def __init__(self, *args):
        self.stopped = False
        self._cpu_seconds = iter([12.0, 12.006])  # before and after the timed 30-Hz run

    def cpu_seconds(self):
        return next(self._cpu_seconds)

    def peak_rss_mb(self):
        return 250.0

    def cores(self):
        return [0]

    def stop(self):
        self.stopped = True
        return 0


class _FakeDriver:
    """A driver whose runs drop frames from ``drops_from`` Hz on."""

    def __init__(self, drops_from):
        self.drops_from = drops_from
        self.runs = []

    def __call__(self, streams):
        return self

    def wait_for(self, nodes):
        pass

    def run(self, rate_hz, seconds):
        self.runs.append((rate_hz, seconds))
        received = 3 if rate_hz < self.drops_from else 2
        return _run(rate_hz, 3, (1.0, 2.0, 3.0)[:received], received, seconds)

    def close(self):
        pass


@pytest.mark.parametrize(
    ('drops_from', 'stepped', 'highest'),
    [
        (45.0, [10.0, 15.0, 20.0, 30.0, 45.0], 30.0),  # stops at the first step with drops
        (10.0, [10.0], 0.0),
        (1000.0, [10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0, 120.0], 120.0),
    ],
)
def test_live_latency_finds_the_highest_rate_without_drops(
    monkeypatch, tmp_path, drops_from, stepped, highest
):
    driver = _FakeDriver(drops_from)
    saved = os.sched_getaffinity(0)
    monkeypatch.setattr(live_latency, 'pin_to_core', lambda core: os.sched_setaffinity(0, {1}))
    monkeypatch.setattr(live_latency, 'tracker_inputs', lambda *args: ([], {}))
    started = []
    monkeypatch.setattr(
        live_latency, 'NodeProcess', lambda node, *_: started.append(node) or _FakeNode()
    )
    monkeypatch.setattr(live_latency, 'Driver', driver)

    if 1 not in saved:
        pytest.skip('core 1 is not available here')
    try:
        result = live_latency.run(BenchOptions(work_dir=tmp_path))
    finally:
        os.sched_setaffinity(0, saved)

    assert list(result) == ['mono', 'stereo']
    assert started == ['mono_tracker', 'stereo_tracker']
    runs = [(30.0, 1.0), (30.0, 60.0)] + [(rate, 4.0) for rate in stepped]  # warm-up, timed, steps
    assert driver.runs == runs * 2
    for kind in ('mono', 'stereo'):
        figures = result[kind]
        assert figures['max_rate_without_drops_hz'] == highest
        assert figures['at_30hz']['seconds'] == 60.0
        assert figures['at_30hz']['dropped'] == (0 if drops_from > 30.0 else 1)
        assert [step['rate_hz'] for step in figures['rate_steps']] == stepped
        assert figures['node_peak_rss_mb'] == 250.0
        received = figures['at_30hz']['received']  # 6 ms of CPU over the timed run
        assert figures['node_cpu_ms_per_frame'] == pytest.approx(6.0 / received)
        assert figures['cores'] == {'node': [0], 'driver': [1]}  # the driver's: this process's
        assert figures['stream_frames'] == 1830


def test_replay_throughput_is_frames_per_second_and_multiple_of_real_time(monkeypatch, tmp_path):
    # mono replay 2 s and command 4 s, stereo replay 3 s and command 5 s
    clock = iter([0.0, 2.0, 2.0, 6.0, 10.0, 13.0, 13.0, 18.0])
    inputs = {'image': 600, 'left/image_raw': 300, 'right/image_raw': 300}
    stats = SimpleNamespace(inputs=inputs, outputs={'face/state': 590}, errors={})
    monkeypatch.setattr(
        replay_throughput, 'time', SimpleNamespace(perf_counter=lambda: next(clock))
    )
    commands = []
    monkeypatch.setattr(
        replay_throughput,
        'subprocess',
        SimpleNamespace(run=lambda command, **_: commands.append(command) or _exited(0)),
    )
    models = []
    monkeypatch.setattr(
        replay_throughput, 'model_file', lambda *args: models.append(args) or tmp_path / 'model'
    )
    monkeypatch.setattr(replay_throughput, 'recorded_bag', lambda *args: (tmp_path, tmp_path))
    monkeypatch.setattr(replay_throughput, 'replay_bag', lambda *args, **kwargs: stats)

    result = replay_throughput.run(BenchOptions(work_dir=tmp_path, seed=3))

    assert models == [(tmp_path, 34, 3)]  # the 34-node model

    assert result['mono'].pop('input_errors') == {}
    assert result['mono'] == pytest.approx(
        {
            'size': '640x480',
            'frames': 600,
            'seconds': 2.0,
            'frames_per_s': 300.0,
            'x_real_time': 10.0,
            'command_seconds': 4.0,
            'command_x_real_time': 5.0,
            'states': 590,
        }
    )
    assert result['stereo']['frames_per_s'] == pytest.approx(100.0)
    assert result['stereo']['x_real_time'] == pytest.approx(10.0 / 3.0)
    assert result['stereo']['command_x_real_time'] == pytest.approx(2.0)
    assert [command[3:6] for command in commands] == [
        ['replay', 'mono_tracker', str(tmp_path)],
        ['replay', 'stereo_tracker', str(tmp_path)],
    ]
    assert commands[0][6:] == [
        '--out', str(tmp_path / 'replay_mono_command'), '--quiet',
        f'--param=model_file={tmp_path / "model"}', f'--param=init_file={tmp_path}',
    ]  # fmt: skip


def _exited(status: int) -> SimpleNamespace:
    """A finished subprocess.run with ``status`` and a standard error."""
    return SimpleNamespace(returncode=status, stderr='loading\nBagError: no such bag\n')


def test_a_failed_replay_command_names_its_node_status_and_error(monkeypatch, tmp_path):
    stats = SimpleNamespace(inputs={'image': 10}, outputs={'face/state': 10}, errors={})
    monkeypatch.setattr(replay_throughput, 'model_file', lambda *args: tmp_path / 'model')
    monkeypatch.setattr(replay_throughput, 'recorded_bag', lambda *args: (tmp_path, tmp_path))
    monkeypatch.setattr(replay_throughput, 'replay_bag', lambda *args, **kwargs: stats)
    monkeypatch.setattr(
        replay_throughput, 'subprocess', SimpleNamespace(run=lambda *_, **__: _exited(2))
    )
    expected = 'face-tracking replay mono_tracker exited with status 2: loading | BagError'
    with pytest.raises(RuntimeError, match=expected):
        replay_throughput.run(BenchOptions(work_dir=tmp_path, seed=3))


def test_soak_growth_is_from_the_first_window_after_warm_up_and_the_trend_a_slope():
    # p50 5, 6, 7 ms at 1/6, 7/6, 13/6 min: 1 ms/min; RSS 103 MB after warm-up, 104.5 at the end.
    windows = [
        (10.0, 100.0, _run(published=4, latency=(5.0,), tracked=1)),
        (70.0, 103.0, _run(published=4, latency=(6.0, 6.0), tracked=2)),
        (130.0, 104.5, _run(published=4, latency=(7.0, 7.0, 7.0), tracked=3)),
    ]
    summary = soak._summary(windows, 5, {'tracker': 300.0, 'recorder': 80.0}, 2.5)
    assert summary['rss_growth_mb'] == pytest.approx(1.5)
    assert summary['latency_p50_slope_ms_per_min'] == pytest.approx(1.0)
    assert (summary['published'], summary['received'], summary['recorded']) == (12, 6, 5)
    assert summary['recorder_missing'] == 1
    assert [w['dropped'] for w in summary['windows']] == [3, 2, 1]
    assert [w['t_s'] for w in summary['windows']] == [10.0, 70.0, 130.0]
    assert (summary['tracker_peak_rss_mb'], summary['recorder_peak_rss_mb']) == (300.0, 80.0)


def test_a_soak_shorter_than_its_warm_up_has_no_growth_and_one_window_no_trend():
    """Not measured is NaN (null in the JSON, 'not measured' in the table), never 0."""
    windows = [(10.0, 100.0, _run()), (20.0, 101.0, _run(latency=(5.0,), tracked=1))]
    two = soak._summary(windows, 4, {'tracker': 1.0, 'recorder': 1.0}, 0.5)
    # p50 4 then 5 ms, 10 s apart: 6 ms/min.
    assert math.isnan(two['rss_growth_mb'])
    assert two['latency_p50_slope_ms_per_min'] == pytest.approx(6.0)
    one = soak._summary(windows[:1], 3, {'tracker': 1.0, 'recorder': 1.0}, 0.5)
    assert math.isnan(one['rss_growth_mb']) and math.isnan(one['latency_p50_slope_ms_per_min'])
    # One window after the warm-up: growth from it to itself is no measurement either.
    late = soak._summary([*windows, (70.0, 103.0, _run())], 4, {'tracker': 1, 'recorder': 1}, 1)
    assert math.isnan(late['rss_growth_mb'])


def test_the_table_says_a_soak_figure_was_not_measured():
    figures = {'minutes': 0.5, 'recorder_missing': 0, 'received': 15}
    for missing in (float('nan'), None):  # as measured, and as read back from the JSON
        row = bench_cli._soak_rows(
            {**figures, 'rss_growth_mb': missing, 'latency_p50_slope_ms_per_min': missing}
        )[0]
        assert row[1] == (
            'RSS growth not measured (shorter than its warm-up), latency p50 trend not '
            'measured, recorder missed 0 of 15'
        )
    row = bench_cli._soak_rows(
        {**figures, 'rss_growth_mb': 1.25, 'latency_p50_slope_ms_per_min': -0.5}
    )[0]
    assert row[1] == 'RSS growth +1.2 MB, latency p50 trend -0.50 ms/min, recorder missed 0 of 15'


def test_mono_accuracy_means_every_number_over_seeds_per_axis():
    per_seed = [
        {'frames': 20, 'rotation_mae_deg': [1.0, 2.0, 3.0], 'name': 'a', 'ok': True},
        {'frames': 10, 'rotation_mae_deg': [3.0, 4.0, 8.0], 'name': 'b', 'ok': False},
    ]
    assert mono_accuracy._mean(per_seed) == {
        'frames': 15.0,
        'rotation_mae_deg': [2.0, 3.0, 5.5],
    }
    assert mono_accuracy._mean(per_seed[:1]) == {'frames': 20.0, 'rotation_mae_deg': [1, 2, 3]}


def test_stereo_pooling_takes_rms_of_rms_figures_and_extremes_of_the_others():
    def evaluation(node, group, by_node, reprojection, drift, max_drift, slip, tracked):
        return SimpleNamespace(
            node_rms=node,
            node_rms_by_group={'eyes': group},
            node_rms_by_node={'nose': by_node},
            max_reprojection=reprojection,
            drift=drift,
            max_drift=max_drift,
            boundary_slip=slip,
            tracked_fraction=tracked,
        )

    pooled = stereo_accuracy._pooled(
        [
            evaluation(0.001, 0.002, 0.003, 1.5, 0.003, 0.002, 0.0015, 1.0),
            evaluation(0.007, 0.014, 0.004, 0.5, 0.004, 0.009, 0.0005, 0.9),
        ]
    )
    # RMS: sqrt((1 + 49) / 2) = 5, sqrt((4 + 196) / 2) = 10, sqrt((9 + 16) / 2) mm.
    assert pooled.pop('node_rms_by_group_mm') == pytest.approx({'eyes': 10.0})
    assert pooled.pop('node_rms_by_node_mm') == pytest.approx({'nose': math.sqrt(12.5)})
    assert pooled == pytest.approx(
        {
            'node_rms_mm': 5.0,
            'max_reprojection_px': 1.5,
            'drift_mm': math.sqrt(12.5),
            'max_drift_mm': 9.0,
            'boundary_slip_mm': 1.5,
            'tracked_fraction': 0.9,
        }
    )
    one = stereo_accuracy._pooled([evaluation(0.001, 0.002, 0.003, 1.5, 0.003, 0.002, 0.0, 1.0)])
    assert (one['node_rms_mm'], one['node_rms_by_node_mm']) == (1.0, {'nose': 3.0})


def test_runner_gives_a_child_its_options_and_reads_its_part(monkeypatch, tmp_path):
    commands = []

    def child(command, **kwargs):
        commands.append(command)
        part = command[command.index('--part') + 1]
        with open(part, 'w') as file:
            json.dump({'figure': 1.5}, file)
        return SimpleNamespace(returncode=0, stderr='')

    monkeypatch.setattr(runner.subprocess, 'run', child)
    monkeypatch.setattr(runner, 'machine', lambda: {'nproc': 1})
    clock = iter([0.0, 2.5, 10.0, 70.0])  # memory 2.5 s, soak 60 s
    monkeypatch.setattr(runner, 'time', SimpleNamespace(perf_counter=lambda: next(clock)))
    options = BenchOptions(True, tmp_path, 2.0, 9, 4, Cores(3, 5))
    results = runner.run_benchmarks(['memory', 'soak'], options)
    assert results['benchmarks'] == {'memory': {'figure': 1.5}, 'soak': {'figure': 1.5}}
    assert results['seconds'] == {'memory': 2.5, 'soak': 60.0}
    assert results['quick'] is True
    assert results['cores'] == {'bench': 3, 'driver': 5}
    assert commands[1][3:] == [
        'soak',
        '--part',
        str(tmp_path / 'soak.json'),
        '--work-dir',
        str(tmp_path),
        '--minutes',
        '2.0',
        '--domain-id',
        '9',
        '--seed',
        '4',
        '--bench-core',
        '3',
        '--driver-core',
        '5',
        '--quick',
    ]


def test_the_machine_is_described_by_its_cores_and_ram(monkeypatch):
    saved = os.sched_getaffinity(0)
    sizes = {'SC_PHYS_PAGES': 4_194_304, 'SC_PAGE_SIZE': 4096}  # 16 GiB
    monkeypatch.setattr(runner.os, 'sysconf', sizes.__getitem__)
    cpuinfo = 'processor\t: 0\nmodel name\t: Chip X: 8 cores @ 2.0GHz\n'
    monkeypatch.setattr(
        runner,
        'Path',
        lambda path: SimpleNamespace(is_file=lambda: True, read_text=lambda: cpuinfo),
    )
    try:
        os.sched_setaffinity(0, {min(saved)})
        machine = runner.machine()
    finally:
        os.sched_setaffinity(0, saved)
    assert (machine['nproc'], machine['ram_gb'], machine['measured_on_cores']) == (1, 16.0, 1)
    assert machine['cpu_model'] == 'Chip X: 8 cores @ 2.0GHz'


def test_runner_records_why_a_child_failed(monkeypatch, tmp_path):
    timeouts = []

    def timed_out(command, timeout, **kwargs):
        timeouts.append(timeout)
        raise subprocess.TimeoutExpired(command, timeout)

    monkeypatch.setattr(runner.subprocess, 'run', timed_out)
    options = BenchOptions(work_dir=tmp_path, minutes=1.5)
    assert runner._run_child('soak', options) == {'failed': 'timed out after 990 s'}
    assert runner._run_child('memory', options) == {'failed': 'timed out after 900 s'}
    stderr = '\n'.join(f'line {k}' for k in range(10)) + '\n'
    failed = SimpleNamespace(returncode=3, stderr=stderr)
    monkeypatch.setattr(runner.subprocess, 'run', lambda command, **kwargs: failed)
    tail = ' | '.join(f'line {k}' for k in range(2, 10))
    assert runner._run_child('memory', options) == {'failed': f'exit status 3: {tail}'}
    quiet = SimpleNamespace(returncode=0, stderr='wrote nothing\n')  # and no part file
    monkeypatch.setattr(runner.subprocess, 'run', lambda command, **kwargs: quiet)
    assert runner._run_child('memory', options) == {'failed': 'exit status 0: wrote nothing'}


def test_table_shows_speed_ratios_replay_memory_and_soak():
    figures = {'median_ms': 1.25, 'p99_ms': 2.5}
    speed = {
        '640x480': {
            '34_nodes': {'mono': figures, 'mono_over_baseline': 1.44},
            'rectification': {'median_ms': 0.5, 'p99_ms': 0.75},
        },
        '320x240': {'19_nodes': {'stereo': figures}},
    }
    replay = {'mono': {'size': '640x480', 'frames_per_s': 300.0, 'x_real_time': 10.0}}
    replay['mono'] |= {'frames': 900, 'command_seconds': 3.5, 'command_x_real_time': 8.57}
    soak_figures = {'minutes': 30.0, 'rss_growth_mb': 1.5, 'latency_p50_slope_ms_per_min': -0.25}
    soak_figures |= {'recorder_missing': 1, 'received': 54000}
    memory = {'mono_tracker': {'peak_rss_mb': 180.4}, 'learner': {'skipped': 'no | data'}}
    benchmarks = {'tracker_speed': speed, 'replay_throughput': replay, 'soak': soak_figures}
    table = format_table({'benchmarks': benchmarks | {'memory': memory}}).splitlines()
    assert table[2:] == [
        '| mono step, 640x480, 34 nodes | 1.2 ms median, 2.5 ms p99 | <= 2 ms |',
        '| mono / baseline time, 640x480, 34 nodes | 1.4x |  |',
        '| rectification of a raw image (distortion, R), 640x480 | 0.50 ms median, '
        '0.75 ms p99 |  |',
        '| stereo step, 320x240, 19 nodes | 1.2 ms median, 2.5 ms p99 |  |',
        '| offline replay, mono, 640x480 | 300.0 frames/s = 10.00x real time (30 fps) | >= 30x |',
        '| face-tracking replay command from launch, mono, 640x480 | 900 frames in 3.50 s = '
        '8.57x real time (30 fps) |  |',
        '| peak RSS, mono_tracker | 180 MB |  |',
        '| peak RSS, learner | skipped: no / data |  |',
        '| soak, 30 min at 30 Hz | RSS growth +1.5 MB, latency p50 trend -0.25 ms/min, '
        'recorder missed 1 of 54000 | < 5 MB, no growth, none missed |',
    ]


class _MemoryNode:
    """A node process that is never started: alive for ``lives`` polls, with a peak RSS."""

    def __init__(self, name, lives=10**6):
        self.name, self.lives, self.stopped = name, lives, False

    def alive(self):
        self.lives -= 1
        return self.lives >= 0

    def peak_rss_mb(self):
        return 321.0

    def tail(self, lines):
        return f'last {lines} lines'

    def stop(self):
        self.stopped = True


def test_a_node_runs_until_done_then_its_peak_rss_is_read(monkeypatch, tmp_path):
    now = [0.0]
    sleep = lambda seconds: now.__setitem__(0, now[0] + seconds)  # noqa: E731
    monkeypatch.setattr(memory, 'time', SimpleNamespace(monotonic=lambda: now[0], sleep=sleep))
    options = BenchOptions(work_dir=tmp_path)
    for lives, done_after, expected in [
        (10**6, 3.0, {'peak_rss_mb': 321.0, 'run': 'learning'}),
        (2, 3.0, {'failed': 'exited early: last 2 lines'}),
        (10**6, 601.0, {'failed': 'not done after 600 s: last 2 lines'}),
    ]:
        node = _MemoryNode('learner', lives)
        monkeypatch.setattr(memory, 'NodeProcess', lambda *args, node=node: node)
        now[0] = 0.0
        done = lambda after=done_after: now[0] >= after  # noqa: E731
        assert memory._peak_until('learner', {}, done, options, 'learning') == expected
        assert node.stopped
        assert now[0] == pytest.approx(min(done_after, 600.2 if lives > 2 else 0.4), abs=0.01)


def test_nodes_that_die_at_start_up_are_reported_and_left_out():
    nodes = [_MemoryNode('mono_tracker'), _MemoryNode('recorder', 0), _MemoryNode('rgbd', 0)]
    waits = []

    def wait_for(running):
        waits.append([node.name for node in running])
        if len(waits) == 1:
            raise memory.ConfigError('did not connect')

    results = {}
    driver = SimpleNamespace(wait_for=wait_for)
    assert memory._connected(driver, nodes, results) == nodes[:1]
    assert waits == [['mono_tracker', 'recorder', 'rgbd'], ['mono_tracker']]
    failed = {'failed': 'exited at start-up: last 2 lines'}
    assert results == {'recorder': failed, 'rgbd': failed}

    def never(running):
        raise memory.ConfigError('did not connect')

    with pytest.raises(memory.ConfigError, match='did not connect'):  # all alive: a real failure
        memory._connected(SimpleNamespace(wait_for=never), [_MemoryNode('mono_tracker')], {})


def test_memory_reads_the_peak_rss_of_the_nodes_that_run(monkeypatch, tmp_path):
    def node_process(name, params, domain_id, log):
        if name == 'rgbd':
            raise memory.ConfigError('rgbd is not installed')
        return _MemoryNode(name, 0 if name == 'recorder' else 10**6)

    def wait_for(nodes):
        if len(nodes) > 1:
            raise memory.ConfigError('did not connect')

    driver = _FakeDriver(1000.0)
    driver.wait_for = wait_for
    monkeypatch.setattr(memory, 'NodeProcess', node_process)
    monkeypatch.setattr(memory, 'Driver', lambda streams, name: driver)
    nodes = {'mono_tracker': {}, 'recorder': {}, 'rgbd': {}}
    results = memory._measure(nodes, [], 30.0, 2.0, BenchOptions(work_dir=tmp_path), 'at 30 Hz')
    assert results == {
        'rgbd': {'skipped': 'rgbd is not installed'},
        'recorder': {'failed': 'exited at start-up: last 2 lines'},
        'mono_tracker': {'peak_rss_mb': 321.0, 'run': 'at 30 Hz'},
    }
    assert driver.runs == [(30.0, 2.0)]
    monkeypatch.setattr(memory, 'NodeProcess', lambda *args: node_process('rgbd', *args[1:]))
    assert memory._peak_until('rgbd', {}, lambda: True, BenchOptions(), '') == {
        'skipped': 'rgbd is not installed'
    }


def test_time_calls_times_each_call_in_order(monkeypatch):
    clock, ran = iter([1.0, 1.5, 2.0, 3.5]), []
    monkeypatch.setattr(common, 'time', SimpleNamespace(perf_counter=lambda: next(clock)))
    assert common.time_calls([lambda: ran.append('a'), lambda: ran.append('b')]) == [0.5, 1.5]
    assert ran == ['a', 'b']


def test_table_shows_click_draws_and_the_learned_models_similarities():
    mean = {'rotation_mae_deg': [1.0, 2.0, 0.25], 'translation_mae_mm': [3.0, 4.0, 5.0]}
    mean |= {'alpha_rms_percent': None, 'drift_deg': -0.5, 'lost': 0.0}
    rows = {
        name: {'mean': mean, 'seeds': [{}, {}], 'click_draws': draws}
        for name, draws in (('true_model_click_draws', 2), ('unfiltered', 1))
    }
    learned = {
        'true': {'shape_similarity': 0.9991, 'action_similarity': 0.99},
        'exact_clicks': {'shape_similarity': 0.98, 'action_similarity': 0.9},
    }
    benchmarks = {'mono_accuracy': {'rows': rows}}
    benchmarks['stereo_accuracy'] = {'learning': {'34_nodes': learned}}
    table = format_table({'benchmarks': benchmarks}).splitlines()
    figures = 'rotation MAE 1.00 / 2.00 / 0.25 deg, t MAE 3.0 / 4.0 / 5.0 mm, alpha n/a, '
    figures += 'drift -0.50 deg, lost 0'
    assert [row.split(' | ')[:2] for row in table[2:]] == [
        ['| mono protocol, true model click draws (mean of 2 seeds x 2 click draws)', figures],
        ['| mono protocol, unfiltered (mean of 2 seeds)', figures],
        [
            '| stereo protocol, 34 nodes: model learned from true / exact clicks meshes',
            'S vs true identity 0.999 / 0.980, A vs true expressions 0.990 / 0.900',
        ],
    ]
