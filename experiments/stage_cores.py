"""How many cores each of the engine's stages keeps busy: wall time against the process's CPU
time (all its threads) per stage, on the bench's frames. A stage at ~1 core on a two-core
robot leaves the other idle.

    python experiments/stage_cores.py [--scenes 4] [--rounds 5]
    bash experiments/avx2_kernels.sh python experiments/stage_cores.py
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

from bench import bench_frames  # noqa: E402

from edge_depth.runtime.backends import cpu_description  # noqa: E402
from edge_depth.runtime.engine import Engine  # noqa: E402

STAGES = ("_prepare", "_encode", "_iterate", "_upsample", "_select", "_match", "_median")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args()
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    engine = Engine()
    engine.warm_up()
    _, _, _, inputs = bench_frames(engine.width, engine.height, args.scenes)
    wall: dict[str, list[float]] = {s: [] for s in STAGES}
    cpu_ms: dict[str, list[float]] = {s: [] for s in STAGES}

    def timed(name, fn):
        def run(*a, **k):
            w, c = time.perf_counter(), time.process_time()
            out = fn(*a, **k)
            wall[name].append((time.perf_counter() - w) * 1000)
            cpu_ms[name].append((time.process_time() - c) * 1000)
            return out
        return run

    for name in STAGES:
        setattr(engine, name, timed(name, getattr(engine, name)))
    totals = []
    for _ in range(args.rounds):
        for frame in inputs:
            w, c = time.perf_counter(), time.process_time()
            engine.infer(*frame)
            totals.append(((time.perf_counter() - w) * 1000, (time.process_time() - c) * 1000))
    print("| stage | wall ms | CPU ms | cores busy |")
    print("|---|---|---|---|")
    for name in STAGES:
        if wall[name]:
            mw, mc = statistics.median(wall[name]), statistics.median(cpu_ms[name])
            print(f"| {name.strip('_')} | {mw:.1f} | {mc:.1f} | {mc / max(mw, 1e-9):.2f} |")
    mw = statistics.median(t[0] for t in totals)
    mc = statistics.median(t[1] for t in totals)
    print(f"| engine | {mw:.1f} | {mc:.1f} | {mc / mw:.2f} |")


if __name__ == "__main__":
    main()
