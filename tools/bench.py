"""Benchmark the pipeline's stages, the engine and OpenCV SGBM on the same pairs, in one run.

    python tools/bench.py [--scenes 4] [--repeat 3] [--iters 1,2,4,8] [--threads 2]
        [--bundle DIR] [--json OUT] [--markdown OUT]

At the bundle's input size (640x400 for the shipped one), on test-split scenes of the rig:
rectify (two remaps, maps computed once), project + occlusion filter (64-beam scans), the
engine's encoder / one update step / upsampling, the engine at each iteration count in fp32
and int8, SGBM (3-way, 64 disparities, grey), logging one frame's results to MCAP, the whole
daemon frame (rectify -> log, int8 at the bundle's default iterations), and the peak RSS of an
`edge-depth replay` subprocess. Methods alternate in blocks, each with an untimed first call
(thread pools and caches favour whatever ran last); medians and p95 in milliseconds.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibration.model import StereoCalibration  # noqa: E402
from calibration.projection import project_to_disparity  # noqa: E402
from edge.baselines import make_sgbm, sgbm_disparity  # noqa: E402
from edge.runtime.engine import DEFAULT_BUNDLE, Engine, load_bundle_meta  # noqa: E402
from edge.sim import RigConfig, make_sample  # noqa: E402
from edge.types import LidarScan  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TEST_SEED0 = 1_000_000


def _timed(fn, args_list, out: list[float]) -> None:
    fn(*args_list[0])  # untimed
    for args in args_list:
        start = time.perf_counter()
        fn(*args)
        out.append((time.perf_counter() - start) * 1000)


def replay_peak_rss_mb(frames: int, size: tuple[int, int], bundle: Path) -> float:
    """Peak RSS (MB) of `edge-depth replay` over a synthetic recording, in a subprocess."""
    from edge.capture.sim import write_sim_recording

    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "rec.mcap"
        write_sim_recording(rec, frames, TEST_SEED0, RigConfig(width=size[0], height=size[1]))
        code = ("import resource, sys; from edge.cli import main; rc = main(sys.argv[1:]); "
                "print('RSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss); "
                "sys.exit(rc)")
        out = subprocess.run([sys.executable, "-c", code, "replay", str(rec), "--out",
                              str(Path(tmp) / "out.mcap"), "--bundle", str(bundle)],
                             cwd=ROOT, capture_output=True, text=True, check=True)
    line = [ln for ln in out.stdout.splitlines() if ln.startswith("RSS_KB")][0]
    return int(line.split()[1]) / 1024


def bench(scenes: int, repeat: int, iters_list: list[int], threads: int, bundle: Path,
          rss_frames: int = 5) -> dict:
    from edge.capture.sim import SimSource
    from edge.daemon import Pipeline
    from edge.mcap_log import McapLogger

    meta = load_bundle_meta(bundle)
    w, h = meta["size"]
    rig = RigConfig(width=w, height=h, focal_px=450.0 * w / 640)
    samples = [make_sample(TEST_SEED0 + i, rig, "beams16") for i in range(scenes)]
    dense = [make_sample(TEST_SEED0 + i, rig, "beams64") for i in range(scenes)]
    K = np.array([[rig.focal_px, 0, rig.cx], [0, rig.focal_px, rig.cy], [0, 0, 1]])
    distorted = StereoCalibration(K, [-0.08, 0.02, 0, 0, 0], K, [-0.07, 0.015, 0, 0, 0],
                                  np.eye(3), [-rig.baseline_m, 0, 0], (w, h))
    rectifier = distorted.rectifier()
    ideal = samples[0].calibration()
    inputs = [(s.left, s.right, s.sparse_disparity("left")[0]) for s in samples]
    pairs = [(s.left, s.right) for s in samples]
    matcher = make_sgbm()
    engines = {p: Engine(bundle, p, threads, meta) for p in ("fp32", "int8")}
    default_iters = int(meta.get("default_iters", 4))

    # stage timings inside the engine come from its own per-stage clock
    stage_runs: dict[str, list[float]] = {"encoder": [], "step": [], "upsample": []}

    def engine_run(precision, iters):
        def fn(left, right, sparse):
            r = engines[precision].infer(left, right, sparse, iters=iters)
            if precision == "int8" and iters == default_iters:
                stage_runs["encoder"].append(r.timings_ms["encoder"])
                stage_runs["step"].append(r.timings_ms["step_mean"])
                stage_runs["upsample"].append(r.timings_ms["upsample"])
        return fn

    tmp = tempfile.TemporaryDirectory()
    logger = McapLogger(Path(tmp.name) / "bench.mcap")
    source = SimSource(1, TEST_SEED0, rig)
    pipeline = Pipeline(engines["int8"], *source.calibration, logger)
    results = [engines["int8"].infer(*x, focal_px=rig.focal_px, baseline_m=rig.baseline_m)
               for x in inputs]
    frames = [s.frame(1_000_000_000 + i * 100_000_000, i) for i, s in enumerate(samples)]
    for i, s in enumerate(samples):
        pipeline.on_scan(LidarScan(frames[i].stamp_ns - 5_000_000, s.scan.points))

    methods = {"rectify": (lambda a, b: rectifier.rectify(a, b), pairs),
               "project_filter": (lambda s: project_to_disparity(s.scan.points, ideal,
                                                                 s.T_cam_lidar),
                                  [(s,) for s in dense]),
               "sgbm": (lambda a, b: sgbm_disparity(a, b, matcher), pairs),
               "log": (lambda r, x: logger.log_result(r, x[2], rig.focal_px,
                                                      (rig.cx, rig.cy)),
                       list(zip(results, inputs, strict=True))),
               "frame": (lambda f: pipeline.on_frame(f), [(f,) for f in frames])}
    for precision in ("fp32", "int8"):
        for iters in iters_list:
            methods[f"engine_{precision}_{iters}"] = (engine_run(precision, iters), inputs)
    times: dict[str, list[float]] = {k: [] for k in methods}
    for _ in range(repeat):  # blocks
        for name, (fn, args_list) in methods.items():
            _timed(fn, args_list, times[name])
    logger.close()
    tmp.cleanup()

    def stat(t):
        return dict(median_ms=float(np.median(t)), p95_ms=float(np.percentile(t, 95)),
                    runs=len(t))

    out = {name: stat(t) for name, t in times.items()}
    for name, t in stage_runs.items():
        out[name] = stat(t)
    sgbm_ms = out["sgbm"]["median_ms"]
    engine_ms = {p: {str(i): out[f"engine_{p}_{i}"]["median_ms"] for i in iters_list}
                 for p in ("fp32", "int8")}
    key = str(default_iters)
    summary = dict(size=[w, h], scenes=scenes, threads=threads, bundle=str(bundle),
                   points_64_beams=int(np.median([len(s.scan) for s in dense])),
                   sgbm_ms=sgbm_ms, engine_ms=engine_ms, stages=out)
    if key in engine_ms["int8"]:
        summary["ratios"] = dict(
            int8_vs_sgbm=engine_ms["int8"][key] / sgbm_ms,
            fp32_vs_sgbm=engine_ms["fp32"][key] / sgbm_ms,
            int8_speedup=engine_ms["fp32"][key] / engine_ms["int8"][key],
            frame_vs_engine=out["frame"]["median_ms"] / engine_ms["int8"][key])
    if rss_frames:
        summary["replay_peak_rss_mb"] = replay_peak_rss_mb(rss_frames, (w, h), bundle)
    summary["bench_peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return summary


def markdown(summary: dict) -> str:
    w, h = summary["size"]
    st = summary["stages"]
    lines = [f"| stage ({w}x{h}, {summary['threads']} threads) | median ms | p95 ms |",
             "|---|---|---|"]
    names = ["rectify", "project_filter", "encoder", "step", "upsample", "log", "frame", "sgbm"]
    names += sorted(k for k in st if k.startswith("engine_"))
    for name in names:
        if name in st:
            lines.append(f"| {name} | {st[name]['median_ms']:.1f} | {st[name]['p95_ms']:.1f} |")
    if "ratios" in summary:
        r = summary["ratios"]
        lines.append("")
        lines.append(f"int8 engine / SGBM: **{r['int8_vs_sgbm']:.2f}x** (fp32 "
                     f"{r['fp32_vs_sgbm']:.2f}x; int8 speed-up x{r['int8_speedup']:.2f}); "
                     f"daemon frame / engine: {r['frame_vs_engine']:.2f}x")
    if "replay_peak_rss_mb" in summary:
        lines.append(f"peak RSS of `edge-depth replay`: {summary['replay_peak_rss_mb']:.0f} MB")
    lines.append(f"(project_filter: 64-beam scans, {summary['points_64_beams']} points; "
                 f"{summary['scenes']} test scenes)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--repeat", type=int, default=3, help="blocks (each over every scene)")
    p.add_argument("--iters", default="1,2,4,8")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--bundle", type=Path, default=DEFAULT_BUNDLE)
    p.add_argument("--rss-frames", type=int, default=5,
                   help="frames of the replay RSS measurement (0: skip it)")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--markdown", type=Path, default=None)
    args = p.parse_args(argv)
    try:
        iters_list = [int(v) for v in args.iters.split(",")]
    except ValueError:
        p.error(f"--iters: expected integers like 1,2,4,8, got {args.iters!r}")
    summary = bench(args.scenes, args.repeat, iters_list, args.threads, args.bundle,
                    args.rss_frames)
    table = markdown(summary)
    print(table)
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2))
    if args.markdown:
        args.markdown.write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
