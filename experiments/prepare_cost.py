"""What the engine's preparation costs inside the engine (caches and threads as a frame leaves
them), with the photometric match and the LiDAR alignment on and off: the shipped engine at
its defaults and one with both off, alternated frame by frame on the rig frame, `_prepare` and
each check timed where the engine calls them. Median ms. `--right-gain`: the right image
brightened by that factor first (1.12: beyond a calibrated pair, so the stages after the
network read it matched; the photometric change is printed).

    bash experiments/avx2_kernels.sh python experiments/prepare_cost.py [--frames 40] \
        [--right-gain 1.12]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from bundle_engine_ab import rig_frame

from edge_depth.runtime.engine import Engine


class _Timed:
    """A check (its `apply` or `measure`, or the check itself called) that notes how long each
    call took; any other attribute is the check's."""

    def __init__(self, check, out: list[float]) -> None:
        self.check, self.out = check, out

    def __getattr__(self, name):
        return getattr(self.check, name)

    def _timed(self, fn, *args):
        t = time.perf_counter()
        result = fn(*args)
        self.out.append((time.perf_counter() - t) * 1000)
        return result

    def apply(self, *args):
        return self._timed(self.check.apply, *args)

    def measure(self, *args):
        return self._timed(self.check.measure, *args)

    def __call__(self, *args):
        return self._timed(self.check, *args)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--right-gain", type=float, default=1.0)
    args = p.parse_args()
    sample, sparse = rig_frame()
    right = sample.right if args.right_gain == 1.0 else np.clip(
        sample.right.astype(np.float32) * args.right_gain, 0, 255).astype(np.uint8)
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
        # the right image the stages after the network read (matched or not)
        engine._matched_for_stages = _Timed(  # type: ignore[method-assign]
            engine._matched_for_stages, times.setdefault(f"{name}: stages' right", []))
        if engine.photometry is not None:
            engine.photometry = _Timed(engine.photometry, times.setdefault(
                f"{name}: photometry", []))
        if engine.lidar_align is not None:
            engine.lidar_align = _Timed(engine.lidar_align, times.setdefault(
                f"{name}: alignment", []))
    for _ in range(args.frames):
        for name, engine in engines.items():
            result = engine.infer(sample.left, right, sparse)
            if name == "defaults":
                change = result.photometry_change
    print(", ".join(f"{k} {statistics.median(v):.2f}" for k, v in times.items())
          + f" (the photometric change {change:.1f} levels)")


if __name__ == "__main__":
    main()
