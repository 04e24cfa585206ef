"""Peak resident memory (VmHWM) of every node process while it works (issue 9).

The mono pipeline runs as it would on a robot: mono_tracker fed rendered 640x480 images at 30 Hz,
identity_recognizer and expression_recognizer on its outputs, and bag_recorder recording the
face topics; then stereo_tracker is fed 640x480 pairs at 10 Hz on its own. bag_player plays the
recorded 640x480 mono test bag in a loop, and the learner learns a model from raw 640x480 stereo
training bags, tracking them first (its heaviest use: ``face-tracking learn`` on a stereo
recording). Each node's peak RSS is read from /proc/<pid>/status before it is stopped. A node
that is not installed yet is reported as skipped.
"""

from __future__ import annotations

from collections.abc import Callable
import shutil
import time
from typing import Any

from face_tracking_ros.bench.common import BenchOptions, pin_to_core, skipped
from face_tracking_ros.bench.live import Driver, NodeProcess, tracker_inputs
from face_tracking_ros.bench.world import classifier_file, recorded_bag, scene_config
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.synthetic.recording import record
from face_tracking_ros.synthetic.scenes import Kind, SceneConfig

WIDTH, HEIGHT = 640, 480
FRAMES = 30
MONO_RATE_HZ, STEREO_RATE_HZ = 30.0, 10.0
SECONDS, QUICK_SECONDS = 15.0, 2.0
RECORDED_TOPICS = '[face/state, face/action, face/shape, face/expression, face/identity]'
PLAYED_FRAMES = 90  # frames of the mono bag bag_player plays (3 s at 30 fps)
LEARN_SUBJECTS, LEARN_FRAMES = 4, 60  # raw stereo training bags of the learner, frames each
NODE_TIMEOUT_S = 600.0  # longest a node of _peak_until may take to be done
POLL_S = 0.2


def run(options: BenchOptions) -> dict[str, Any]:
    """Peak RSS per node, MB, with the run each was measured in.

    Returns:
        ``{'<node>': {'peak_rss_mb': m, 'run': '...'} | {'skipped': reason}}``.
    """
    pin_to_core(options.cores.driver)
    seconds = QUICK_SECONDS if options.quick else SECONDS
    work = options.work_dir
    streams, params = tracker_inputs(work, Kind.MONO, WIDTH, HEIGHT, FRAMES, options.seed)
    recording = work / 'memory_recording'
    shutil.rmtree(recording, ignore_errors=True)
    model = {'model_file': params['model_file']}
    pipeline = {
        'mono_tracker': params,
        'identity_recognizer': model,
        'expression_recognizer': {**model, 'classifier_file': classifier_file(work, options.seed)},
        'bag_recorder': {'output': recording, 'topics': RECORDED_TOPICS},
    }
    mono_run = f'mono pipeline, {WIDTH}x{HEIGHT} at {MONO_RATE_HZ:g} Hz for {seconds:g} s'
    results = _measure(pipeline, streams, MONO_RATE_HZ, seconds, options, mono_run)
    streams, params = tracker_inputs(work, Kind.STEREO, WIDTH, HEIGHT, FRAMES, options.seed)
    stereo_run = f'stereo pairs {WIDTH}x{HEIGHT} at {STEREO_RATE_HZ:g} Hz for {seconds:g} s'
    results.update(
        _measure({'stereo_tracker': params}, streams, STEREO_RATE_HZ, seconds, options, stereo_run)
    )
    results['bag_player'] = _bag_player(options, seconds)
    results['learner'] = _learner(options)
    return results


def _bag_player(options: BenchOptions, seconds: float) -> dict[str, Any]:
    """bag_player's peak RSS over ``seconds`` of playing the mono test bag in a loop."""
    config = scene_config(Kind.MONO, WIDTH, HEIGHT, PLAYED_FRAMES, options.seed)
    bag, _ = recorded_bag(options.work_dir, config)
    deadline = time.monotonic() + seconds
    description = f'{WIDTH}x{HEIGHT} mono bag played in a loop, read {seconds:g} s after start'
    return _peak_until(
        'bag_player',
        {'bag': bag, 'loop': True},
        lambda: time.monotonic() >= deadline,
        options,
        description,
    )


def _learner(options: BenchOptions) -> dict[str, Any]:
    """The learner's peak RSS while it tracks raw stereo training bags and learns from them."""
    bags = options.work_dir / f'memory_stereo_train_seed{options.seed}'
    if not bags.is_dir():
        config = SceneConfig(
            kind=Kind.STEREO,
            subjects=LEARN_SUBJECTS,
            frames=LEARN_FRAMES,
            fps=30.0,
            seed=options.seed,
            motion='still',
        )
        record(config, bags)
    output = options.work_dir / 'memory_model.npz'
    report = output.with_suffix('.json')  # written after the model: the learning is done
    output.unlink(missing_ok=True)
    report.unlink(missing_ok=True)
    params = {'bag_dir': bags, 'output': output, 'from_images': True, 'simulate_clicks': 0.0}
    description = (
        f'learning from {LEARN_SUBJECTS} raw stereo bags of {LEARN_FRAMES} pairs '
        f'({WIDTH}x{HEIGHT}), tracked first'
    )
    return _peak_until('learner', params, report.is_file, options, description)


def _peak_until(
    name: str,
    params: dict[str, object],
    done: Callable[[], bool],
    options: BenchOptions,
    description: str,
) -> dict[str, Any]:
    """Run one node until ``done()``, then read its peak RSS and stop it.

    A node that exits first, or is not done within NODE_TIMEOUT_S, is reported as failed.
    """
    try:
        node = NodeProcess(name, params, options, options.work_dir / f'{name}.log')
    except ConfigError as error:
        return skipped(str(error))
    deadline = time.monotonic() + NODE_TIMEOUT_S
    try:
        while not done():
            if not node.alive():
                return {'failed': f'exited early: {node.tail(2)}'}
            if time.monotonic() > deadline:
                return {'failed': f'not done after {NODE_TIMEOUT_S:g} s: {node.tail(2)}'}
            time.sleep(POLL_S)
        return {'peak_rss_mb': node.peak_rss_mb(), 'run': description}
    finally:
        node.stop()


def _measure(
    nodes: dict[str, dict[str, object]],
    streams: list,
    rate_hz: float,
    seconds: float,
    options: BenchOptions,
    description: str,
) -> dict[str, Any]:
    """Start the nodes that are installed, drive them, read their peak RSS, stop them."""
    results: dict[str, Any] = {}
    running: list[NodeProcess] = []
    for name, params in nodes.items():
        try:
            running.append(NodeProcess(name, params, options, options.work_dir / f'{name}.log'))
        except ConfigError as error:
            results[name] = skipped(str(error))
    driver = Driver(streams, name='bench_memory_driver')
    try:
        running = _connected(driver, running, results)
        if running:
            driver.run(rate_hz, seconds)
        for node in running:
            results[node.name] = {'peak_rss_mb': node.peak_rss_mb(), 'run': description}
    finally:
        driver.close()
        for node in running:
            node.stop()
    return results


def _connected(
    driver: Driver, nodes: list[NodeProcess], results: dict[str, Any]
) -> list[NodeProcess]:
    """Wait for the nodes; those that die at start-up are reported as failed and left out."""
    while nodes:
        try:
            driver.wait_for(nodes)
        except ConfigError:
            dead = [node for node in nodes if not node.alive()]
            if not dead:
                raise
            for node in dead:
                results[node.name] = {'failed': f'exited at start-up: {node.tail(2)}'}
            nodes = [node for node in nodes if node.alive()]
        else:
            break
    return nodes
