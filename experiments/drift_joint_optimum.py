"""Where PhotometricCost (blur 1) is lowest over the three rotations, searched from the right
calibration on N sim rig frames (every 10th seed from SEED), each thinned to POINTS points:

    python experiments/drift_joint_optimum.py SEED N POINTS
"""

from __future__ import annotations

import sys

import numpy as np
from scipy.optimize import minimize

from edge_depth.calibration.extrinsics import PhotometricCost, _perturb
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.lidar import default_T_cam_lidar


def main() -> None:
    seed, n, points = (int(a) for a in sys.argv[1:4])
    samples = [make_sample(seed + 10 * i, RigConfig(), "beams16") for i in range(n)]
    calib, T = samples[0].calibration(), default_T_cam_lidar()
    frames = []
    for s in samples:
        p = s.scan.points
        frames.append((s.left, s.right,
                       p[np.linspace(0, len(p) - 1, min(points, len(p))).astype(int)]))
    cost = PhotometricCost(frames, calib, T, 1.0)

    def at(x: np.ndarray) -> float:
        return cost(_perturb(T, np.r_[x, 0.0, 0.0, 0.0]))

    result = minimize(at, np.zeros(3), method="Nelder-Mead",
                      options=dict(initial_simplex=np.vstack([np.zeros(3), np.eye(3) * 0.3]),
                                   xatol=0.005, fatol=1e-7, maxfev=300))
    print(seed, n, points, "optimum pitch/yaw/roll (deg)", np.round(result.x, 3), result.nfev)


if __name__ == "__main__":
    main()
