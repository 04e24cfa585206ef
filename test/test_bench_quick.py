"""`face-tracking bench --quick`: a smoke run of the runner, a tracker, the learner and DDS.

Runs tracker_speed, learner_scaling, live_latency, mono_accuracy and stereo_accuracy at their
quick sizes (each in its own pinned process, live over loopback DDS) and checks the JSON: every
benchmark present, none failed, the headline figures there, and every number finite (NaN is
written as null and only allowed where a figure does not apply). Timings are never asserted.
The other benchmarks (replay, memory, accuracy, soak) run in `face-tracking bench` only (they
take minutes).
"""

from __future__ import annotations

import json
import os
import re

import pytest

from face_tracking_ros.bench import runner
from face_tracking_ros.bench.common import BenchOptions, Cores, pin_to_core
from face_tracking_ros.bench.runner import run_benchmarks
from face_tracking_ros.cli import bench
from face_tracking_ros.cli.bench import format_table
from face_tracking_ros.cli.main import main
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import finite_or_null

QUICK = ('tracker_speed', 'learner_scaling', 'live_latency', 'mono_accuracy', 'stereo_accuracy')


def _leaves(value, path=''):
    """Every (path, leaf) of a JSON value."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, f'{path}/{key}')
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _leaves(item, f'{path}/{index}')
    else:
        yield path, value


def _not_applicable(path: str) -> bool:
    """Whether a figure is NaN (null) by definition in a quick run.

    Alpha's error relative to its range (20 frames show no expression) and the face-edge slip of
    a mesh without face edge are.
    """
    if path.startswith('/benchmarks/mono_accuracy/rows/'):
        return path.endswith('/alpha_rms_percent')
    if path.startswith('/benchmarks/stereo_accuracy/runs/') and '19' in path.split('/')[4]:
        return path.rsplit('/', 1)[1] in {'boundary_slip_mm', 'boundary_slip_rms_mm'}
    return False


# About 100 s alone; under `make test` its pinned benchmark processes share the cores with the
# other test process, which can take it past the suite's 300-s time-out.
@pytest.mark.timeout(900)
def test_quick_run_writes_finite_figures(tmp_path):
    out = tmp_path / 'results.json'  # (live runs on conftest's ROS_DOMAIN_ID)
    status = main(
        ['bench', '--quick', '--out', str(tmp_path), '--json', str(out), '--only', *QUICK]
    )
    failed = tmp_path / 'results.failed.json'  # (where a run with a failure writes)
    assert status == 0, json.loads(failed.read_text())['benchmarks']
    results = json.loads(out.read_text())
    assert set(results['benchmarks']) == set(QUICK)
    assert results['machine']['nproc'] == len(os.sched_getaffinity(0))
    speed = results['benchmarks']['tracker_speed']['320x240']
    for nodes in ('19_nodes', '34_nodes'):
        for tracker in ('mono', 'stereo', 'baseline'):
            assert speed[nodes][tracker]['samples'] >= 1
            assert speed[nodes][tracker]['p99_ms'] >= speed[nodes][tracker]['median_ms'] > 0
        assert speed[nodes]['mono_over_baseline'] > 0
        assert speed[nodes]['stereo_over_baseline'] > 0
    assert speed['rectification']['p99_ms'] >= speed['rectification']['median_ms'] > 0
    learner = results['benchmarks']['learner_scaling']
    assert [row['meshes'] for row in learner['meshes']] == [1000, 10000]
    assert set(learner['meshes_exponent']) == {'align_s', 'seed_s', 'joint_s'}
    for kind in ('mono', 'stereo'):
        live = results['benchmarks']['live_latency'][kind]
        assert live['at_30hz']['published'] == 150, kind
        assert 0 < live['at_30hz']['received'] == live['at_30hz']['tracked'], kind  # all TRACKING
        assert live['node_peak_rss_mb'] > 0
        cores = sorted(os.sched_getaffinity(0))
        if len(cores) > 1:  # the node on the benchmark's core, the driver on another
            assert len(live['cores']['node']) == len(live['cores']['driver']) == 1
            assert live['cores']['node'] != live['cores']['driver']
    protocol = results['benchmarks']['mono_accuracy']
    rows = ('true_model', 'unfiltered', 'learned_model', 'baseline', 'nodes_19')
    rows += ('epsilon_0', 'prior_off', 'bundle_off', 'true_model_click_draws')
    rows += ('photo_texture', 'photo_baseline', 'realistic_true_model', 'realistic_packaged_model')
    rows += ('motion_blur', 'jpeg_quality_95', 'jpeg_quality_75')
    rows += ('small_face',)
    assert set(protocol['rows']) == set(rows)
    for row in rows:
        assert len(protocol['rows'][row]['seeds']) == 1
        assert protocol['rows'][row]['mean']['frames'] == 20
        assert protocol['rows'][row]['mean']['tracked'] == 20
    # Measured: 1.04 / 1.82 / 0.19 degrees over the 20 frames.
    assert max(protocol['rows']['true_model']['mean']['rotation_mae_deg']) < 2.5
    assert len(protocol['still']['mean']['angle_std_deg']) == 3
    assert len(protocol['still']['mean']['angle_std_unfiltered_deg']) == 3
    stereo = results['benchmarks']['stereo_accuracy']
    runs = ('exact_clicks', 'clicks_1px', 'nodes_19', 'realistic_exact_clicks')
    recorded = ('nodes_19_rig_fault_corrected', 'nodes_19_rig_fault_uncorrected')
    recorded += ('exact_clicks_jpeg_95', 'nodes_19_jpeg_95', 'nodes_19_jpeg_75')
    runs += ('realistic_nodes_19', 'half_size_exact_clicks', 'half_size_nodes_19')
    for run in (*runs, *recorded):
        assert len(stereo['runs'][run]['subjects']) == 3
        pooled = stereo['runs'][run]['pooled']
        assert pooled['tracked_fraction'] == 1.0
        # Measured on the 12-frame smoke sequences: 3.3 / 4.2 mm (2.2 / 3.4 on 380 frames).
        assert 0.5 < pooled['node_rms_mm'] < 8.0
    assert set(stereo['learning']['34_nodes']) == {'true', 'exact_clicks', 'clicks_1px'}
    assert set(stereo['learning']['19_nodes']) == {'true', 'exact_clicks'}
    for prefix in ('realistic', 'half_size'):
        for size in (f'{prefix}_34_nodes', f'{prefix}_19_nodes'):
            assert set(stereo['learning'][size]) == {'true', 'exact_clicks'}
    leaves = list(_leaves(results))
    nulls = [path for path, value in leaves if value is None]  # NaN and infinities
    assert nulls == [path for path, _ in leaves if _not_applicable(path)]
    assert '/benchmarks/stereo_accuracy/runs/nodes_19/pooled/boundary_slip_mm' in nulls
    assert sum(isinstance(value, int | float) for _, value in leaves) > 50


def test_pin_to_core_moves_a_pinned_process_to_another_core():
    """The runner pins a benchmark to one core; a live one then moves its driver to another."""
    saved = os.sched_getaffinity(0)
    if len(saved) < 2:
        pytest.skip('one core here')
    cores = Cores.of()
    try:
        assert pin_to_core(cores.bench) == cores.bench
        assert pin_to_core(cores.driver) == cores.driver
        assert os.sched_getaffinity(0) == {cores.driver}
        assert pin_to_core(4095) == cores.driver  # no such core: the lowest of the affinity
        os.sched_setaffinity(0, saved)
        assert pin_to_core(4095) == min(saved)
        assert os.sched_getaffinity(0) == {min(saved)}  # this process's, not another's
    finally:
        os.sched_setaffinity(0, saved)


@pytest.mark.parametrize(
    ('affinity', 'bench', 'driver'),
    [({0, 1}, 0, 1), ({3, 1, 7}, 1, 3), ({5}, 5, 5)],  # one core both measures and drives
)
def test_benchmarks_run_on_the_lowest_cores_they_are_given(affinity, bench, driver):
    assert Cores.of(affinity) == Cores(bench, driver)


def test_benchmark_options_take_their_cores_from_the_affinity_the_command_started_with():
    """`taskset -c 1 face-tracking bench` measures on core 1, not on core 0."""
    saved = os.sched_getaffinity(0)
    highest = max(saved)
    try:
        os.sched_setaffinity(0, {highest})
        assert BenchOptions().cores == Cores(highest, highest)
    finally:
        os.sched_setaffinity(0, saved)


@pytest.mark.parametrize(
    ('arguments', 'message'),
    [
        (
            ['--minutes', 'nan'],
            r'--minutes must be a finite number > 0 \(the soak duration\), got nan',
        ),
        (['--minutes', 'inf'], r'--minutes must be a finite number > 0 .*, got inf'),
        (['--minutes', '0'], r'--minutes must be a finite number > 0 .*, got 0.0'),
        (['--domain-id', '-1'], r'--domain-id must be in \[0, 232\] .*, got -1'),
        (['--domain-id', '233'], r'--domain-id must be in \[0, 232\] .*, got 233'),
        (['--seed', '-1'], r'--seed must be >= 0, got -1'),
        (['--json', '.'], r'--json \. is a directory, not a file'),
    ],
)
def test_bad_options_are_refused_before_any_benchmark_runs(
    tmp_path, capsys, monkeypatch, arguments, message
):
    ran = []
    monkeypatch.setattr(
        bench, 'run_benchmarks', lambda names, options: ran.append(names) or {'benchmarks': {}}
    )
    monkeypatch.chdir(tmp_path)

    status = main(['bench', '--out', str(tmp_path), '--only', 'soak', *arguments])

    assert status == 2
    assert re.fullmatch(f'error: {message}\n', capsys.readouterr().err)
    assert not ran
    assert list(tmp_path.iterdir()) == []


def test_the_live_runs_are_on_the_environments_ros_domain_unless_given(
    tmp_path, capsys, monkeypatch
):
    """--domain-id defaults to ROS_DOMAIN_ID when set (it was always 70), else to 70."""
    domains = []
    monkeypatch.setattr(
        bench,
        'run_benchmarks',
        lambda names, options: domains.append(options.domain_id) or {'benchmarks': {}},
    )
    argv = ['bench', '--out', str(tmp_path), '--only', 'soak']
    for environment, more, domain in [
        ('76', [], 76),
        ('76', ['--domain-id', '5'], 5),
        ('', [], 70),
        (None, [], 70),
    ]:
        monkeypatch.delenv('ROS_DOMAIN_ID', raising=False)
        if environment is not None:
            monkeypatch.setenv('ROS_DOMAIN_ID', environment)
        assert main([*argv, *more]) == 0
        assert domains.pop() == domain, (environment, more)
    for environment, message in [
        ('233', 'ROS_DOMAIN_ID (the default of --domain-id) must be in [0, 232] (a '),
        ('seven', "ROS_DOMAIN_ID (the default of --domain-id) must be an integer, got 'seven'"),
    ]:
        monkeypatch.setenv('ROS_DOMAIN_ID', environment)
        assert main(argv) == 2
        assert capsys.readouterr().err.startswith(f'error: {message}')
    assert not domains


def test_a_run_with_a_failed_benchmark_keeps_the_earlier_results(tmp_path, capsys, monkeypatch):
    parts = {'tracker_speed': {}, 'memory': {'failed': 'exit status 1: MemoryError'}}
    monkeypatch.setattr(runner, '_run_child', lambda name, options: parts[name])
    results = tmp_path / 'bench' / 'results.json'
    results.parent.mkdir()
    results.write_text('{"benchmarks": "of an earlier run"}')
    argv = ['bench', '--out', str(tmp_path), '--only', 'tracker_speed', 'memory']

    status = main(argv)

    assert status == 1
    assert results.read_text() == '{"benchmarks": "of an earlier run"}'
    failed = results.with_name('results.failed.json')
    assert json.loads(failed.read_text())['benchmarks'] == parts
    printed = capsys.readouterr().out
    assert f'results: {failed} ({results} not replaced)\n' in printed
    assert 'memory failed: exit status 1: MemoryError' in printed
    # A run without failures replaces them.
    parts['memory'] = {}
    assert main(argv) == 0
    assert json.loads(results.read_text())['benchmarks'] == parts
    assert f'results: {results}\n' in capsys.readouterr().out


def test_the_command_says_which_cores_measured_and_drove(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(runner, '_run_child', lambda name, options: {})
    saved = os.sched_getaffinity(0)
    argv = ['bench', '--out', str(tmp_path), '--only', 'tracker_speed']
    try:
        os.sched_setaffinity(0, {max(saved)})  # as under `taskset -c N`
        assert main(argv) == 0
    finally:
        os.sched_setaffinity(0, saved)
    core = max(saved)
    printed = capsys.readouterr().out
    assert f'measured on core {core}, live drivers on core {core} (one core: ' in printed
    assert json.loads((tmp_path / 'bench' / 'results.json').read_text())['cores'] == {
        'bench': core,
        'driver': core,
    }


def test_unknown_benchmark_is_refused(tmp_path):
    with pytest.raises(ConfigError, match='unknown benchmark nope; choose from '):
        run_benchmarks(['nope'], BenchOptions(work_dir=tmp_path))


def test_nan_and_infinity_become_null():
    assert finite_or_null({'a': [1.0, float('nan')], 'b': (float('inf'), 2)}) == {
        'a': [1.0, None],
        'b': [None, 2],
    }


def test_table_says_so_when_no_state_came_back():
    # A node that never answers leaves no latency to print, only the drops.
    run = {'seconds': 60.0, 'published': 1800, 'received': 0, 'dropped': 1800}
    run |= {'latency_p50_ms': None, 'latency_p99_ms': None}
    live = {'size': '640x480', 'at_30hz': run, 'max_rate_without_drops_hz': 0.0}
    table = format_table({'benchmarks': {'live_latency': {'stereo': live}}})
    row = '| live latency image -> face/state, stereo, 640x480 at 30 Hz, 60 s | '
    assert f'{row}no face/state received, 1800 of 1800 dropped |' in table


def test_table_gives_the_live_node_cpu_per_frame():
    run = {'seconds': 60.0, 'published': 1800, 'received': 1800, 'dropped': 0}
    run |= {'latency_p50_ms': 5.84, 'latency_p99_ms': 9.06}
    live = {'size': '640x480', 'at_30hz': run, 'max_rate_without_drops_hz': 120.0}
    live['node_cpu_ms_per_frame'] = 5.27
    table = format_table({'benchmarks': {'live_latency': {'stereo': live}}})
    row = '| live latency image -> face/state, stereo, 640x480 at 30 Hz, 60 s | '
    latency = '5.8 ms p50, 9.1 ms p99, 0 of 1800 dropped, node CPU 5.3 ms a frame |'
    assert f'{row}{latency}' in table


def test_table_shows_the_learner_against_meshes_and_against_subjects():
    row = {'align_s': 0.5, 'seed_s': 1.25}
    learner = {
        'meshes': [{'meshes': 10_000, 'subjects': 10, **row}],
        'meshes_exponent': {'align_s': 1.0, 'seed_s': 1.04, 'joint_s': 0.98},
        'subjects': [{'meshes': 20_000, 'subjects': 50, **row, 'joint_s': 3.0}],
    }
    table = format_table({'benchmarks': {'learner_scaling': learner}}).splitlines()
    assert table[2:] == [
        '| learner, 10,000 meshes, 10 subjects | align 0.50 s + learn 1.25 s |  |',
        '| learner scaling exponent (time ~ meshes^k) | align k = 1.00, learn k = 1.04, '
        'joint learner k = 0.98 | k = 1 (linear) |',
        '| learner, 20,000 meshes, 50 subjects | align 0.50 s + learn 1.25 s '
        '(joint learner 3.00 s) |  |',
    ]
