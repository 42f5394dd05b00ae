"""The upsampling graph exported from the shipped checkpoint twice — the convex sum as the 5-D
view (`network.convex_upsample`, what the shipped bundle's upsample.onnx holds) and written out
neighbour by neighbour (`convex_upsample_unrolled` here) — on the engine's own feeds (the last
step's disparity and hidden state of four rig test scenes): how far their outputs lie from the
shipped graph's, and their time on OpenVINO and on ONNX Runtime, alternated call by call
(median ms per run).

    python experiments/upsample_unrolled.py [--out runs/upsample_unrolled] [--calls 100] [--runs 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from edge_depth.model.cspn import patches_3x3
from edge_depth.runtime.backends import OpenVinoSession, OrtSession, cpu_description
from edge_depth.runtime.engine import Engine
from edge_depth.sim import RigConfig, make_sample
from edge_depth.tools.export import OPSET, load_checkpoint

SHIPPED = Path("edge/models/default")


def convex_upsample_unrolled(disparity, mask, factor: int, logit):
    """`network.convex_upsample` with its sum over the 9 neighbours written out, one slice of
    the mask at a time (the same values up to float rounding): exported, each neighbour's
    exp, products and sums are one chain of element-wise nodes over a (B, f², h, w) slice."""
    f2 = factor * factor
    values = [patches_3x3(disparity * factor), patches_3x3(logit)]

    def weight(k: int):
        return torch.exp(mask[:, k * f2:(k + 1) * f2].clamp(-30.0, 30.0))

    total = weight(0)
    sums = [total * patches[:, :1] for patches in values]
    for k in range(1, 9):
        w_k = weight(k)
        total = total + w_k
        sums = [s + w_k * patches[:, k:k + 1] for s, patches in zip(sums, values, strict=True)]
    return [F.pixel_shuffle(s / total, factor) for s in sums]


class Upsample(torch.nn.Module):
    """The shipped bundle's upsampling graph (`tools/export.py`), the convex sum either way."""

    def __init__(self, net, unrolled: bool) -> None:
        super().__init__()
        self.net, self.unrolled = net, unrolled

    def forward(self, disparity, hidden):
        mask = self.net.update.upsampling_mask(hidden)
        if not self.unrolled:
            full, logit = self.net.upsample(disparity, mask, hidden)
            return full, torch.sigmoid(logit)
        logit = self.net.refine(hidden, disparity)
        full, logits = convex_upsample_unrolled(disparity, mask, self.net.config.downsample,
                                                logit)
        return full, torch.sigmoid(logits)


def engine_feeds(scenes: int) -> list[dict[str, np.ndarray]]:
    """The upsampling's inputs as the engine makes them for `scenes` rig test scenes."""
    engine = Engine(SHIPPED, threads=2)
    feeds = []
    for i in range(scenes):
        sample = make_sample(1_000_000 + i, RigConfig(), "beams16")
        sparse, valid = sample.sparse_disparity("left")
        record: dict[str, list] = {}
        engine.infer(sample.left, sample.right, (sparse * valid).astype(np.float32),
                     record=record)
        feeds.append(record["upsample"][0])
    return feeds


def export(net, unrolled: bool, path: Path, feeds: dict) -> None:
    args = tuple(torch.from_numpy(feeds[k]) for k in ("disparity", "hidden"))
    dynamic = {"disparity": {2: "h", 3: "w"}, "hidden": {2: "h", 3: "w"},
               "disparity_full": {2: "H", 3: "W"}, "confidence": {2: "H", 3: "W"}}
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(Upsample(net, unrolled), args, str(path),
                          input_names=["disparity", "hidden"],
                          output_names=["disparity_full", "confidence"], opset_version=OPSET,
                          dynamo=False, dynamic_axes=dynamic)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--out", type=Path, default=Path("runs/upsample_unrolled"))
    p.add_argument("--calls", type=int, default=100)
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args()
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    args.out.mkdir(parents=True, exist_ok=True)
    net, _ = load_checkpoint(Path("edge/models/sparse_stereo.pt"))
    feeds = engine_feeds(4)
    graphs = {"shipped": SHIPPED / "upsample.onnx"}
    for name, unrolled in (("5-D view", False), ("unrolled", True)):
        graphs[name] = args.out / f"upsample_{'unrolled' if unrolled else 'view'}.onnx"
        export(net, unrolled, graphs[name], feeds[0])
    for runtime, session_type in (("OpenVINO", OpenVinoSession), ("ONNX Runtime", OrtSession)):
        sessions = {name: session_type(path, 2) for name, path in graphs.items()}
        outputs = {name: [s.run(f) for f in feeds] for name, s in sessions.items()}
        for name in ("5-D view", "unrolled"):
            gaps = [np.abs(a - b).max() for o, r in zip(outputs[name], outputs["shipped"],
                                                          strict=True)
                    for a, b in zip(o, r, strict=True)]
            print(f"{runtime}, {name}: largest difference from the shipped graph's outputs "
                  f"{max(gaps):.2e}")
        for run in range(args.runs):
            times: dict[str, list[float]] = {name: [] for name in sessions}
            for i in range(args.calls):
                for name, session in sessions.items():
                    t = time.perf_counter()
                    session.run(feeds[i % len(feeds)])
                    times[name].append((time.perf_counter() - t) * 1000)
            print(f"{runtime}, run {run + 1} (ms): " + ", ".join(
                f"{name} {statistics.median(t):.2f}" for name, t in times.items()))


if __name__ == "__main__":
    main()
