"""Runs benchmarks, each in its own process on one core, and gathers one results JSON.

Every benchmark runs as ``python -m face_tracking_ros.bench.runner NAME --part FILE ...`` with one
BLAS/OpenMP thread set in its environment before numpy loads, pinned to the bench core of
:class:`~.common.Cores` (the lowest core the command may run on; the live ones move their DDS
driver to the next one and run the nodes on the bench core), and on the benchmark ROS domain with
loopback-only DDS. A benchmark that fails is recorded as ``{'failed': <last lines of its
stderr>}``; one that cannot run yet reports ``{'skipped': reason}`` itself. NaN figures (not
applicable, e.g. the alpha error of a sequence without expressions) are written as null.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import datetime
import importlib
import json
import os
from pathlib import Path
import platform
import subprocess
import sys
import time
from typing import Any

from face_tracking_ros.bench.common import BenchOptions, Cores, dds_env, last_lines, pin_to_core
from face_tracking_ros.errors import ConfigError
from face_tracking_ros.io.atomic import write_json_atomically
from face_tracking_ros.wording import listed

BENCHMARKS = (
    'tracker_speed',
    'replay_throughput',
    'live_latency',
    'learner_scaling',
    'memory',
    'accuracy_table',
    'mono_accuracy',
    'stereo_accuracy',
    'soak',
)
DEFAULT_BENCHMARKS = BENCHMARKS[:-1]  # the soak run only on request
TIMEOUT_S = 900.0  # per benchmark, besides the soak's own duration
FAILURE_LINES = 8


def run_benchmarks(names: Sequence[str], options: BenchOptions) -> dict[str, Any]:
    """Run benchmarks one after another, each in its own pinned process.

    Args:
        names: benchmark names, from :data:`BENCHMARKS`.
        options: sizes, work directory, soak duration, ROS domain, seed.

    Returns:
        ``{'date', 'machine', 'cores': {'bench', 'driver'}, 'quick', 'benchmarks': {name:
        result}, 'seconds': {name: s}}``.

    Raises:
        ConfigError: for an unknown benchmark name.
    """
    unknown = [name for name in names if name not in BENCHMARKS]
    if unknown:
        msg = f'unknown {listed("benchmark", unknown)}; choose from {", ".join(BENCHMARKS)}'
        raise ConfigError(msg)
    options.work_dir.mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = {}
    seconds: dict[str, float] = {}
    for name in names:
        start = time.perf_counter()
        results[name] = _run_child(name, options)
        seconds[name] = time.perf_counter() - start
    return {
        'date': datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds'),
        'machine': machine(),
        'cores': {'bench': options.cores.bench, 'driver': options.cores.driver},
        'quick': options.quick,
        'benchmarks': results,
        'seconds': seconds,
    }


def _run_child(name: str, options: BenchOptions) -> dict[str, Any]:
    """One benchmark in a child process; its result, or why it failed."""
    part = options.work_dir / f'{name}.json'
    part.unlink(missing_ok=True)
    command = [
        sys.executable,
        '-m',
        __name__,
        name,
        '--part',
        str(part),
        '--work-dir',
        str(options.work_dir),
        '--minutes',
        str(options.minutes),
        '--domain-id',
        str(options.domain_id),
        '--seed',
        str(options.seed),
        '--bench-core',
        str(options.cores.bench),
        '--driver-core',
        str(options.cores.driver),
    ]
    if options.quick:
        command.append('--quick')
    timeout = TIMEOUT_S + (60.0 * options.minutes if name == 'soak' else 0.0)
    try:
        child = subprocess.run(
            command,
            env=dds_env(options.domain_id),
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        return {'failed': f'timed out after {timeout:g} s'}
    if child.returncode != 0 or not part.is_file():
        tail = last_lines(child.stderr, FAILURE_LINES)
        return {'failed': f'exit status {child.returncode}: {tail}'}
    return json.loads(part.read_text())


def machine() -> dict[str, Any]:
    """The machine the figures come from: cores, CPU model, RAM, Python, OS."""
    cpuinfo = Path('/proc/cpuinfo').read_text() if Path('/proc/cpuinfo').is_file() else ''
    models = [
        line.split(':', 1)[1].strip() for line in cpuinfo.splitlines() if 'model name' in line
    ]
    pages = os.sysconf('SC_PHYS_PAGES') * os.sysconf('SC_PAGE_SIZE')
    return {
        'nproc': len(os.sched_getaffinity(0)),
        'cpu_model': models[0] if models else platform.processor(),
        'ram_gb': round(pages / 2**30, 1),
        'python': platform.python_version(),
        'os': platform.platform(),
        'measured_on_cores': 1,
    }


def main(argv: Sequence[str] | None = None) -> int:
    """Child entry point: run one benchmark pinned to one core and write its JSON part."""
    parser = argparse.ArgumentParser(
        description='Run one benchmark (used by face-tracking bench).'
    )
    parser.add_argument('name', choices=BENCHMARKS)
    parser.add_argument('--part', type=Path, required=True, help='JSON file to write')
    parser.add_argument('--work-dir', type=Path, default=BenchOptions.work_dir)
    parser.add_argument('--minutes', type=float, default=BenchOptions.minutes)
    parser.add_argument('--domain-id', type=int, default=BenchOptions.domain_id)
    parser.add_argument('--seed', type=int, default=BenchOptions.seed)
    parser.add_argument('--bench-core', type=int, required=True)
    parser.add_argument('--driver-core', type=int, required=True)
    parser.add_argument('--quick', action='store_true')
    args = parser.parse_args(argv)
    cores = Cores(pin_to_core(args.bench_core), args.driver_core)
    options = BenchOptions(
        args.quick, args.work_dir, args.minutes, args.domain_id, args.seed, cores
    )
    result = importlib.import_module(f'{__package__}.{args.name}').run(options)
    write_json_atomically(args.part, result, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
