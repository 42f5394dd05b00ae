"""Throughput of one engine on two threads against two engines on one thread each, run on two
Python threads over the same four rig frames (640x400, 16 LiDAR rows): frames/s, and the two
engines' median latency. Would a daemon that hands frames to two engines run more of them?

    python experiments/two_engines.py [--frames 40] [--runs 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

import bench  # noqa: E402  (tools/bench.py: the frames it times)

from edge_depth.runtime.backends import cpu_description  # noqa: E402
from edge_depth.runtime.engine import Engine  # noqa: E402


def serial(engine: Engine, frames: list, count: int) -> float:
    t = time.perf_counter()
    for i in range(count):
        engine.infer(*frames[i % len(frames)])
    return count / (time.perf_counter() - t)


def parallel(engines: list[Engine], frames: list, count: int) -> tuple[float, float]:
    latency: list[float] = []

    def work(engine: Engine, first: int) -> None:
        for i in range(first, count, len(engines)):
            t = time.perf_counter()
            engine.infer(*frames[i % len(frames)])
            latency.append((time.perf_counter() - t) * 1000)

    threads = [threading.Thread(target=work, args=(e, k)) for k, e in enumerate(engines)]
    t = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return count / (time.perf_counter() - t), statistics.median(latency)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args()
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    frames = bench.bench_frames(640, 400, 4)[3]  # the bench's engine inputs
    one = Engine(threads=2)
    two = [Engine(threads=1), Engine(threads=1)]
    for engine in (one, *two):
        engine.warm_up()
    for run in range(args.runs):
        alone = serial(one, frames, args.frames)
        together, latency = parallel(two, frames, args.frames)
        print(f"run {run + 1}: one engine, 2 threads {alone:.1f} frames/s; two engines, 1 "
              f"thread each {together:.1f} frames/s (latency median {latency:.0f} ms)")


if __name__ == "__main__":
    main()
