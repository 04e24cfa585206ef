"""One BLAS thread per process: the trackers' matrix products are too small to share out.

numpy's OpenBLAS starts a thread per core and keeps them spinning after each call. The
trackers' products are small (eq. 6's normal equations are 4114 x 11), so the extra threads
only burn the other core, which a live node's DDS threads need. Measured on a 300-frame
640x480 mono replay on this 2-core machine: 3.8 ms of CPU and 3.3 ms of wall time per frame
with two BLAS threads, 3.05 and 3.05 ms with one. With one thread the results also no longer
depend on the machine's core count: another thread count changes sums by about 1e-13, which a
long track can grow to 1e-5 rad. The benchmarks always measured with one thread (their
processes set ``OPENBLAS_NUM_THREADS=1``); the nodes and ``face-tracking`` now do the same.

A process loads several OpenBLAS copies (numpy's, scipy's and one more once the trackers are
imported), some only when first used, so both the loaded ones and the ones still to come are
limited.
"""

from __future__ import annotations

import os

from threadpoolctl import threadpool_limits

ONE_THREAD_ENV = {'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1'}
"""Thread limits that BLAS and OpenMP libraries read when they are loaded."""


def limit_blas_threads() -> None:
    """Limit BLAS to one thread in this process and its children, from now on.

    Libraries already loaded are limited through threadpoolctl; libraries loaded later, and
    child processes, read :data:`ONE_THREAD_ENV` from the environment.
    """
    os.environ.update(ONE_THREAD_ENV)
    threadpool_limits(limits=1, user_api='blas')
