"""Benchmark the pipeline's stages, the engine and OpenCV SGBM on the same pairs, in one run.

    python tools/bench.py [--scenes 4] [--repeat 3] [--iters 1,2,4,8] [--threads 2]
        [--bundle DIR] [--runtime auto|onnxruntime|openvino] [--bf16 auto|on|off] [--runs 3]
        [--json OUT] [--markdown OUT]

At the bundle's input size (640x400 for the shipped one), on test-split scenes of the rig:
rectify (two remaps, maps computed once), project + occlusion filter (64-beam scans), the
engine's encoder / one update step / upsampling / band refinement / median (the engine at its
defaults and the median its bundle declares), the engine at each
iteration count in fp32 and int8, SGBM (3-way, 64 disparities, grey), logging one frame's
results to MCAP, the whole daemon frame (rectify -> log, int8 at the bundle's default
iterations), and the peak RSS of an `edge-depth replay` subprocess. Methods alternate in
blocks, each with an untimed first call (thread pools and caches favour whatever ran last);
medians and p95 in milliseconds.

A single run decides nothing on a shared machine (the same-run int8/SGBM ratio moved from
1.8x to 2.9x between runs here): `--runs N` repeats the whole measurement and reports the
median of the per-run ratios with their range, and every run says how much of the CPU other
processes took while it ran (from /proc/stat against this process's own CPU time) and how
far SGBM's own time spread; a run where others took over 10 % is flagged busy, and the
summary says the ratio should not be trusted.

`--threads N` sets the engine's threads and OpenCV's (SGBM's) alike, so the ratio compares
like with like. On a 2-vCPU host one thread each gives the steadiest ratio: SGBM's gain from
its second thread drifted from 1.1x to 1.85x within a minute there, one thread stayed
within ±4 % (docs/experiments.md).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from edge_depth.baselines import make_sgbm, sgbm_disparity
from edge_depth.calibration.model import StereoCalibration
from edge_depth.calibration.projection import project_to_disparity
from edge_depth.calibration_watch import EVERY as WATCH_EVERY
from edge_depth.runtime.backends import cpu_description
from edge_depth.runtime.engine import DEFAULT_BUNDLE, Engine
from edge_depth.runtime.graphs import load_bundle_meta
from edge_depth.sim import RigConfig, make_sample
from edge_depth.tools.bench_report import BUSY_SHARE, host_line, machine_line, markdown
from edge_depth.types import LidarScan

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
    from edge_depth.sim_recording import write_sim_recording

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




def _cpu_jiffies() -> tuple[float, float] | None:
    """(busy, total) seconds of all CPUs since boot from /proc/stat; None off Linux."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    except OSError:
        return None
    values = [float(v) for v in fields[:8]]
    tick = os.sysconf("SC_CLK_TCK")
    idle = values[3] + values[4]  # idle + iowait
    return (sum(values) - idle) / tick, sum(values) / tick


class CpuShare:
    """How much of the machine's CPU time other processes used while the block ran."""

    def __enter__(self):
        self._jiffies, self._own = _cpu_jiffies(), os.times()
        self._wall = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        end, own = _cpu_jiffies(), os.times()
        self.wall_s = time.perf_counter() - self._wall
        self.others = None
        if self._jiffies is not None and end is not None:
            busy = end[0] - self._jiffies[0]
            total = end[1] - self._jiffies[1]
            mine = (own.user - self._own.user) + (own.system - self._own.system)
            self.others = max(0.0, busy - mine) / total if total > 0 else None


RUNTIME_SPECS = {"onnxruntime": ("onnxruntime", False), "openvino": ("openvino", False),
                 "openvino+bf16": ("openvino", True)}


def compare_runtimes(specs: list[str], scenes: int, rounds: int, threads: int, bundle: Path,
                     precision: str = "int8") -> dict:
    """The engine (4 iterations) on each runtime and SGBM, interleaved call by call on the
    same pairs (round-robin, so a busy spell hits every contender alike): median ms of each,
    and each engine's median over SGBM's."""
    cv2.setNumThreads(threads)
    meta = load_bundle_meta(bundle)
    w, h = meta["size"]
    rig = RigConfig(width=w, height=h, focal_px=450.0 * w / 640)
    samples = [make_sample(TEST_SEED0 + i, rig, "beams16") for i in range(scenes)]
    inputs = [(s.left, s.right, s.sparse_disparity("left")[0]) for s in samples]
    matcher = make_sgbm()
    contenders = {"sgbm": lambda left, right, sparse: sgbm_disparity(left, right, matcher)}
    for spec in specs:
        if spec not in RUNTIME_SPECS:
            raise SystemExit(f"--runtimes: {spec!r} is not one of {', '.join(RUNTIME_SPECS)}")
        runtime, bf16 = RUNTIME_SPECS[spec]
        engine = Engine(bundle, precision=precision, threads=threads, meta=meta, runtime=runtime,
                        bf16=bf16)
        contenders[spec] = (lambda e: lambda left, right, sparse:
                            e.infer(left, right, sparse, iters=4))(engine)
    times: dict[str, list[float]] = {k: [] for k in contenders}
    for fn in contenders.values():  # untimed: first-call allocation
        fn(*inputs[0])
    with CpuShare() as share:
        for r in range(rounds):
            for name, fn in contenders.items():
                args = inputs[r % len(inputs)]
                start = time.perf_counter()
                fn(*args)
                times[name].append((time.perf_counter() - start) * 1000)
    med = {k: float(np.median(v)) for k, v in times.items()}
    return dict(precision=precision, rounds=rounds, median_ms=med,
                vs_sgbm={k: med[k] / med["sgbm"] for k in specs},
                others_cpu_share=share.others,
                busy=share.others is not None and share.others > BUSY_SHARE)


def paired_ratios(engine, sgbm, inputs: list[tuple], repeat: int) -> list[float]:
    """Engine ms / SGBM ms for each frame, the two timed back to back (which goes first
    alternates): a host that slows between the blocks above moves both sides of each pair."""
    ratios = []
    for r in range(repeat):
        for i, (left, right, sparse) in enumerate(inputs):
            ms = {}
            for name in (("engine", "sgbm") if (r + i) % 2 == 0 else ("sgbm", "engine")):
                start = time.perf_counter()
                engine(left, right, sparse) if name == "engine" else sgbm(left, right)
                ms[name] = time.perf_counter() - start
            ratios.append(ms["engine"] / ms["sgbm"])
    return ratios


def distorted_rig(rig: RigConfig) -> StereoCalibration:
    """The rig's cameras with a little lens distortion: what rectification has to undo."""
    K = np.array([[rig.focal_px, 0, rig.cx], [0, rig.focal_px, rig.cy], [0, 0, 1]])
    return StereoCalibration(K, [-0.08, 0.02, 0, 0, 0], K, [-0.07, 0.015, 0, 0, 0],
                             np.eye(3), [-rig.baseline_m, 0, 0], (rig.width, rig.height))


class StageClock:
    """The engine's own per-stage timings of the int8 runs at the default iterations (a
    stage with nothing to do in a frame counts 0 ms): the encoder, a step, the upsampling
    and the refinement after them: the band refinement and the median, where they run."""

    def __init__(self, engines: dict, default_iters: int) -> None:
        self.engines, self.default_iters = engines, default_iters
        self.runs: dict[str, list[float]] = {"encoder": [], "step": [], "upsample": []}
        engine = engines["int8"]
        if engine.band is not None:
            self.runs["band_refine"] = []
        if engine.median is not None:
            self.runs["edge_median"] = []

    def run(self, precision: str, iters: int):
        """The timed call for `engine_{precision}_{iters}`."""
        def fn(left, right, sparse):
            r = self.engines[precision].infer(left, right, sparse, iters=iters)
            if precision == "int8" and iters == self.default_iters:
                for name in self.runs:
                    self.runs[name].append(r.timings_ms.get(
                        "step_mean" if name == "step" else name, 0.0))
        return fn


def stat(t: list[float]) -> dict:
    return dict(median_ms=float(np.median(t)), p95_ms=float(np.percentile(t, 95)),
                runs=len(t))


def ratios(out: dict, engine_ms: dict, key: str, paired: list[float]) -> dict:
    """The engine against SGBM (blocks and frame by frame), fp32 against int8, the daemon's
    frame against the engine, the matching against SGBM."""
    sgbm_ms = out["sgbm"]["median_ms"]
    return dict(
        int8_vs_sgbm=engine_ms["int8"][key] / sgbm_ms,
        fp32_vs_sgbm=engine_ms["fp32"][key] / sgbm_ms,
        int8_speedup=engine_ms["fp32"][key] / engine_ms["int8"][key],
        frame_vs_engine=out["frame"]["median_ms"] / engine_ms["int8"][key],
        **({"band_refine_vs_sgbm": out["band_refine"]["median_ms"] / sgbm_ms}
           if "band_refine" in out else {}),
        int8_vs_sgbm_paired=float(np.median(paired)),
        int8_vs_sgbm_paired_p10_p90=[float(np.percentile(paired, 10)),
                                     float(np.percentile(paired, 90))])


def bench(scenes: int, repeat: int, iters_list: list[int], threads: int, bundle: Path,
          rss_frames: int = 5, runtime: str = "auto", bf16: bool | None = None) -> dict:
    """Every stage timed on `scenes` rig frames in `repeat` blocks, the engine at each of
    `iters_list` (and the bundle's own count) in fp32 and int8, SGBM on the same pairs; the
    JSON summary `main` writes."""
    from edge_depth.capture.sim import SimSource
    from edge_depth.daemon import Pipeline
    from edge_depth.mcap_log import McapLogger

    cv2.setNumThreads(threads)  # SGBM with the engine's thread count
    meta = load_bundle_meta(bundle)
    w, h = meta["size"]
    rig, samples, dense, inputs = bench_frames(w, h, scenes)
    matcher = make_sgbm()
    # as the daemon runs them: the engine's defaults (the band refinement) with the settings
    # the bundle declares (the shipped one's median), inside every engine row
    engines = {p: Engine(bundle, precision=p, threads=threads, meta=meta, runtime=runtime,
                         bf16=bf16)
               for p in ("fp32", "int8")}
    default_iters = int(meta.get("default_iters", 4))
    # the ratio is the engine's at the bundle's own count: timed whatever --iters lists
    iters_list = sorted(set(iters_list) | {default_iters})
    clock = StageClock(engines, default_iters)

    tmp = tempfile.TemporaryDirectory()
    logger = McapLogger(Path(tmp.name) / "bench.mcap")
    source = SimSource(1, TEST_SEED0, rig)
    pipeline = Pipeline(engines["int8"], *source.calibration, logger)
    stages = daemon_stages(rig, samples, dense, inputs, engines["int8"], logger, pipeline)
    methods = timed_methods(stages, samples, inputs, matcher, clock, iters_list)
    load_before = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    with CpuShare() as share:
        times = _timed_blocks(methods, repeat)
        paired = paired_ratios(  # the engine at the bundle's count against SGBM, frame by frame
            lambda a, b, p: engines["int8"].infer(a, b, p, iters=default_iters),
            lambda a, b: sgbm_disparity(a, b, matcher), inputs, repeat)
    watch = watch_costs(engines["int8"], source, logger, samples, repeat)
    logger.close()
    tmp.cleanup()

    out = {name: stat(t) for name, t in (times | clock.runs).items()}
    engine_ms = {p: {str(i): out[f"engine_{p}_{i}"]["median_ms"] for i in iters_list}
                 for p in ("fp32", "int8")}
    engine = engines["int8"]
    summary = dict(size=[w, h], scenes=scenes, threads=threads,
                   opencv_threads=cv2.getNumThreads(), bundle=str(bundle),
                   engine=engine.describe(), runtime=engine.runtime,
                   bf16_encoder=engine.bf16_encoder, int8_encoder=engine.int8_encoder,
                   points_64_beams=int(np.median([len(s.scan) for s in dense])),
                   sgbm_ms=out["sgbm"]["median_ms"], engine_ms=engine_ms, stages=out,
                   machine=machine_state(share.others, load_before, times["sgbm"]))
    summary["ratios"] = ratios(out, engine_ms, str(default_iters), paired)
    summary["outside_engine"] = outside_engine(pipeline.stats.timings)
    summary["calibration_watch"] = watch_summary(watch)
    if rss_frames:
        summary["replay_peak_rss_mb"] = replay_peak_rss_mb(rss_frames, (w, h), bundle)
    summary["bench_peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return summary


def bench_frames(width: int, height: int, scenes: int) -> tuple:
    """(rig, its 16-beam samples, the same scenes with 64 beams, the engine's inputs) at the
    bundle's size."""
    rig = RigConfig(width=width, height=height, focal_px=450.0 * width / 640)
    samples = [make_sample(TEST_SEED0 + i, rig, "beams16") for i in range(scenes)]
    dense = [make_sample(TEST_SEED0 + i, rig, "beams64") for i in range(scenes)]
    inputs = [(s.left, s.right, s.sparse_disparity("left")[0]) for s in samples]
    return rig, samples, dense, inputs


def timed_methods(stages: dict, samples, inputs, matcher, clock: StageClock,
                  iters_list: list[int]) -> dict:
    """What each block times, in this order: rectify, project_filter, sgbm, the daemon's other
    stages (log, frame), then the engine at each precision and count."""
    methods = {k: stages[k] for k in ("rectify", "project_filter")}
    methods["sgbm"] = (lambda a, b: sgbm_disparity(a, b, matcher),
                       [(s.left, s.right) for s in samples])
    methods.update(stages)
    for precision in ("fp32", "int8"):
        for iters in iters_list:
            methods[f"engine_{precision}_{iters}"] = (clock.run(precision, iters), inputs)
    return methods


def daemon_stages(rig, samples, dense, inputs, engine, logger, pipeline) -> dict:
    """The daemon's stages around the engine, as `_timed` takes them (a function and its
    argument tuples): rectification, the LiDAR's projection with its occlusion filter (64
    beams), the results' logging and the daemon's whole frame (`pipeline`, given a scan 5 ms
    before each frame)."""
    rectifier = distorted_rig(rig).rectifier()
    ideal = samples[0].calibration()
    results = [engine.infer(*x, focal_px=rig.focal_px, baseline_m=rig.baseline_m)
               for x in inputs]
    frames = [s.frame(1_000_000_000 + i * 100_000_000, i) for i, s in enumerate(samples)]
    for i, s in enumerate(samples):
        pipeline.on_scan(LidarScan(frames[i].stamp_ns - 5_000_000, s.scan.points))
    return {"rectify": (lambda a, b: rectifier.rectify(a, b),
                        [(s.left, s.right) for s in samples]),
            "project_filter": (lambda s: project_to_disparity(s.scan.points, ideal,
                                                              s.T_cam_lidar),
                               [(s,) for s in dense]),
            "log": (lambda r, x: logger.log_result(r, x[2], rig.focal_px, (rig.cx, rig.cy)),
                    list(zip(results, inputs, strict=True))),
            "frame": (lambda f: pipeline.on_frame(f), [(f,) for f in frames])}


def _timed_blocks(methods: dict, repeat: int) -> dict[str, list[float]]:
    """Each method's per-call ms over `repeat` blocks, every method once per block (so a
    slow spell of the host falls on all of them)."""
    times: dict[str, list[float]] = {k: [] for k in methods}
    for _ in range(repeat):
        for name, (fn, args_list) in methods.items():
            _timed(fn, args_list, times[name])
    return times


def machine_state(others_share: float | None, load_avg: float | None,
                  sgbm_times: list[float]) -> dict:
    """What else ran while the bench did, and how steady SGBM's own times were."""
    spread = float(np.percentile(sgbm_times, 90) / np.percentile(sgbm_times, 10))
    return dict(others_cpu_share=others_share, load_avg_1min=load_avg,
                sgbm_p90_over_p10=spread,
                busy=others_share is not None and others_share > BUSY_SHARE,
                cpu=cpu_description())


def watch_summary(watch: list[tuple[float, float]]) -> dict:
    """The calibration watch's sample (`watch_costs`: its ms, the frame's ms) per frame."""
    sample_ms = float(np.median([w for w, _ in watch]))
    return dict(sample_ms=sample_ms, every=WATCH_EVERY, per_frame_ms=sample_ms / WATCH_EVERY,
                share_of_frame_pct=100 * float(np.median([w / f for w, f in watch]))
                / WATCH_EVERY)


def outside_engine(timings) -> dict:
    """The daemon's frame outside the engine (rectification, projection, logging), from the
    frames' own timings: "frame" and "engine" of one frame are timed together, so the share
    does not mix blocks timed minutes apart on a host whose speed drifts (the frame / engine
    ratio does). Median ms and median % of the frame."""
    rest = [t["frame"] - t["engine"] for t in timings]
    return dict(ms=float(np.median(rest)), share_pct=100 * float(np.median(
        [r / t["frame"] for r, t in zip(rest, timings, strict=True)])), frames=len(rest))


def watch_costs(engine, source, logger, samples, repeat: int) -> list[tuple[float, float]]:
    """The calibration watch's (ms a sample with the estimate it updates, the same frame's
    ms without them): the daemon's pipeline taking a sample on every frame, each scene
    `repeat` times. Paired frame by frame, since this host's speed drifts between blocks."""
    from edge_depth.daemon import Pipeline

    pipeline = Pipeline(engine, *source.calibration, logger, watch_every=1)
    out: list[tuple[float, float]] = []
    for k in range(repeat * len(samples)):
        s, stamp = samples[k % len(samples)], 5_000_000_000 + k * 100_000_000
        pipeline.on_scan(LidarScan(stamp - 5_000_000, s.scan.points))
        pipeline.on_frame(s.frame(stamp, k))
        t = time.perf_counter()
        assert pipeline.watch is not None
        pipeline.watch.estimate()  # the runner's /diagnostics asks after each new sample
        estimate_ms = (time.perf_counter() - t) * 1000
        taken = pipeline.stats.watch_ms
        if len(taken) > len(out):  # a sample was taken on this frame
            out.append((taken[-1] + estimate_ms, pipeline.stats.timings[-1]["frame"]))
    return out


def runtimes_main(args: argparse.Namespace) -> int:
    """`--runtimes`: the int8 engine on each runtime and SGBM, interleaved call by call, as a
    table instead of the stage table."""
    specs = [v.strip() for v in args.runtimes.split(",") if v.strip()]
    result = compare_runtimes(specs, args.scenes, args.rounds, args.threads, args.bundle)
    lines = ["| contender | median ms | / SGBM |", "|---|---|---|"]
    for name, ms in result["median_ms"].items():
        ratio = result["vs_sgbm"].get(name)
        lines.append(f"| {name} | {ms:.1f} | {'' if ratio is None else f'{ratio:.2f}x'} |")
    others = result["others_cpu_share"]
    lines.append(f"({result['rounds']} interleaved calls each; other processes "
                 f"{'n/a' if others is None else f'{others:.0%}'} of the CPU"
                 f"{' — BUSY: do not trust' if result['busy'] else ''})")
    print("\n".join(lines))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


def run_line(summary: dict) -> dict:
    """One run's entry in a --runs summary: its ratios, SGBM's and the engine's ms, and the
    machine's state during it."""
    r = summary["ratios"]
    return dict(int8_vs_sgbm=r["int8_vs_sgbm"], sgbm_ms=summary["sgbm_ms"],
                engine_int8_ms=r["int8_vs_sgbm"] * summary["sgbm_ms"],
                **{k: r[k] for k in ("band_refine_vs_sgbm",) if k in r},
                int8_vs_sgbm_paired=r["int8_vs_sgbm_paired"], **summary["machine"])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=4)
    p.add_argument("--repeat", type=int, default=3, help="blocks (each over every scene)")
    p.add_argument("--iters", default="1,2,4,8")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--bundle", type=Path, default=DEFAULT_BUNDLE)
    p.add_argument("--runtime", choices=("auto", "onnxruntime", "openvino"), default="auto")
    p.add_argument("--bf16", choices=("auto", "on", "off"), default="auto",
                   help="OpenVINO: the encoder in bf16 (auto: where the CPU has it)")
    p.add_argument("--runtimes", default=None,
                   help="instead of the stage table: the int8 engine on each of these "
                        "runtimes and SGBM, interleaved call by call, e.g. "
                        "onnxruntime,openvino,openvino+bf16")
    p.add_argument("--rounds", type=int, default=30, help="--runtimes: calls of each")
    p.add_argument("--runs", type=int, default=1,
                   help="repeat the whole measurement; report the median per-run ratio")
    p.add_argument("--rss-frames", type=int, default=5,
                   help="frames of the replay RSS measurement (0: skip it)")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--markdown", type=Path, default=None)
    args = p.parse_args(argv)
    try:
        iters_list = [int(v) for v in args.iters.split(",")]
    except ValueError:
        p.error(f"--iters: expected integers like 1,2,4,8, got {args.iters!r}")
    if args.runs < 1:
        p.error("--runs: at least 1")
    if args.runtimes:
        return runtimes_main(args)
    bf16 = {"auto": None, "on": True, "off": False}[args.bf16]
    print(host_line(cpu_description()), flush=True)  # ratios are only comparable per ISA
    runs = []
    for i in range(args.runs):
        summary = bench(args.scenes, args.repeat, iters_list, args.threads, args.bundle,
                        args.rss_frames if i == args.runs - 1 else 0, args.runtime, bf16)
        if args.runs > 1:
            print(f"run {i + 1}/{args.runs}: int8 / SGBM "
                  f"{summary['ratios']['int8_vs_sgbm']:.2f}x; "
                  + machine_line(summary["machine"]), flush=True)
        runs.append(summary)
    if args.runs > 1:
        summary["runs"] = [run_line(r) for r in runs]
        summary["ratio_median"] = float(np.median([r["int8_vs_sgbm"] for r in summary["runs"]]))
    table = markdown(summary)
    print(table)
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2))
    if args.markdown:
        args.markdown.write_text(table + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
