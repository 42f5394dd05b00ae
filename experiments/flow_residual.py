"""What `edge.runtime.propagate`'s lost-flow check reads on the moving sim worlds: the key
frame's left image carried along DIS optical flow to the frames 1, 2 and 3 after it, mean
|Δ| against each (grey levels), and the same against another scene (a cut).

    python experiments/flow_residual.py [--seed 1000000]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from edge_depth.sim.motion import KINDS, moving_sample


def residual(flow, key: np.ndarray, frame: np.ndarray) -> float:
    field = flow.calc(frame, key, None)
    h, w = frame.shape
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    carried = cv2.remap(key, xs + field[..., 0], ys + field[..., 1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
    return float(np.mean(cv2.absdiff(carried, frame)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seed", type=int, default=1_000_000)
    args = p.parse_args()
    flow = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
    for kind in ("forward", "turn", "mover"):
        frames = [moving_sample(args.seed, i / 30, KINDS[kind], frame=i).left for i in range(4)]
        print(kind, [round(residual(flow, frames[0], frames[k]), 2) for k in (1, 2, 3)])
    other = moving_sample(args.seed + 1, 0.0, KINDS["still"]).left
    print("another scene", round(residual(flow, frames[0], other), 2))


if __name__ == "__main__":
    main()
