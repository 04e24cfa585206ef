"""Offline replay throughput: a recorded 30 fps bag through a tracker node's processor (issue 9).

:func:`face_tracking_ros.replay.replay_bag` runs the node's own processor over the bag (reading,
decoding, tracking, converting and writing the outputs), so the figure is what ``face-tracking
track`` achieves. Target: >= 30x real time for a 30 fps mono bag.

The bag is 30 s long, as a recording would be: the fixed costs of a replay (opening the bags,
building the processor, the first frame's fit, the bundle adjustment of the first views) took
about 0.25 s, so a 3-s bag (90 frames, used before 2026-12-03) measured mostly those: mono 5.0x
real time for 90 frames, 7.9x for 300 and 8.4x for 900 in one run.
"""

from __future__ import annotations

import shutil
import time
from typing import Any

from face_tracking_ros.bench.common import BenchOptions
from face_tracking_ros.bench.world import model_file, recorded_bag, scene_config
from face_tracking_ros.processing.parameters import OverrideParameters
from face_tracking_ros.replay import replay_bag
from face_tracking_ros.synthetic.scenes import Kind

FPS = 30.0
WIDTH, HEIGHT = 640, 480
QUICK_WIDTH, QUICK_HEIGHT = 320, 240
FRAMES, QUICK_FRAMES = 900, 10
NODES = {Kind.MONO: 'mono_tracker', Kind.STEREO: 'stereo_tracker'}
IMAGE_TOPIC = {Kind.MONO: 'image', Kind.STEREO: 'left/image_raw'}


def run(options: BenchOptions) -> dict[str, Any]:
    """Replay a mono and a stereo bag; frames per second and the multiple of real time.

    Returns:
        ``{'mono': {...}, 'stereo': {...}}`` with the image size, frames, seconds, frames/s,
        x real time (for a 30 fps bag), frames with a face/state output and input errors.
    """
    width, height = (QUICK_WIDTH, QUICK_HEIGHT) if options.quick else (WIDTH, HEIGHT)
    frames = QUICK_FRAMES if options.quick else FRAMES
    model = model_file(options.work_dir, 34, options.seed)
    results = {}
    for kind, node in NODES.items():
        bag, init_file = recorded_bag(
            options.work_dir, scene_config(kind, width, height, frames, options.seed)
        )
        out = options.work_dir / f'replay_{kind.value}'
        shutil.rmtree(out, ignore_errors=True)
        params = OverrideParameters.parse([f'model_file={model}', f'init_file={init_file}'])
        start = time.perf_counter()
        stats = replay_bag([node], bag, out, params, progress=False)
        seconds = time.perf_counter() - start
        images = stats.inputs[IMAGE_TOPIC[kind]]
        results[kind.value] = {
            'size': f'{width}x{height}',
            'frames': images,
            'seconds': seconds,
            'frames_per_s': images / seconds,
            'x_real_time': images / FPS / seconds,
            'states': stats.outputs['face/state'],
            'input_errors': dict(stats.errors),
        }
    return results
