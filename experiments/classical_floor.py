"""The engine's floor without its graphs: the shipped engine on the bench's frames, alternated
frame by frame with the same engine whose three graphs answer instantly (each returns what the
real graph returned for that frame and call), and SGBM on the same frames. What is left is
what the engine costs outside the network (preparation, selection, the matching's StereoBM and
choice, the median, depth) — the part no smaller network removes; it includes copying the
recorded answers (~0.3 ms a frame).

    python experiments/classical_floor.py [--scenes 4] [--rounds 10]
    bash experiments/avx2_kernels.sh python experiments/classical_floor.py
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))

from bench import bench_frames  # noqa: E402

from edge_depth.baselines import make_sgbm, sgbm_disparity  # noqa: E402
from edge_depth.runtime.backends import cpu_description  # noqa: E402
from edge_depth.runtime.engine import Engine  # noqa: E402


class _Recorded:
    """A graph that answers each call of a frame with what the real graph answered to it."""

    def __init__(self, session) -> None:
        self.session, self.answers, self.calls = session, {}, 0
        self.frame = 0

    def __getattr__(self, name):
        return getattr(self.session, name)

    def record(self, frame: int, feeds: dict) -> list:
        out = [o.copy() for o in self.session.run(feeds)]
        self.answers[(frame, self.calls)] = out
        self.calls += 1
        return out

    def run(self, feeds: dict) -> list:
        out = self.answers[(self.frame, self.calls)]
        self.calls += 1
        return [o.copy() for o in out]  # the engine may write into what it is given


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--rounds", type=int, default=10)
    args = p.parse_args()
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    real, floor = Engine(), Engine()
    real.warm_up()
    floor.warm_up()
    _, _, _, inputs = bench_frames(real.width, real.height, args.scenes)
    graphs = {k: _Recorded(s) for k, s in floor.sessions.items()}
    for i, frame in enumerate(inputs):  # each frame's answers, from the real graphs
        for g in graphs.values():
            g.calls = 0
        for name, g in graphs.items():
            floor.sessions[name] = _Recording(g, i)
        floor.infer(*frame)
    for name, g in graphs.items():
        floor.sessions[name] = g
    matcher = make_sgbm()
    times: dict[str, list[float]] = {"engine": [], "floor": [], "sgbm": []}
    stages: dict[str, list[float]] = {}
    for _ in range(args.rounds):
        for i, frame in enumerate(inputs):
            t = time.perf_counter()
            real.infer(*frame)
            times["engine"].append((time.perf_counter() - t) * 1000)
            for g in graphs.values():
                g.frame, g.calls = i, 0
            t = time.perf_counter()
            result = floor.infer(*frame)
            times["floor"].append((time.perf_counter() - t) * 1000)
            for k, v in result.timings_ms.items():
                stages.setdefault(k, []).append(v)
            t = time.perf_counter()
            sgbm_disparity(frame[0], frame[1], matcher)
            times["sgbm"].append((time.perf_counter() - t) * 1000)
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"engine {med['engine']:.1f} ms, its floor without graphs {med['floor']:.1f} ms, "
          f"SGBM {med['sgbm']:.1f} ms ({args.rounds} rounds of {len(inputs)} frames)")
    print(f"engine / SGBM {med['engine'] / med['sgbm']:.2f}x; floor / SGBM "
          f"{med['floor'] / med['sgbm']:.2f}x; what 2x SGBM leaves the graphs: "
          f"{2 * med['sgbm'] - med['floor']:.1f} ms against "
          f"{med['engine'] - med['floor']:.1f} now")
    print("floor's stages, median ms: " + ", ".join(
        f"{k} {statistics.median(v):.1f}" for k, v in stages.items()))


class _Recording:
    """Passes a frame's calls to the real graph and keeps their answers."""

    def __init__(self, graph: _Recorded, frame: int) -> None:
        self.graph, self.frame = graph, frame

    def __getattr__(self, name):
        return getattr(self.graph.session, name)

    def run(self, feeds: dict) -> list:
        return self.graph.record(self.frame, feeds)


if __name__ == "__main__":
    main()
