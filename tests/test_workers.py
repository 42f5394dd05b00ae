"""Worker processes of our pools run one BLAS and one OpenCV thread each."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import cv2
import numpy as np

from edge_depth.workers import one_thread_each, thread_counts


def blas_threads(counts: dict[str, int]) -> set[int]:
    blas = {v for k, v in counts.items() if k in ("openblas", "mkl", "blis")}
    assert blas, f"numpy's BLAS not seen by threadpoolctl: {counts}"
    return blas


def test_workers_started_inside_one_thread_each_run_one_thread_and_the_parent_gets_its_own_back():
    # the parent has used both libraries' threads before the fork, as a renderer has
    np.ones((300, 300)) @ np.ones((300, 300))
    cv2.GaussianBlur(np.zeros((512, 512), np.float32), (5, 5), 1.0)
    before = thread_counts()
    for method in ("fork", "spawn"):
        context = multiprocessing.get_context(method)
        with one_thread_each(), ProcessPoolExecutor(1, mp_context=context) as pool:
            counts = pool.submit(thread_counts).result(timeout=120)
        assert counts["opencv"] == 1 and blas_threads(counts) == {1}, (method, counts)
    assert thread_counts() == before


def test_an_engine_leaves_every_openblas_in_its_process_on_one_thread():
    # their threads spin after each call and took a core from the engine's graphs
    from threadpoolctl import threadpool_info

    from edge_depth.runtime.engine import Engine

    np.ones((300, 300)) @ np.ones((300, 300))  # the BLAS pool busy before, as a renderer's
    Engine(precision="fp32")
    openblas = [pool for pool in threadpool_info() if pool["internal_api"] == "openblas"]
    assert openblas and all(pool["num_threads"] == 1 for pool in openblas), openblas
