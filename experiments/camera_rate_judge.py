"""Depth at the camera's rate judged on the moving worlds against its targets: the
frames between scans against the key frames (all pixels, and the moving object's own), and
the temporal instability after the known motion against the engine run on every frame.

    python experiments/camera_rate_judge.py [--kinds forward,turn,mover] [--seeds 1000000]
        [--frames 30] [--fps 30] [--every 3]

For each kind and seed, `--frames` frames of `edge.sim.motion`'s world at `--fps`, a scan on
every `--every`th frame (its key frame). Methods:
- per frame: the shipped engine on every frame with the last scan (the LiDAR's rate, were
  the engine fast enough: what the daemon's nearest pairing gives a frame);
- flow: the engine on key frames, `edge.runtime.propagate.Propagator.carry` between them
  with the disparity as the key frame's (the fitted motion's depth change switched off);
- flow+motion: the same with the depth change of the camera's motion fitted to the flow
  (`propagate.depth_change`), as the daemon runs it.
Per method: EPE px / bad-3 % on key frames and on frames between, their ratio; on the
mover's pixels (`edge.sim.motion.mover_mask`) the same ratio; the temporal instability
(`edge.metrics.temporal_instability`) after the known motion (`positions_then`) and without
it; and the median ms of a frame between scans.
"""

from __future__ import annotations

import argparse
import time
from unittest import mock

import numpy as np

from edge_depth.metrics import disparity_metrics, error_map, temporal_instability
from edge_depth.runtime import propagate
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.motion import KINDS, mover_mask, moving_sample, positions_then
from edge_depth.sim.scene import RigConfig

METHODS = ("per frame", "flow", "flow+motion")


def sequence(kind: str, seed: int, args, rig: RigConfig) -> list:
    period = 1.0 / args.fps
    return [moving_sample(seed, i * period, KINDS[kind], rig, frame=i)
            for i in range(args.frames)]


def outputs(samples, args, engine: Engine, rig: RigConfig) -> dict[str, list]:
    """Each method's disparity per frame and its ms (a key frame's: the engine's)."""
    per_frame, ms, sparse = [], [], None
    for i, s in enumerate(samples):
        if i % args.every == 0:
            sparse, _ = s.sparse_disparity()
        t = time.perf_counter()
        per_frame.append(engine.infer(s.left, s.right, sparse).disparity)
        ms.append((time.perf_counter() - t) * 1000)
    out = {"per frame": list(zip(per_frame, ms, strict=True))}
    for name, scaled in (("flow", False), ("flow+motion", True)):
        carry, frames = propagate.Propagator(), []
        with mock.patch.object(propagate, "depth_change",
                               propagate.depth_change if scaled else lambda *a, **k: None):
            for i, s in enumerate(samples):
                stamp = int(i * 1e9 / args.fps)
                if i % args.every == 0:
                    result = engine.infer(s.left, s.right, s.sparse_disparity()[0])
                    carry.key(stamp, i, s.left, result)
                    frames.append((result.disparity, ms[i]))
                    continue
                t = time.perf_counter()
                carried = carry.carry(stamp, s.left, rig.focal_px, rig.baseline_m,
                                      (rig.cx, rig.cy))
                assert carried is not None, "the flow is lost on a moving world"
                frames.append((carried.disparity, (time.perf_counter() - t) * 1000))
        out[name] = frames
    return out


def judge(kind: str, seed: int, args, engine: Engine) -> dict[str, dict]:
    rig = RigConfig()
    samples = sequence(kind, seed, args, rig)
    movers = [mover_mask(seed, i / args.fps, KINDS[kind], s.disp_left, rig)
              for i, s in enumerate(samples)]
    then = [None] + [positions_then(seed, i / args.fps, (i - 1) / args.fps, KINDS[kind],
                                    s.disp_left, samples[i - 1].disp_left, rig)
                     for i, s in enumerate(samples) if i]
    rows = {}
    for name, frames in outputs(samples, args, engine, rig).items():
        r: dict[str, list] = {k: [] for k in ("key", "between", "mkey", "mbetween", "ms",
                                              "stable", "raw")}
        errors = []
        for i, ((disp, ms), s) in enumerate(zip(frames, samples, strict=True)):
            part = "key" if i % args.every == 0 else "between"
            m = disparity_metrics(disp, s.disp_left)
            r[part].append((m["epe"], m["bad3"]))
            if movers[i].any():
                r["m" + part].append(disparity_metrics(disp, s.disp_left, movers[i])["epe"])
            if part == "between":
                r["ms"].append(ms)
            errors.append(error_map(disp, s.disp_left))
            if i:
                r["stable"].append(temporal_instability(errors[i], errors[i - 1], then[i]))
                r["raw"].append(temporal_instability(errors[i], errors[i - 1]))
        rows[name] = {k: np.nanmean(v, axis=0) if k not in ("ms",) else np.median(v)
                      for k, v in r.items()}
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--kinds", default="forward,turn,mover")
    p.add_argument("--seeds", default="1000000")
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--every", type=int, default=3)
    args = p.parse_args()
    engine = Engine(options=EngineOptions())
    print("| kind | seed | method | key EPE / bad-3 | between EPE / bad-3 | between / key | "
          "mover between / key | instability (after motion; raw) | vs per frame | "
          "ms between |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for kind in args.kinds.split(","):
        for seed in (int(x) for x in args.seeds.split(",")):
            rows = judge(kind, seed, args, engine)
            base = rows["per frame"]["stable"]
            for name in METHODS:
                r = rows[name]
                print(f"| {kind} | {seed} | {name} | {r['key'][0]:.4f} / {r['key'][1]:.2f} | "
                      f"{r['between'][0]:.4f} / {r['between'][1]:.2f} | "
                      f"{r['between'][0] / r['key'][0]:.2f} | "
                      f"{r['mbetween'] / r['mkey']:.2f} | {r['stable']:.4f}; {r['raw']:.4f} | "
                      f"{r['stable'] / base:.2f} | {r['ms']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
