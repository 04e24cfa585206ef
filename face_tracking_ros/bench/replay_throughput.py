"""Offline replay throughput: a recorded 30 fps bag through a tracker node's processor (issue 9).

Two figures per tracker, each in frames/s and as a multiple of real time:

- the replay: :func:`face_tracking_ros.replay.replay_bag` runs the node's own processor over the
  bag (reading, decoding, tracking, converting and writing the outputs) in a process that has
  imported the processor's modules (numba and the kernels compiled when a module loads), as a
  process replaying bag after bag would; the kernels compiled at their first call, the bag's
  opening and the first image's fit are counted. Target: >= 30x real time for a 30 fps mono bag.
- the command: ``face-tracking replay NODE BAG`` in a new process, wall time from launch to exit,
  which adds the interpreter's start, every import and writing the output bag's metadata: what a
  user waits for.

The bag is 30 s long, as a recording would be: the fixed costs of a replay (opening the bags,
building the processor, the first frame's fit, the bundle adjustment of the first views) took
about 0.25 s, so a 3-s bag (90 frames, used before 2026-12-03) measured mostly those: mono 5.0x
real time for 90 frames, 7.9x for 300 and 8.4x for 900 in one run.
"""

from __future__ import annotations

from pathlib import Path
import shutil
import subprocess
import sys
import time
from typing import Any

from face_tracking_ros.bench.common import BenchOptions, last_lines
from face_tracking_ros.bench.world import model_file, recorded_bag, scene_config
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.processing.registry import processor_factory
from face_tracking_ros.replay import replay_bag
from face_tracking_ros.synthetic.scenes import Kind

FPS = 30.0
WIDTH, HEIGHT = 640, 480
QUICK_WIDTH, QUICK_HEIGHT = 320, 240
FRAMES, QUICK_FRAMES = 900, 10
NODES = {Kind.MONO: 'mono_tracker', Kind.STEREO: 'stereo_tracker'}
IMAGE_TOPIC = {Kind.MONO: 'image', Kind.STEREO: 'left/image_raw'}
FAILURE_LINES = 5  # of a failed command's standard error quoted in the error


def run(options: BenchOptions) -> dict[str, Any]:
    """Replay a mono and a stereo bag, in this process and as a command; frames/s, x real time.

    Returns:
        ``{'mono': {...}, 'stereo': {...}}`` with the image size, frames, seconds, frames/s and
        x real time (for a 30 fps bag) of the replay, the command's seconds and x real time,
        frames with a face/state output and input errors.

    Raises:
        RuntimeError: if the command fails.
    """
    width, height = (QUICK_WIDTH, QUICK_HEIGHT) if options.quick else (WIDTH, HEIGHT)
    frames = QUICK_FRAMES if options.quick else FRAMES
    model = model_file(options.work_dir, 34, options.seed)
    results = {}
    for kind, node in NODES.items():
        bag, init_file = recorded_bag(
            options.work_dir, scene_config(kind, width, height, frames, options.seed)
        )
        params = [f'model_file={model}', f'init_file={init_file}']
        processor_factory(node)  # its modules imported before the clock starts
        out = options.work_dir / f'replay_{kind.value}'
        shutil.rmtree(out, ignore_errors=True)
        start = time.perf_counter()
        stats = replay_bag([node], bag, out, OverrideParameters.parse(params), progress=False)
        seconds = time.perf_counter() - start
        images = stats.inputs[IMAGE_TOPIC[kind]]
        command_seconds = _command_seconds(node, bag, out.with_name(f'{out.name}_command'), params)
        results[kind.value] = {
            'size': f'{width}x{height}',
            'frames': images,
            'seconds': seconds,
            'frames_per_s': images / seconds,
            'x_real_time': images / FPS / seconds,
            'command_seconds': command_seconds,
            'command_x_real_time': images / FPS / command_seconds,
            'states': stats.outputs['face/state'],
            'input_errors': dict(stats.errors),
        }
    return results


def _command_seconds(node: str, bag: Path, out: Path, params: list[str]) -> float:
    """Wall seconds of ``face-tracking replay node bag --out out`` with ``params``, from launch.

    Raises:
        RuntimeError: if the command exits with an error (its last lines of standard error).
    """
    shutil.rmtree(out, ignore_errors=True)
    command = [sys.executable, '-m', 'face_tracking_ros.cli.main', 'replay', node, str(bag)]
    command += ['--out', str(out), '--quiet', *(f'--param={param}' for param in params)]
    start = time.perf_counter()
    child = subprocess.run(command, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - start
    if child.returncode != 0:
        tail = last_lines(child.stderr, FAILURE_LINES)
        msg = f'face-tracking replay {node} exited with status {child.returncode}: {tail}'
        raise RuntimeError(msg)
    return seconds
