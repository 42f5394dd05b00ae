"""Worker processes that use one core each.

numpy's BLAS (OpenBLAS) and OpenCV each start a thread per core in every process. A pool of N
workers on an N-core machine then runs N² busy threads: on a 16-core machine `edge-depth synth
--workers 16` rendered one pair a second instead of 6.8, and training beside it ran five to
seven times slower (docs/experiments.md). Every pool of ours starts its workers inside
`one_thread_each`.

The limits are set in the parent, around the moment the workers start, and not in the
workers: a forked worker that reconfigures a thread pool its parent had running can hang
(seen here: `cv2.setNumThreads` / `openblas_set_num_threads` in a pool's initializer hung a
worker forked from a process that had rendered before). Forked workers inherit the limits;
spawned ones read them from the environment.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterator
from contextlib import contextmanager

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "OPENCV_FOR_THREADS_NUM")


@contextmanager
def one_thread_each() -> Iterator[None]:
    """Within the block this process's BLAS and OpenCV run one thread, and so does every
    worker process started inside it (forked or spawned); on leaving, the parent's own
    settings come back."""
    import cv2
    from threadpoolctl import threadpool_limits

    saved_env = {k: os.environ.get(k) for k in THREAD_VARIABLES}
    saved_cv = cv2.getNumThreads()
    os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    cv2.setNumThreads(1)
    try:
        with threadpool_limits(1, user_api="blas"):
            yield
    finally:
        cv2.setNumThreads(saved_cv)
        for k, v in saved_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@functools.cache
def one_openblas_thread() -> list[str]:
    """Sets every OpenBLAS loaded in this process (numpy's, scipy's and the one OpenCV's wheel
    bundles for `cv2.gemm`) to one thread, once; the libraries set. Their worker threads spin
    for ~0.1 s after each multi-threaded call: on a 2-core host the LiDAR projection's matmul
    and the selections' gemm left one spinning through what came next, so the engine's graphs
    and OpenCV's own parallel calls ran on one core for part of every frame (SGBM 14 → 20–27
    ms after them, the engine 3–5 ms slower; `experiments/blas_threads_ab.py`,
    docs/experiments.md). Every BLAS call of the pipeline is small. Called by the engine:
    an application that loads one gets this for its whole process."""
    from threadpoolctl import ThreadpoolController

    libs = ThreadpoolController().select(internal_api="openblas").lib_controllers
    for lib in libs:
        lib.set_num_threads(1)
    return [lib.filepath for lib in libs]


def thread_counts() -> dict[str, int]:
    """This process's thread pools: OpenCV's and each BLAS / OpenMP library loaded."""
    import cv2
    import numpy  # noqa: F401  (its BLAS is what threadpoolctl reports)
    from threadpoolctl import threadpool_info

    counts = {"opencv": cv2.getNumThreads()}
    for pool in threadpool_info():
        counts[pool["internal_api"]] = pool["num_threads"]
    return counts
