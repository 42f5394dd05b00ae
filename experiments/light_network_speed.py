"""Candidate lighter networks timed before any is trained: each configuration with random
weights exported to a float bundle, then the network alone (encoder + N steps + upsampling;
no selection, no matching) timed on the frame the export check uses, median of F frames.

    ONEDNN_MAX_CPU_ISA=AVX2 python experiments/light_network_speed.py
    python experiments/light_network_speed.py --runtime onnxruntime

`ONEDNN_MAX_CPU_ISA=AVX2` limits OpenVINO's kernels to AVX2 on an AVX-512 host (the kernels
an AVX2-only CPU runs, not that CPU's speed). The configurations change only sizes the
training already takes (`tools/train.py --dims`, `--no-half-res-block`; `experiments/prune.py`
for the update block's widths), so a chosen one can be cut from the shipped checkpoint.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from edge_depth.model.config import ModelConfig
from edge_depth.model.network import SparseStereoNet
from edge_depth.runtime.backends import cpu_description
from edge_depth.runtime.engine import DEFAULT_BUNDLE, Engine

SHIPPED = json.loads((DEFAULT_BUNDLE / "model.json").read_text())["config"]
CANDIDATES = {
    "shipped": {},
    "update 32": dict(hidden_dim=32, motion_dim=32, head_dim=24, context_dim=24),
    "update 32 + features 32": dict(hidden_dim=32, motion_dim=32, head_dim=24, context_dim=24,
                                   feature_dim=32),
    "backbone 16/24/40": dict(widths=(16, 24, 40)),
    "update 32 + quarter 24": dict(widths=(16, 24, 48), hidden_dim=32, motion_dim=32,
                                  head_dim=24, context_dim=24),
    "backbone 12/24/32 + update 32 + features 32": dict(
        widths=(12, 24, 32), hidden_dim=32, motion_dim=32, head_dim=24, context_dim=24,
        feature_dim=32),
}


def bundle_for(config: dict, folder: Path) -> Path:
    from edge_depth.tools.export import export

    torch.manual_seed(0)
    net = SparseStereoNet(ModelConfig.from_dict(config))
    ckpt = folder / "random.pt"
    torch.save({"config": net.config.to_dict(), "model": net.state_dict(), "step": 0}, ckpt)
    export(ckpt, folder / "bundle", (640, 400), check=False)
    return folder / "bundle"


def network_ms(bundle: Path, runtime: str, iters: int, frames: int) -> float:
    from edge_depth.tools.export import reference_inputs

    engine = Engine(bundle, precision="fp32", runtime=runtime, threads=2, edge_match=0,
                    lidar_select=False, edge_select=False, bf16="off")
    feeds = reference_inputs((640, 400))
    left = feeds["left"][0, 0].astype(np.uint8)
    right = feeds["right"][0, 0].astype(np.uint8)
    sparse = feeds["sparse"][0, 0]
    engine.warm_up(camera=(640, 400))
    times = []
    for _ in range(frames):
        t = time.perf_counter()
        engine.infer(left, right, sparse, iters=iters)
        times.append((time.perf_counter() - t) * 1000)
    return statistics.median(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runtime", default="openvino", choices=("openvino", "onnxruntime"))
    p.add_argument("--iters", default="4,2", help="GRU iterations to time, comma-separated")
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--only", default=None, help="candidates' names, comma-separated")
    args = p.parse_args()
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}; {args.runtime}, fp32, 2 threads, "
          f"640x400, network only")
    iters = [int(i) for i in args.iters.split(",")]
    print("| candidate | params | GFLOP @4 | " + " | ".join(f"ms @{i}" for i in iters) + " |")
    print("|---|---|---|" + "---|" * len(iters))
    for name, change in CANDIDATES.items():
        if args.only and name not in args.only.split(","):
            continue
        with tempfile.TemporaryDirectory() as tmp:
            bundle = bundle_for({**SHIPPED, **change}, Path(tmp))
            meta = json.loads((bundle / "model.json").read_text())
            ms = [network_ms(bundle, args.runtime, i, args.frames) for i in iters]
        print(f"| {name} | {meta['params']:,} | {meta['flops']['iters_4'] / 1e9:.2f} | "
              + " | ".join(f"{m:.1f}" for m in ms) + " |", flush=True)


if __name__ == "__main__":
    main()
