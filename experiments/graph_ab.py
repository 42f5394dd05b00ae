"""Interleaved A/B timing of ONNX graphs: which of two versions of a graph is faster.

    python experiments/graph_ab.py A.onnx B.onnx [...] [--runtime openvino] [--rounds 40]
        [--threads 2] [--json OUT]

Each round calls every graph once, in turn, on the same random inputs (the shapes the graph
declares), so a host whose speed drifts within minutes slows all of them alike — a ratio
between separate runs does not hold on these shared machines (README, Speed). Prints the
median and 10th percentile of each graph's call time, the first `--warmup` rounds left out.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from edge_depth.runtime.backends import open_session, resolve_runtime
from edge_depth.tools.quantize import random_feeds


def interleaved_ms(paths: list[Path], runtime: str = "auto", rounds: int = 40,
                   warmup: int = 5, threads: int = 2) -> dict[str, dict[str, float]]:
    runtime = resolve_runtime(runtime)
    runs = [(open_session(p, runtime, threads), random_feeds(p)) for p in paths]
    times: list[list[float]] = [[] for _ in paths]
    for _ in range(warmup + rounds):
        for k, (session, feeds) in enumerate(runs):
            start = time.perf_counter()
            session.run(feeds)
            times[k].append((time.perf_counter() - start) * 1000)
    return {str(p): dict(median_ms=float(np.median(t[warmup:])),
                         p10_ms=float(np.percentile(t[warmup:], 10)), runtime=runtime)
            for p, t in zip(paths, times, strict=True)}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("graphs", type=Path, nargs="+")
    p.add_argument("--runtime", default="auto", choices=("auto", "onnxruntime", "openvino"))
    p.add_argument("--rounds", type=int, default=40)
    p.add_argument("--warmup", type=int, default=5)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    missing = [str(g) for g in args.graphs if not g.is_file()]
    if missing:
        p.error(f"no such graph: {', '.join(missing)}")
    result = interleaved_ms(args.graphs, args.runtime, args.rounds, args.warmup, args.threads)
    for name, r in result.items():
        print(f"{name}: median {r['median_ms']:.2f} ms, p10 {r['p10_ms']:.2f} ms "
              f"({r['runtime']}, {args.rounds} interleaved rounds)")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
