"""The engine against OpenCV's SGBM as `tools/bench.py` times them (its frames, its blocks of
every stage, then engine and SGBM back to back frame by frame), with the OpenBLAS that OpenCV's
wheel bundles (what `cv2.gemm` runs on) at its own thread count and at one, each in a process
of its own: the paired rounds' median ms of each, their ratio, and how many SGBM calls took
over 20 ms (its steady time here is ~14: a core lost to a spinning thread).

    python experiments/blas_threads_ab.py [--rounds 3]
    python experiments/blas_threads_ab.py --opencv-blas-threads 1   # one setting, this process
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

import bench  # noqa: E402  (tools/bench.py: the frames and blocks it times)


def opencv_blas(threads: int) -> list[str]:
    """Sets the OpenBLAS libraries OpenCV's wheel bundles to `threads`; their paths."""
    from threadpoolctl import ThreadpoolController

    libs = [lib for lib in ThreadpoolController().lib_controllers
            if lib.internal_api == "openblas" and "opencv" in lib.filepath]
    for lib in libs:
        lib.set_num_threads(threads)
    return [Path(lib.filepath).name for lib in libs]


def one_setting(threads: int | None, rounds: int) -> None:
    import cv2

    from edge_depth.capture.sim import SimSource
    from edge_depth.daemon import Pipeline
    from edge_depth.mcap_log import McapLogger
    from edge_depth.runtime.engine import Engine

    cv2.setNumThreads(2)
    libs = opencv_blas(threads) if threads else []
    rig, samples, dense, inputs = bench.bench_frames(640, 400, 4)
    matcher = bench.make_sgbm()
    engines = {p: Engine(precision=p, threads=2) for p in ("fp32", "int8")}
    clock = bench.StageClock(engines, 4)
    with tempfile.TemporaryDirectory() as tmp:
        logger = McapLogger(Path(tmp) / "bench.mcap")
        pipeline = Pipeline(engines["int8"], *SimSource(1, bench.TEST_SEED0, rig).calibration,
                            logger)
        stages = bench.daemon_stages(rig, samples, dense, inputs, engines["int8"], logger,
                                     pipeline)
        methods = bench.timed_methods(stages, samples, inputs, matcher, clock, [4])
        for fn, args_list in methods.values():  # one block of every stage, as the bench
            bench._timed(fn, args_list, [])
        label = f"OpenCV's OpenBLAS at {threads} thread(s) {libs}" if threads else \
            "OpenCV's OpenBLAS at its own thread count"
        for r in range(rounds):
            ms: dict[str, list[float]] = {"engine": [], "sgbm": []}
            for k in range(3 * len(inputs)):
                left, right, sparse = inputs[k % len(inputs)]
                for name in ("engine", "sgbm") if k % 2 == 0 else ("sgbm", "engine"):
                    t = time.perf_counter()
                    if name == "engine":
                        engines["int8"].infer(left, right, sparse)
                    else:
                        bench.sgbm_disparity(left, right, matcher)
                    ms[name].append((time.perf_counter() - t) * 1000)
            e, s = statistics.median(ms["engine"]), statistics.median(ms["sgbm"])
            print(f"{label}, round {r + 1}: engine {e:.1f}, SGBM {s:.1f} ms, {e / s:.2f}×; "
                  f"SGBM calls over 20 ms: {sum(x > 20 for x in ms['sgbm'])} of "
                  f"{len(ms['sgbm'])}", flush=True)
        logger.close()


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--opencv-blas-threads", type=int, default=None,
                   help="run one setting in this process (0: leave it as it is)")
    args = p.parse_args()
    if args.opencv_blas_threads is not None:
        one_setting(args.opencv_blas_threads, args.rounds)
        return
    from edge_depth.runtime.backends import cpu_description

    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}", flush=True)
    for threads in (0, 1):
        subprocess.run([sys.executable, __file__, "--rounds", str(args.rounds),
                        "--opencv-blas-threads", str(threads)], check=True)


if __name__ == "__main__":
    main()
