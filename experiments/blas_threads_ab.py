"""The engine against OpenCV's SGBM as `tools/bench.py` times them (its frames, its blocks of
every stage, then engine and SGBM back to back frame by frame) with the process's OpenBLAS
libraries (numpy's, scipy's, the one OpenCV's wheel bundles for `cv2.gemm`) at two threads
each, with only OpenCV's at one, and at one each (what the engine sets:
`edge.workers.one_openblas_thread`), each in a process of its own: the paired rounds' median
ms of each, their ratio, and how many SGBM calls took over 20 ms (its steady time here is ~14:
a core lost to a spinning thread).

    python experiments/blas_threads_ab.py [--rounds 3]
    python experiments/blas_threads_ab.py --openblas opencv-one   # one setting, this process
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

SETTINGS = ("two", "opencv-one", "engine")


def set_openblas(setting: str) -> None:
    """After the engines are built (which sets every OpenBLAS to one thread): two threads
    each again, or two but OpenCV's, or (the engine's) as they are."""
    from threadpoolctl import ThreadpoolController

    if setting == "engine":
        return
    for lib in ThreadpoolController().select(internal_api="openblas").lib_controllers:
        lib.set_num_threads(1 if setting == "opencv-one" and "opencv" in lib.filepath else 2)


def one_setting(setting: str, rounds: int) -> None:
    import cv2

    from edge_depth.capture.sim import SimSource
    from edge_depth.daemon import Pipeline
    from edge_depth.mcap_log import McapLogger
    from edge_depth.runtime.engine import Engine

    cv2.setNumThreads(2)
    rig, samples, dense, inputs = bench.bench_frames(640, 400, 4)
    matcher = bench.make_sgbm()
    engines = {p: Engine(precision=p, threads=2) for p in ("fp32", "int8")}
    set_openblas(setting)
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
        label = {"two": "every OpenBLAS at two threads",
                 "opencv-one": "OpenCV's OpenBLAS at one thread, the others at two",
                 "engine": "every OpenBLAS at one thread (the engine's)"}[setting]
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
    p.add_argument("--openblas", choices=SETTINGS, default=None,
                   help="run one setting in this process")
    args = p.parse_args()
    if args.openblas is not None:
        one_setting(args.openblas, args.rounds)
        return
    from edge_depth.runtime.backends import cpu_description

    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}", flush=True)
    for setting in SETTINGS:
        subprocess.run([sys.executable, __file__, "--rounds", str(args.rounds),
                        "--openblas", setting], check=True)


if __name__ == "__main__":
    main()
