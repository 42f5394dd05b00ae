"""How far a key frame's depth carries to the frames between scans, on the moving worlds
(`edge.sim.motion`): a probe for depth at the camera's rate, nothing in the daemon.

    python experiments/propagation_probe.py [--kinds forward,turn,mover] [--frames 30]
        [--fps 30] [--every 3] [--seed 1000000]

For each kind, a sequence of `--frames` frames at `--fps` with a scan on every `--every`th:
- per frame: the shipped engine on every frame with the last scan (what the daemon's nearest
  pairing gives a frame between scans);
- hold: the engine on the frames with a scan (key frames), the key frame's disparity held on
  the frames between;
- turned: the same, warped by the camera's turn between the key frame and the frame as
  `edge.camera_turn.TurnMeter` measures it from the left images (a rotation about the
  vertical axis: the homography K R K⁻¹; no translation, no independent motion);
- flow: the same, carried along the optical flow from the frame's left image to the key
  frame's (OpenCV's DIS, its ultrafast preset): any motion, the disparity itself unchanged.
EPE px / bad-3 % on key and in-between frames, the temporal instability over the sequence
(`edge.metrics.temporal_instability`) and each method's median time a frame.
"""

from __future__ import annotations

import argparse
import math
import time

import cv2
import numpy as np

from edge_depth.camera_turn import TurnMeter
from edge_depth.metrics import disparity_metrics, error_map, temporal_instability
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim.motion import KINDS, moving_sample
from edge_depth.sim.scene import RigConfig


def turn_warp(disparity: np.ndarray, yaw_deg: float, rig: RigConfig) -> np.ndarray:
    """A disparity map seen after the camera turned by `yaw_deg` (right positive) about its
    vertical axis: K R K⁻¹ (disparity kept: a turn of a few degrees barely changes depth)."""
    yaw = math.radians(yaw_deg)
    K = np.array([[rig.focal_px, 0, rig.cx], [0, rig.focal_px, rig.cy], [0, 0, 1.0]])
    R = np.array([[math.cos(yaw), 0, -math.sin(yaw)], [0, 1, 0],
                  [math.sin(yaw), 0, math.cos(yaw)]])
    H = K @ R @ np.linalg.inv(K)
    return cv2.warpPerspective(disparity, H, disparity.shape[::-1], flags=cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_REPLICATE)


def flow_warp(disparity: np.ndarray, key_left: np.ndarray, left: np.ndarray, dis) -> np.ndarray:
    """The key frame's disparity carried to the current frame along the optical flow from the
    current left image to the key frame's (OpenCV's DIS): each pixel takes the key frame's
    disparity where its content was then."""
    flow = dis.calc(left, key_left, None)
    h, w = left.shape
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(disparity, xs + flow[..., 0], ys + flow[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def run_kind(kind: str, args, engine: Engine) -> dict:
    rig = RigConfig()
    period = 1.0 / args.fps
    samples = [moving_sample(args.seed, i * period, KINDS[kind], rig, frame=i)
               for i in range(args.frames)]
    rows: dict[str, dict[str, list]] = {m: {"key": [], "between": [], "errors": [], "ms": []}
                                        for m in ("per frame", "hold", "turned", "flow")}
    dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
    key_left = None
    sparse = None
    key_disp = None
    meter = TurnMeter(rig.focal_px)
    turn_since_key = 0.0
    for i, s in enumerate(samples):
        is_key = i % args.every == 0
        if is_key:
            sparse, _ = s.sparse_disparity()
        t = time.perf_counter()
        per_frame = engine.infer(s.left, s.right, sparse).disparity
        engine_ms = (time.perf_counter() - t) * 1000
        t = time.perf_counter()
        meter.frame(int(i * period * 1e9), s.left)
        rate = meter.rate() if i > 0 else None
        turn_ms = (time.perf_counter() - t) * 1000
        if is_key:
            key_disp, turn_since_key, key_left = per_frame, 0.0, s.left
            held, turned, flowed, cost, flow_ms = per_frame, per_frame, per_frame, engine_ms, \
                engine_ms
        else:
            # TurnMeter's rate is positive when the image moves right: the camera turning left
            turn_since_key -= (rate or 0.0) * period
            t = time.perf_counter()
            turned = turn_warp(key_disp, turn_since_key, rig)
            cost = turn_ms + (time.perf_counter() - t) * 1000
            held = key_disp
            t = time.perf_counter()
            flowed = flow_warp(key_disp, key_left, s.left, dis)
            flow_ms = (time.perf_counter() - t) * 1000
        for name, disp, ms in (("per frame", per_frame, engine_ms), ("hold", held, 0.0),
                               ("turned", turned, cost), ("flow", flowed, flow_ms)):
            m = disparity_metrics(disp, s.disp_left)
            rows[name]["key" if is_key else "between"].append((m["epe"], m["bad3"]))
            rows[name]["errors"].append(error_map(disp, s.disp_left))
            rows[name]["ms"].append(ms if not is_key or name == "per frame" else engine_ms)
    out = {}
    for name, r in rows.items():
        pairs = zip(r["errors"], r["errors"][1:], strict=False)  # consecutive frames
        instability = [temporal_instability(b, a) for a, b in pairs]
        out[name] = dict(key=np.mean(r["key"], axis=0).tolist(),
                         between=np.mean(r["between"], axis=0).tolist(),
                         instability=float(np.nanmean(instability)),
                         between_ms=float(np.median([ms for i, ms in enumerate(r["ms"])
                                                     if i % args.every])))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--kinds", default="forward,turn,mover")
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--every", type=int, default=3)
    p.add_argument("--seed", type=int, default=1_000_000)
    args = p.parse_args()
    engine = Engine(options=EngineOptions())
    print("| kind | method | key EPE / bad-3 | between EPE / bad-3 | between / key EPE | "
          "instability | ms a frame between |")
    print("|---|---|---|---|---|---|---|")
    for kind in args.kinds.split(","):
        for name, r in run_kind(kind, args, engine).items():
            ratio = r["between"][0] / r["key"][0]
            print(f"| {kind} | {name} | {r['key'][0]:.3f} / {r['key'][1]:.2f} | "
                  f"{r['between'][0]:.3f} / {r['between'][1]:.2f} | {ratio:.2f} | "
                  f"{r['instability']:.3f} | {r['between_ms']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
