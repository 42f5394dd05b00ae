"""Where a frame's milliseconds go: each graph of a bundle profiled node by node on ONNX Runtime
(its profiler) and OpenVINO (its per-layer counters), summed by operator type, and the engine's
own stages around them, on this host.

    python experiments/profile_graphs.py [--bundle DIR] [--precision int8] [--threads 2]
        [--runs 30] [--markdown OUT.md] [--bf16 auto|on|off]

With `ONEDNN_MAX_CPU_ISA=AVX2` (and `--bf16 off`) OpenVINO's oneDNN kernels are those an
AVX2-only CPU gets (the table's kernel column says which ran); ONNX Runtime's are not limited.

Graph inputs are a rig frame's (640x400, 16 LiDAR rows) as the engine feeds them; each graph
runs `--runs` times after a warm-up, and the per-run time of an operator type is its total over
the runs divided by them.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from edge_depth.runtime.backends import cpu_description
from edge_depth.runtime.engine import DEFAULT_BUNDLE, Engine
from edge_depth.sim import RigConfig, make_sample


def recorded_feeds(engine: Engine) -> dict[str, dict[str, np.ndarray]]:
    """Each graph's first feeds for a rig frame, as the engine gave them."""
    sample = make_sample(1_000_000, RigConfig(), "beams16")
    sparse, valid = sample.sparse_disparity("left")
    record: dict[str, list] = {}
    engine.infer(sample.left, sample.right, (sparse * valid).astype(np.float32), record=record)
    return {part: feeds[0] for part, feeds in record.items()}


def ort_profile(path: Path, feeds: dict, threads: int, runs: int) -> dict[str, float]:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.enable_profiling = True
    opts.profile_file_prefix = str(Path(tempfile.mkdtemp()) / "ort")
    session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    for _ in range(runs + 3):
        session.run(None, {k: feeds[k] for k in names})
    events = json.loads(Path(session.end_profiling()).read_text())
    by_op: dict[str, float] = defaultdict(float)
    for e in events:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
            by_op[e["args"]["op_name"]] += e["dur"] / 1000  # µs -> ms
    total_runs = runs + 3
    return {op: ms / total_runs for op, ms in by_op.items()}


def ov_profile(path: Path, feeds: dict, threads: int, runs: int, bf16: bool,
               nodes: dict | None = None) -> dict[str, float]:
    """ms per run by operator type; `nodes`, if given, receives ms per run by node name with
    the kernel OpenVINO chose (its exec_type names the instruction set: jit_avx512, brgconv_avx2,
    ..._amx)."""
    import openvino as ov

    core = ov.Core()
    model = core.read_model(str(path))
    names = [i.get_any_name() for i in model.inputs]
    if model.is_dynamic():
        model.reshape({k: list(feeds[k].shape) for k in names})
    compiled = core.compile_model(model, "CPU", {
        "INFERENCE_NUM_THREADS": threads, "PERFORMANCE_HINT": "LATENCY", "PERF_COUNT": True,
        "INFERENCE_PRECISION_HINT": "bf16" if bf16 else "f32"})
    request = compiled.create_infer_request()
    for _ in range(3):
        request.infer({k: feeds[k] for k in names})
    by_op: dict[str, float] = defaultdict(float)
    for _ in range(runs):
        request.infer({k: feeds[k] for k in names})
        for info in request.get_profiling_info():
            ms = info.real_time.total_seconds() * 1000
            by_op[info.node_type] += ms
            if nodes is not None:
                key = (info.node_name, info.exec_type)
                nodes[key] = nodes.get(key, 0.0) + ms / runs
    return {op: ms / runs for op, ms in by_op.items()}


def stage_medians(engine: Engine, runs: int) -> dict[str, float]:
    sample = make_sample(1_000_001, RigConfig(), "beams16")
    sparse, valid = sample.sparse_disparity("left")
    sparse = (sparse * valid).astype(np.float32)
    times: dict[str, list[float]] = defaultdict(list)
    for _ in range(runs):
        for k, v in engine.infer(sample.left, sample.right, sparse).timings_ms.items():
            times[k].append(v)
    return {k: statistics.median(v) for k, v in times.items()}


def table(title: str, by_op: dict[str, float], top: int = 8) -> list[str]:
    total = sum(by_op.values())
    rows = [f"**{title}**: {total:.1f} ms", "", "| operator | ms | share |", "|---|---|---|"]
    for op, ms in sorted(by_op.items(), key=lambda kv: -kv[1])[:top]:
        rows.append(f"| {op} | {ms:.2f} | {100 * ms / max(total, 1e-9):.0f} % |")
    return rows + [""]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bundle", type=Path, default=DEFAULT_BUNDLE)
    p.add_argument("--precision", default="int8", choices=("int8", "fp32"))
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--runs", type=int, default=30)
    p.add_argument("--markdown", type=Path, default=None)
    p.add_argument("--bf16", default="auto", choices=("auto", "on", "off"),
                   help="off with ONEDNN_MAX_CPU_ISA=AVX2 (an AVX2-only CPU's kernels on this "
                        "one), where OpenVINO cannot compile bf16")
    args = p.parse_args()
    cpu = cpu_description()
    lines = [f"host: {cpu['model']}; ISA {', '.join(cpu['isa'])}; {args.threads} threads; "
             f"{args.precision} graphs of {args.bundle}", ""]
    engine = Engine(args.bundle, precision=args.precision, threads=args.threads, bf16=args.bf16)
    feeds = recorded_feeds(engine)
    files = engine.meta["precisions"][args.precision]
    for part in ("encoder", "step", "upsample"):
        path = args.bundle / files[part]
        lines += table(f"{part} on ONNX Runtime", ort_profile(path, feeds[part], args.threads,
                                                              args.runs))
        nodes: dict = {}
        lines += table(f"{part} on OpenVINO" + (" (bf16)" if engine.bf16 and part == "encoder"
                                               else ""),
                       ov_profile(path, feeds[part], args.threads, args.runs,
                                  engine.bf16 and part == "encoder", nodes))
        lines += ["| its slowest nodes | kernel | ms |", "|---|---|---|"]
        lines += [f"| {name} | {kernel} | {ms:.2f} |" for (name, kernel), ms in
                  sorted(nodes.items(), key=lambda kv: -kv[1])[:5]] + [""]
    stages = stage_medians(engine, args.runs)
    lines += [f"**the engine's stages** ({engine.describe()}), median ms of {args.runs} frames:",
              "", "| stage | ms |", "|---|---|"]
    lines += [f"| {k} | {v:.1f} |" for k, v in stages.items()] + [""]
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        args.markdown.write_text(text)


if __name__ == "__main__":
    main()
