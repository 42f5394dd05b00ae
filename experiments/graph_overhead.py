"""Two bundles' step and encoder in the engine against the same graph run alone on the same
feeds, in one process, alternated frame by frame (rig frame, 640x400, 16 LiDAR rows): what the
engine adds around its graphs, and how the two bundles' graphs compare at the same moment of
a host whose speed drifts. Median ms of 30 frames.

    python experiments/graph_overhead.py BUNDLE_A BUNDLE_B
"""

import statistics
import sys
import time

import numpy as np

from edge_depth.runtime.engine import Engine
from edge_depth.sim import RigConfig, make_sample

s = make_sample(1_000_000, RigConfig(), "beams16")
sp, v = s.sparse_disparity("left")
sp = (sp * v).astype(np.float32)
engs = {b: Engine(b, threads=2) for b in sys.argv[1:]}
for e in engs.values():
    e.warm_up()
rec: dict = {}
for b, e in engs.items():
    r: dict = {}
    e.infer(s.left, s.right, sp, record=r)
    rec[b] = r
res: dict = {b: {"engine_steps": [], "step_alone": [], "enc_alone": [], "engine_enc": []}
             for b in engs}
for _ in range(30):
    for b, e in engs.items():
        out = e.infer(s.left, s.right, sp)
        res[b]["engine_steps"].append(out.timings_ms["step_mean"])
        res[b]["engine_enc"].append(out.timings_ms["encoder"])
        for part, key in (("step", "step_alone"), ("encoder", "enc_alone")):
            t = time.perf_counter()
            e.sessions[part].run(rec[b][part][0])
            res[b][key].append((time.perf_counter() - t) * 1000)
for b in engs:
    print(b, {k: round(statistics.median(v), 2) for k, v in res[b].items()})
