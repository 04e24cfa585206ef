"""BLAS runs on one thread in the package's processes (face_tracking_ros.threads)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from threadpoolctl import threadpool_info

from face_tracking_ros.threads import limit_blas_threads

PROBE = """
import json
import numpy, scipy.linalg
from threadpoolctl import threadpool_info
from face_tracking_ros.threads import limit_blas_threads
def blas():
    return {info['filepath']: info['num_threads'] for info in threadpool_info()
            if info['user_api'] == 'blas'}
before = blas()
limit_blas_threads()
import face_tracking_ros.tracking.mono  # loads more BLAS copies after the limit
print(json.dumps([before, blas()]))
"""


def test_every_blas_library_is_limited_also_those_loaded_later() -> None:
    env = {k: v for k, v in os.environ.items() if not k.endswith('_NUM_THREADS')}
    result = subprocess.run(
        [sys.executable, '-c', PROBE], env=env, capture_output=True, text=True, check=True
    )
    before, after = json.loads(result.stdout)
    assert set(after) > set(before)  # libraries were loaded after the call
    assert set(after.values()) == {1}, after


def test_limit_holds_in_this_process_and_is_passed_to_children() -> None:
    limit_blas_threads()
    assert os.environ['OPENBLAS_NUM_THREADS'] == '1'
    assert {info['num_threads'] for info in threadpool_info() if info['user_api'] == 'blas'} == {1}
