"""What the engine's preparation costs inside the engine (caches and threads as a frame leaves
them), with the photometric match and the LiDAR alignment on and off: the shipped engine at
its defaults and one with both off, alternated frame by frame on the rig frame, `_prepare` and
each check timed where the engine calls them. Median ms.

    bash experiments/avx2_kernels.sh python experiments/prepare_cost.py [--frames 40]
"""

from __future__ import annotations

import argparse
import statistics
import time

from bundle_engine_ab import rig_frame

from edge_depth.runtime.engine import Engine


class _Timed:
    """A check (`apply`) that notes how long each call took."""

    def __init__(self, check, out: list[float]) -> None:
        self.check, self.out = check, out

    def apply(self, *args):
        t = time.perf_counter()
        result = self.check.apply(*args)
        self.out.append((time.perf_counter() - t) * 1000)
        return result


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=40)
    args = p.parse_args()
    sample, sparse = rig_frame()
    engines = {"defaults": Engine(), "both off": Engine(match_photometry=False,
                                                        align_lidar=False)}
    times: dict[str, list[float]] = {}
    for name, engine in engines.items():
        engine.warm_up()
        prepare, spent = engine._prepare, times.setdefault(f"{name}: prepare", [])

        def timed(*a, prepare=prepare, spent=spent):
            t = time.perf_counter()
            result = prepare(*a)
            spent.append((time.perf_counter() - t) * 1000)
            return result

        engine._prepare = timed  # type: ignore[method-assign]
        if engine.photometry is not None:
            engine.photometry = _Timed(engine.photometry, times.setdefault(
                f"{name}: photometry", []))
        if engine.lidar_align is not None:
            engine.lidar_align = _Timed(engine.lidar_align, times.setdefault(
                f"{name}: alignment", []))
    for _ in range(args.frames):
        for engine in engines.values():
            engine.infer(sample.left, sample.right, sparse)
    print(", ".join(f"{k} {statistics.median(v):.2f}" for k, v in times.items()))


if __name__ == "__main__":
    main()
