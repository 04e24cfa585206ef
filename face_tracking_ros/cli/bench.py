"""``face-tracking bench [--quick] [--json FILE] [--only NAME ...]``: the benchmark suite.

Runs the benchmarks of :mod:`face_tracking_ros.bench` (each in its own process on one core; see
:mod:`face_tracking_ros.bench.runner`), writes every figure to one JSON file and prints the
headline table (the one in README.md, "Performance"). A run in which a benchmark failed leaves
the results file of an earlier run as it was and writes its own beside it (``results.json``:
``results.failed.json``). ``--only soak --minutes 30`` is the soak run of issue 10; it is not
part of the default set. The live benchmarks run on the ROS domain ``--domain-id``, by default
the environment's ``ROS_DOMAIN_ID`` (as every ROS 2 tool), else 70.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from face_tracking_ros.bench.common import BenchOptions, Cores
from face_tracking_ros.bench.runner import BENCHMARKS, DEFAULT_BENCHMARKS, run_benchmarks
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import check_output_path, write_json_atomically
from face_tracking_ros.wording import counted

TABLE_SIZE = '640x480'
STAGE_NAMES = {'align_s': 'align', 'seed_s': 'learn', 'joint_s': 'joint learner'}  # learner rows
MAX_DOMAIN_ID = 232  # the last whose DDS ports fit in 16 bits (ROS 2 docs, 'About Domain ID')
_WARM_UP = ' (shorter than its warm-up)'  # why a soak has no RSS growth


def register(parser: argparse.ArgumentParser) -> None:
    """Register the ``bench`` subcommand's options."""
    parser.description = (
        'Run the benchmark suite on the synthetic world, one core per benchmark, '
        'and write the results as JSON.'
    )
    parser.add_argument('--quick', action='store_true', help='smoke-test sizes (seconds)')
    parser.add_argument(
        '--json',
        type=Path,
        help='results file (default: OUT/bench/results.json); a run in which a benchmark fails '
        'writes STEM.failed.json beside it instead (results.failed.json)',
    )
    parser.add_argument(
        '--out', type=Path, default=Path('out'), help='output directory (default: out)'
    )
    parser.add_argument(
        '--only',
        nargs='+',
        choices=BENCHMARKS,
        metavar='NAME',
        help=f'run only these benchmarks: {", ".join(BENCHMARKS)} (default: all but soak)',
    )
    parser.add_argument(
        '--minutes',
        type=float,
        default=BenchOptions.minutes,
        help='soak duration, min, > 0 (%(default)g)',
    )
    parser.add_argument(
        '--domain-id',
        type=int,
        help=f'ROS domain of the live runs, 0 to {MAX_DOMAIN_ID} (default: ROS_DOMAIN_ID when '
        f'set, else {BenchOptions.domain_id})',
    )
    parser.add_argument(
        '--seed',
        type=int,
        default=BenchOptions.seed,
        help='synthetic world seed, >= 0 (%(default)s)',
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run, write the JSON (atomically), print the table; 1 if a benchmark failed.

    Raises:
        ConfigError: for an option out of range, before any benchmark runs.
    """
    domain_id = _check_options(args)
    work_dir = args.out / 'bench'
    options = BenchOptions(args.quick, work_dir, args.minutes, domain_id, args.seed)
    results = run_benchmarks(args.only or DEFAULT_BENCHMARKS, options)
    path = args.json or work_dir / 'results.json'
    failed = [name for name, r in results['benchmarks'].items() if 'failed' in r]
    written = path.with_name(f'{path.stem}.failed{path.suffix}') if failed else path
    written.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomically(written, results, indent=1)
    print(format_table(results))
    print(_cores_line(options.cores))
    print(f'results: {written}' + (f' ({path} not replaced)' if failed else ''))
    for name in failed:
        print(f'{name} failed: {results["benchmarks"][name]["failed"]}')
    return 1 if failed else 0


def _cores_line(cores: Cores) -> str:
    """Which cores measured and drove, and a warning when one core did both."""
    line = f'measured on core {cores.bench}, live drivers on core {cores.driver}'
    if cores.bench == cores.driver:
        line += " (one core: the live figures include the driver's work)"
    return line


def _check_options(args: argparse.Namespace) -> int:
    """Refuse option values the benchmarks cannot run with, before the first one starts.

    Returns:
        The ROS domain of the live runs (:func:`_domain_id`).

    Raises:
        ConfigError: naming the option (or ROS_DOMAIN_ID), its value and the range expected, or
            an output path that cannot be written
            (:func:`~face_tracking_ros.io.atomic.check_output_path`).
    """
    if not (math.isfinite(args.minutes) and args.minutes > 0.0):
        msg = f'--minutes must be a finite number > 0 (the soak duration), got {args.minutes}'
        raise ConfigError(msg)
    domain_id, source = _domain_id(args.domain_id)
    if not 0 <= domain_id <= MAX_DOMAIN_ID:
        msg = (
            f'{source} must be in [0, {MAX_DOMAIN_ID}] (a ROS_DOMAIN_ID whose DDS ports '
            f'exist), got {domain_id}'
        )
        raise ConfigError(msg)
    if args.seed < 0:
        msg = f'--seed must be >= 0, got {args.seed}'
        raise ConfigError(msg)
    check_output_path(args.out, '--out', directory=True)
    if args.json is not None:
        check_output_path(args.json, '--json')
    return domain_id


def _domain_id(given: int | None) -> tuple[int, str]:
    """The ROS domain of the live runs and where it comes from, for messages.

    ``given`` (--domain-id), else the environment's ROS_DOMAIN_ID when set (not empty), else
    :attr:`BenchOptions.domain_id`.

    Raises:
        ConfigError: if ROS_DOMAIN_ID, used, is not an integer.
    """
    if given is not None:
        return given, '--domain-id'
    text = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if not text:
        return BenchOptions.domain_id, '--domain-id'
    try:
        return int(text), 'ROS_DOMAIN_ID (the default of --domain-id)'
    except ValueError:
        msg = f'ROS_DOMAIN_ID (the default of --domain-id) must be an integer, got {text!r}'
        raise ConfigError(msg) from None


def format_table(results: dict[str, Any]) -> str:
    """The headline figures as a Markdown table (one row per figure present in the results)."""
    rows = [('Figure', 'Measured', 'Target')]
    benchmarks = results['benchmarks']
    rows += _speed_rows(benchmarks.get('tracker_speed', {}))
    rows += _replay_rows(benchmarks.get('replay_throughput', {}))
    rows += _live_rows(benchmarks.get('live_latency', {}))
    rows += _learner_rows(benchmarks.get('learner_scaling', {}))
    rows += _memory_rows(benchmarks.get('memory', {}))
    rows += _accuracy_rows(benchmarks.get('accuracy_table', {}))
    rows += _mono_accuracy_rows(benchmarks.get('mono_accuracy', {}))
    rows += _stereo_accuracy_rows(benchmarks.get('stereo_accuracy', {}))
    rows += _soak_rows(benchmarks.get('soak', {}))
    lines = [f'| {" | ".join(row)} |' for row in rows]
    lines.insert(1, '| --- | --- | --- |')
    return '\n'.join(lines)


def _speed_rows(speed: dict[str, Any]) -> list[tuple[str, str, str]]:
    rows = []
    for size, by_nodes in speed.items():
        if not isinstance(by_nodes, dict):
            continue
        for nodes, figures in by_nodes.items():
            if nodes == 'rectification':
                rows.append(
                    (
                        f'rectification of a raw image (distortion, R), {size}',
                        f'{figures["median_ms"]:.2f} ms median, {figures["p99_ms"]:.2f} ms p99',
                        '',
                    )
                )
                continue
            for tracker, target in (('mono', '<= 2 ms'), ('stereo', '<= 5 ms'), ('baseline', '')):
                f = figures.get(tracker, {})
                if 'median_ms' in f:
                    rows.append(
                        (
                            f'{tracker} step, {size}, {nodes.replace("_", " ")}',
                            f'{f["median_ms"]:.1f} ms median, {f["p99_ms"]:.1f} ms p99',
                            target if size == TABLE_SIZE else '',
                        )
                    )
            rows.extend(
                (
                    f'{tracker} / baseline time, {size}, {nodes.replace("_", " ")}',
                    f'{figures[f"{tracker}_over_baseline"]:.1f}x',
                    '',
                )
                for tracker in ('mono', 'stereo')
                if f'{tracker}_over_baseline' in figures
            )
    return rows


def _replay_rows(replay: dict[str, Any]) -> list[tuple[str, str, str]]:
    rows = []
    for kind, f in replay.items():
        if not (isinstance(f, dict) and 'frames_per_s' in f):
            continue
        rows.append(
            (
                f'offline replay, {kind}, {f["size"]}',
                f'{f["frames_per_s"]:.1f} frames/s = {f["x_real_time"]:.2f}x real time (30 fps)',
                '>= 30x' if kind == 'mono' else '',
            )
        )
        if 'command_seconds' in f:
            rows.append(
                (
                    f'face-tracking replay command from launch, {kind}, {f["size"]}',
                    f'{f["frames"]} frames in {f["command_seconds"]:.2f} s = '
                    f'{f["command_x_real_time"]:.2f}x real time (30 fps)',
                    '',
                )
            )
    return rows


def _live_rows(live: dict[str, Any]) -> list[tuple[str, str, str]]:
    rows = []
    for kind, tracker in live.items():
        if isinstance(tracker, dict) and 'at_30hz' in tracker:
            rows += _tracker_live_rows(kind, tracker)
    return rows


def _tracker_live_rows(kind: str, live: dict[str, Any]) -> list[tuple[str, str, str]]:
    f = live['at_30hz']
    run = f'{kind}, {live["size"]} at 30 Hz, {f["seconds"]:g} s'
    latency = (
        f'{f["latency_p50_ms"]:.1f} ms p50, {f["latency_p99_ms"]:.1f} ms p99'
        if f['received']
        else 'no face/state received'
    )
    cpu = live.get('node_cpu_ms_per_frame')  # runs before 2026-12-07 did not time it
    node_cpu = f', node CPU {cpu:.1f} ms a frame' if f['received'] and cpu is not None else ''
    return [
        (
            f'live latency image -> face/state, {run}',
            f'{latency}, {f["dropped"]} of {f["published"]} dropped{node_cpu}',
            'p99 <= 10 ms, no drops',
        ),
        (
            f'highest rate without drops (stepped), {kind}',
            f'{live["max_rate_without_drops_hz"]:g} Hz',
            '>= 30 Hz',
        ),
    ]


def _learner_rows(learner: dict[str, Any]) -> list[tuple[str, str, str]]:
    rows = [_learner_row(r) for r in learner.get('meshes', [])]
    if 'meshes_exponent' in learner:
        e = learner['meshes_exponent']
        rows.append(
            (
                'learner scaling exponent (time ~ meshes^k)',
                ', '.join(f'{STAGE_NAMES[stage]} k = {k:.2f}' for stage, k in e.items()),
                'k = 1 (linear)',
            )
        )
    return rows + [_learner_row(r) for r in learner.get('subjects', [])]


def _learner_row(row: dict[str, Any]) -> tuple[str, str, str]:
    """'align A s + learn L s' (the seed learner), with the joint learner's time if measured."""
    figures = f'align {row["align_s"]:.2f} s + learn {row["seed_s"]:.2f} s'
    if 'joint_s' in row:
        figures += f' (joint learner {row["joint_s"]:.2f} s)'
    return f'learner, {row["meshes"]:,} meshes, {row["subjects"]} subjects', figures, ''


def _memory_rows(memory: dict[str, Any]) -> list[tuple[str, str, str]]:
    return [
        (f'peak RSS, {node}', f'{f["peak_rss_mb"]:.0f} MB' if 'peak_rss_mb' in f else _why(f), '')
        for node, f in memory.items()
        if isinstance(f, dict)
    ]


def _accuracy_rows(table: dict[str, Any]) -> list[tuple[str, str, str]]:
    rows = []
    for key, label in (
        ('mono', f'mono accuracy ({table.get("scene")})'),
        ('baseline', f'baseline accuracy ({table.get("scene")})'),
        ('mono_occlusion', 'mono accuracy (same scene), an occluder passing'),
    ):
        f = table.get(key, {})
        if 'node_rms_mm' in f:
            rotation = ' / '.join(f'{v:.2f}' for v in f['rotation_mae_deg'])
            rows.append(
                (
                    label,
                    f'node RMS {f["node_rms_mm"]:.1f} mm, rotation MAE {rotation} deg, '
                    f'{f["tracked"]}/{f["frames"]} tracked',
                    '',
                )
            )
    for key, path in (
        ('stereo', 'streamed, as the node'),
        ('stereo_offline', 'as learn tracks'),
        ('stereo_photo', 'photo skin, as learn tracks'),
    ):
        f = table.get(key, {})
        if 'node_rms_mm' in f:
            rows.append(
                (
                    f'stereo accuracy (same scene), {path}',
                    f'node RMS {f["node_rms_mm"]:.1f} mm, max reprojection '
                    f'{f["max_reprojection_px"]:.1f} px, drift {f["drift_mm"]:.1f} mm',
                    '',
                )
            )
    f = table.get('learning', {})
    if 'loo_shape_similarity' in f:
        rows.append(
            (
                'learning (§3.4) vs truth',
                f'LOO similarity S {f["loo_shape_similarity"]:.3f}, A '
                f'{f["loo_action_similarity"]:.3f}; truth S {f["truth"]["shape_similarity"]:.3f}'
                f', A {f["truth"]["action_similarity"]:.3f}',
                '',
            )
        )
    f = table.get('recognition', {})
    if 'identity_closed_set' in f:
        rows.append(
            (
                'recognition',
                f'identity {100 * f["identity_closed_set"]:.0f} % (open set '
                f'{100 * f["identity_open_set"]:.0f} %), expressions '
                f'{100 * f["expression_clear_frames"]:.0f} % clear frames, event F1 '
                f'{f["event_f1"]:.2f}',
                '',
            )
        )
    return rows


_MONO_TARGET = 'rotation <= 1.0 deg per axis; t <= 2 / 2 / 5 mm; alpha <= 15 %; drift <= 0.2'
MONO_TARGETS = {
    'true_model': _MONO_TARGET,
    'true_model_click_draws': _MONO_TARGET,
    'baseline': 'mono rotation error >= 2x lower',
    'photo_baseline': 'mono rotation error >= 2x lower',
}


def _mono_accuracy_rows(protocol: dict[str, Any]) -> list[tuple[str, str, str]]:
    rows = []
    for name, entry in protocol.get('rows', {}).items():
        f = entry['mean']
        rotation = ' / '.join(f'{v:.2f}' for v in f['rotation_mae_deg'])
        translation = ' / '.join(f'{v:.1f}' for v in f['translation_mae_mm'])
        alpha = f['alpha_rms_percent']
        count = entry.get('click_draws', 1)
        draws = f' x {count} click draws' if count > 1 else ''
        rows.append(
            (
                f'mono protocol, {name.replace("_", " ")} '
                f'(mean of {counted(len(entry["seeds"]), "seed")}{draws})',
                f'rotation MAE {rotation} deg, t MAE {translation} mm, alpha '
                f'{"n/a" if alpha is None else f"{alpha:.0f} %"}, drift {f["drift_deg"]:+.2f} '
                f'deg, lost {f["lost"]:.0f}',
                MONO_TARGETS.get(name, ''),
            )
        )
    still = protocol.get('still', {})
    for key, pose in (('angle_std_deg', 'published'), ('angle_std_unfiltered_deg', 'raw')):
        if key in still.get('mean', {}):
            worst = np.max([seed[key] for seed in still['seeds']], axis=0)
            rows.append(
                (
                    f'mono jitter, static head, {pose} pose (std of the rotation angles)',
                    ' / '.join(f'{v:.3f}' for v in still['mean'][key])
                    + ' deg (x / y / z), worst seed '
                    + ' / '.join(f'{v:.3f}' for v in worst),
                    '<= 0.05 deg' if pose == 'published' else '',
                )
            )
    return rows


_STEREO_TARGET = 'node RMS <= 1.0 mm, reprojection <= 1.0 px, drift <= 1 mm, slip <= 1.5 mm'


def _stereo_accuracy_rows(protocol: dict[str, Any]) -> list[tuple[str, str, str]]:
    rows = []
    for name, run in protocol.get('runs', {}).items():
        f = run['pooled']
        groups = f['node_rms_by_group_mm']
        edge = f'face edge {groups["edge"]:.2f}, ' if 'edge' in groups else ''
        slip = f['boundary_slip_mm']
        rows.append(
            (
                f'stereo protocol, {name.replace("_", " ")} ({len(run["subjects"])} subjects)',
                f'node RMS {f["node_rms_mm"]:.2f} mm ({edge}mouth {groups["mouth"]:.2f}), max '
                f'reprojection {f["max_reprojection_px"]:.2f} px, drift {f["drift_mm"]:.2f} mm'
                + ('' if slip is None else f', slip {slip:.2f} mm'),
                _STEREO_TARGET,
            )
        )
    for size, learned in protocol.get('learning', {}).items():
        names = ' / '.join(name.replace('_', ' ') for name in learned)
        rows.append(
            (
                f'stereo protocol, {size.replace("_", " ")}: model learned from {names} meshes',
                'S vs true identity '
                + ' / '.join(f'{m["shape_similarity"]:.3f}' for m in learned.values())
                + ', A vs true expressions '
                + ' / '.join(f'{m["action_similarity"]:.3f}' for m in learned.values()),
                'tracked within 0.01 of true',
            )
        )
    return rows


def _soak_rows(soak: dict[str, Any]) -> list[tuple[str, str, str]]:
    if 'rss_growth_mb' not in soak:
        return []
    return [
        (
            f'soak, {soak["minutes"]:g} min at 30 Hz',
            f'RSS growth {_measured(soak["rss_growth_mb"], "+.1f", " MB", _WARM_UP)}, latency '
            f'p50 trend {_measured(soak["latency_p50_slope_ms_per_min"], "+.2f", " ms/min")}, '
            f'recorder missed {soak["recorder_missing"]} of {soak["received"]}',
            '< 5 MB, no growth, none missed',
        )
    ]


def _measured(value: float | None, spec: str, unit: str, why: str = '') -> str:
    """``value`` formatted by ``spec`` with its unit, or 'not measured' for NaN (or JSON null)."""
    if value is None or math.isnan(value):
        return f'not measured{why}'
    return f'{value:{spec}}{unit}'


def _why(entry: dict[str, Any]) -> str:
    """'skipped: ...' or 'failed: ...' (first 80 characters)."""
    key = 'skipped' if 'skipped' in entry else 'failed'
    return f'{key}: {str(entry.get(key, ""))[:80]}'.replace('|', '/')
