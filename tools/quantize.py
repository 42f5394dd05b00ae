"""Static int8 quantization of an exported bundle with ONNX Runtime.

    python tools/quantize.py BUNDLE_DIR [--calib SCENES_DIR | --calib synthetic:16]
        [--eval TEST_SCENES_DIR] [--max-graph-px 0.1] [--max-total-px 0.05]
        [--timing-runtime auto] [--min-gain 0.05] [--max-confidence 0.03]

QDQ format, QUInt8 activations and QInt8 per-channel weights, convolutions only: on this CPU
that fuses every convolution into an integer kernel, while quantizing the correlation, the
lookup, CSPN and the upsampling costs agreement and gains no speed (DESIGN.md). Calibration
feeds come from the fp32 engine run over the calibration frames (every step's inputs, so the
step graph sees the disparities of all iterations). Each graph is then tried alone in int8 and
kept in float if it alone moves the disparity by more than --max-graph-px on average or
does not make the engine at least --min-gain (5 %) faster (median of paired calls, on the
runtime the engine will use: --timing-runtime auto is OpenVINO on x86-64, where ONNX Runtime's
speed said nothing about OpenVINO's: the upsampling graph's int8 was neutral on one and ~25 %
faster on the other); then, while the
int8 graphs together move it by more than --max-total-px, the one that moves it most alone
goes back to float. Both tests run on ONNX Runtime and on the timing runtime, and bound the
confidence map too (--max-confidence): OpenVINO's int8 once turned a confidence head that ONNX
Runtime ran faithfully into 0.99 everywhere. In a graph that goes
int8, each convolution is then tried in float alone; those whose float version removes a
quarter or more of the graph's disparity shift stay float. The choices and the numbers are
written to model.json under "quantization". --eval reports EPE and speed of fp32 vs int8 on
scene folders with ground truth.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from edge_depth.metrics import disparity_metrics
from edge_depth.runtime.backends import cpu_description, resolve_runtime
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.graphs import load_bundle_meta
from edge_depth.sim.folder import list_scene_folders, read_scene_folder

CALIB_SEED0 = 500_000  # synthetic calibration frames come from the training seeds
PARTS = ("encoder", "step", "upsample")
RUNTIME = "onnxruntime"  # the quantizer is ONNX Runtime's: agreement is measured on it


def network_engine(bundle, precision: str, threads: int, meta: dict | None = None,
                   **kwargs) -> Engine:
    """The bundle's graphs alone: quantization calibrates, times and compares the network's own
    output, never the matching a bundle may declare as its engine's default (nor an int8
    encoder the bundle has from before, unless asked)."""
    kwargs.setdefault("int8_encoder", "off")
    return Engine(bundle, precision=precision, threads=threads, meta=meta, refine="off",
                  edge_median="off", **kwargs)


def calibration_frames(spec: str, size: tuple[int, int]):
    """Yield (left, right, sparse) from scene folders or `synthetic:N` rig scenes."""
    if spec.startswith("synthetic:"):
        from edge_depth.sim import RigConfig, make_sample

        count = int(spec.split(":", 1)[1])
        rig = RigConfig(width=size[0], height=size[1])
        for i in range(count):
            sample = make_sample(CALIB_SEED0 + i, rig, ("beams16", "beams32", "beams64")[i % 3])
            sparse, valid = sample.sparse_disparity("left")
            yield sample.left, sample.right, sparse * valid
        return
    folders = list_scene_folders(spec)
    if not folders:
        raise SystemExit(f"--calib {spec}: no scene folders (or use synthetic:N)")
    for folder in folders:
        scene = read_scene_folder(folder)
        sparse = scene.sparse if scene.sparse is not None else np.zeros_like(scene.disp)
        yield scene.left, scene.right, sparse


class FeedReader:
    """onnxruntime CalibrationDataReader over recorded feeds."""

    def __init__(self, feeds: list[dict[str, np.ndarray]]) -> None:
        self._iter = iter(feeds)

    def get_next(self):
        return next(self._iter, None)


# convolutions that always stay float: the confidence head's int8 graph agreed with its float
# one on ONNX Runtime but not on OpenVINO (the runtime `auto` picks on x86), where stage 12's
# confidence read 0.99 on average against 0.90 in float (the rig's test split: 99 % of pixels
# at >= 0.9 instead of 79 %, i.e. no information) while the disparity did not move
ALWAYS_FLOAT = ("/refine/head/",)  # the confidence head's layers stay float


def quantize_graph(src: Path, dst: Path, feeds: list[dict],
                   exclude: list[str] | None = None) -> None:
    from onnxruntime.quantization import QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    exclude = list(exclude or []) + [n for n in conv_nodes(src) if n.startswith(ALWAYS_FLOAT)]

    with tempfile.TemporaryDirectory() as tmp:
        prepared = Path(tmp) / "prepared.onnx"
        quant_pre_process(str(src), str(prepared), skip_symbolic_shape=True)
        quantize_static(str(prepared), str(dst), FeedReader(feeds),
                        quant_format=QuantFormat.QDQ, op_types_to_quantize=["Conv"],
                        per_channel=True, activation_type=QuantType.QUInt8,
                        weight_type=QuantType.QInt8, nodes_to_exclude=exclude)


def conv_nodes(path: Path) -> list[str]:
    import onnx

    return [n.name for n in onnx.load(str(path)).graph.node if n.op_type == "Conv"]


def random_feeds(path: Path, seed: int = 0) -> dict[str, np.ndarray]:
    """Float inputs 0-10 (images, disparities, features alike) at the declared shapes; a
    graph that takes any size gets its bundle's (model.json beside it)."""
    import onnx

    rng = np.random.default_rng(seed)
    named = bundle_dims(json.loads((path.parent / "model.json").read_text())) \
        if (path.parent / "model.json").is_file() else {}
    feeds = {}
    for value in onnx.load(str(path), load_external_data=False).graph.input:
        dims = [d.dim_value or named.get(d.dim_param, 1)
                for d in value.type.tensor_type.shape.dim]
        feeds[value.name] = (rng.random(dims) * 10).astype(np.float32)
    return feeds


def bundle_dims(meta: dict) -> dict[str, int]:
    """The exported graphs' named dimensions (tools/export.py's DYNAMIC) at the bundle's size."""
    (w, h), step = meta["size"], meta["downsample"]
    levels = meta.get("config", {}).get("corr_levels", 4)
    return dict(height=h, width=w, height_8=h // step, width_8=w // step,
                pyramid=sum((w // step >> level) + 3 for level in range(levels)))


def agreement(engine_a: Engine, engine_b: Engine, frames, iters: int) -> dict[str, float]:
    """Mean |disparity difference| ("px") and mean |confidence difference| ("confidence", 0-1;
    0 for a bundle without confidence) between two engines over the frames."""
    disp, conf = [], []
    for frame in frames:
        a, b = engine_a.infer(*frame, iters=iters), engine_b.infer(*frame, iters=iters)
        disp.append(np.abs(a.disparity - b.disparity).mean())
        if a.confidence is not None and b.confidence is not None:
            conf.append(np.abs(a.confidence - b.confidence).mean())
    return dict(px=float(np.mean(disp)), confidence=float(np.mean(conf)) if conf else 0.0)


def mean_abs_difference(engine_a: Engine, engine_b: Engine, frames, iters: int) -> float:
    return agreement(engine_a, engine_b, frames, iters)["px"]


def paired_ms(engines: list[Engine], frames, iters: int, rounds: int = 3
              ) -> tuple[float, float, float]:
    """Two engines timed call by call, in turn (their order swapped every round), on the
    same frames: (median ms of the first, median ms of the second, median of the per-pair
    ratios second / first). A pair's two calls are a fraction of a second apart, so a host
    whose speed swings between minutes — or seconds — slows both alike; blocks of runs per
    engine once judged the int8 step slower than float (301 against 241 ms) in the minute
    after a training run ended, where it is ~1.8x faster."""
    for engine in engines:
        engine.infer(*frames[0], iters=iters)  # untimed first call (compilation, caches)
    times: list[list[float]] = [[], []]
    for r in range(rounds):
        order = (0, 1) if r % 2 == 0 else (1, 0)
        for frame in frames:
            for i in order:
                times[i].append(engines[i].infer(*frame, iters=iters).timings_ms["engine"])
    ratios = np.asarray(times[1]) / np.maximum(np.asarray(times[0]), 1e-9)
    return float(np.median(times[0])), float(np.median(times[1])), float(np.median(ratios))


def evaluate(engine: Engine, folders: list[Path], iters: int) -> dict[str, float]:
    rows, times = [], []
    for folder in folders:
        scene = read_scene_folder(folder)
        engine.infer(scene.left, scene.right, scene.sparse, iters=iters)  # warm
        start = time.perf_counter()
        pred = engine.infer(scene.left, scene.right, scene.sparse, iters=iters).disparity
        times.append((time.perf_counter() - start) * 1000)
        rows.append(disparity_metrics(pred, scene.disp))
    out = {k: float(np.mean([r[k] for r in rows])) for k in ("epe", "bad1", "bad3")}
    out["ms_median"] = float(np.median(times))
    out["scenes"] = len(folders)
    return out


@dataclass
class GraphChoices:
    """One bundle's quantization: each graph tried in int8 against fp32 (its agreement on ONNX
    Runtime and on the runtime that will time it, its speed on that runtime), then the
    choices capped together. `over` says how far past its limits a shift is (> 1: over)."""

    bundle: Path
    meta: dict
    frames: list
    iters: int
    threads: int
    timing: str
    max_graph_px: float
    max_total_px: float
    max_confidence: float
    min_gain: float
    node_search: bool
    record: dict = field(default_factory=dict)
    graphs: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.files = dict(self.meta["precisions"]["fp32"])
        self.fp32 = network_engine(self.bundle, "fp32", self.threads, self.meta,
                                   runtime=RUNTIME)
        # speed is measured on the runtime the engine will use (`auto`: OpenVINO on x86-64),
        # agreement on ONNX Runtime's; where they are the same, the same engines
        self.fp32_timed = self.fp32 if self.timing == RUNTIME else network_engine(
            self.bundle, "fp32", self.threads, self.meta, runtime=self.timing)
        self.references = {RUNTIME: self.fp32, self.timing: self.fp32_timed}

    def over(self, shift: dict[str, float], px_limit: float) -> float:
        return max(shift["px"] / max(px_limit, 1e-9),
                   shift["confidence"] / max(self.max_confidence, 1e-9))

    def engine(self, meta: dict, runtime: str = RUNTIME) -> Engine:
        return network_engine(self.bundle, "int8", self.threads, meta, runtime=runtime)

    def calibrate(self) -> None:
        """Each graph's inputs on the calibration frames (fp32)."""
        for frame in self.frames:
            self.fp32.infer(*frame, iters=self.iters, record=self.record)

    def choose(self, part: str) -> None:
        """`part` in int8 if it moves the disparity (and confidence) little enough on both
        runtimes and is faster by `min_gain`; its costliest convolutions stay float where
        that brings it under the limit."""
        src = self.bundle / self.files[part]
        dst = self.bundle / self.files[part].replace(".onnx", ".int8.onnx")
        quantize_graph(src, dst, self.record[part])
        # the trial: int8 so far plus this graph, under the name the engine runs
        trial = dict(self.meta, precisions={"int8": dict(self.files, **{part: dst.name})})
        shipped = agreement(self.engine(trial), self.fp32, self.frames, self.iters)
        alone = shipped["px"]
        timed = self.engine(trial, self.timing)
        ms_fp32, ms_trial, ratio = paired_ms([self.fp32_timed, timed], self.frames[:4],
                                             self.iters)
        faster = ratio < 1.0 - self.min_gain
        graph = self.graphs[part] = dict(
            int8=alone <= self.max_graph_px and faster, mean_abs_px_alone=alone,
            engine_ms_fp32=ms_fp32, engine_ms_with_this_int8=ms_trial,
            int8_to_fp32_ratio=ratio, float_nodes=[])
        if faster and self.node_search:
            shipped = self.search_nodes(part, trial, alone) or shipped
        if graph["int8"]:
            # the graph as it will ship, checked on both runtimes: ONNX Runtime's agreement
            # said nothing about OpenVINO's confidence (stage 12's int8 head: 0.99 everywhere)
            graph["alone"] = {RUNTIME: shipped} | {
                rt: agreement(self.engine(trial, rt), ref, self.frames, self.iters)
                for rt, ref in self.references.items() if rt != RUNTIME}
            graph["int8"] = all(self.over(a, self.max_graph_px) <= 1
                                for a in graph["alone"].values())
        if not graph["int8"]:
            dst.unlink()

    def search_nodes(self, part: str, trial: dict, alone: float) -> dict | None:
        """Convolutions that cost most of the graph's agreement stay float; a graph whose
        all-int8 shift is over the limit goes int8 if that brings it under (stage 6's step:
        0.20 px all-int8). The agreement with them float, where some stay float."""
        src = self.bundle / self.files[part]
        dst = self.bundle / self.files[part].replace(".onnx", ".int8.onnx")
        graph, shifts = self.graphs[part], {}
        # (ALWAYS_FLOAT's are float in every trial: trying them would repeat the graph)
        for node in [n for n in conv_nodes(src) if not n.startswith(ALWAYS_FLOAT)]:
            quantize_graph(src, dst, self.record[part], [node])
            shifts[node] = mean_abs_difference(self.engine(trial), self.fp32, self.frames,
                                               self.iters)
        keep_float = [n for n, v in shifts.items() if v < 0.75 * alone]
        graph["shift_with_node_float"] = shifts
        if len(keep_float) == len(shifts):  # every convolution float is no int8 graph
            graph.update(int8=False, float_nodes=keep_float)
            return None
        if not keep_float:
            quantize_graph(src, dst, self.record[part])  # all int8 again, as measured
            return None
        quantize_graph(src, dst, self.record[part], keep_float)
        shipped = agreement(self.engine(trial), self.fp32, self.frames, self.iters)
        graph.update(float_nodes=keep_float, mean_abs_px_with_float_nodes=shipped["px"],
                     int8=shipped["px"] <= self.max_graph_px)
        return shipped

    def totals(self) -> dict[str, dict[str, float]]:
        """The int8 precision as chosen so far, against fp32, on both runtimes."""
        self.meta["precisions"]["int8"] = {
            part: self.files[part].replace(".onnx", ".int8.onnx") if self.graphs[part]["int8"]
            else self.files[part] for part in PARTS}
        return {rt: agreement(self.engine(self.meta, rt), ref, self.frames, self.iters)
                for rt, ref in self.references.items()}

    def cap_total(self) -> dict[str, dict[str, float]]:
        """The graphs' shifts add up: while together they move the disparity (or the
        confidence) too much on either runtime, the one that moves it most alone goes back
        to float (a speed test on a busy machine once passed the encoder, 0.07 px alone, and
        the bundle lost 4 % EPE on the rig). The totals as finally chosen."""
        total = self.totals()
        while (max(self.over(t, self.max_total_px) for t in total.values()) > 1
               and any(g["int8"] for g in self.graphs.values())):
            worst = max((p for p in PARTS if self.graphs[p]["int8"]),
                        key=lambda p: max(self.over(a, self.max_total_px)
                                          for a in self.graphs[p]["alone"].values()))
            self.graphs[worst].update(int8=False, float_for_the_total=True)
            (self.bundle / self.files[worst].replace(".onnx", ".int8.onnx")).unlink()
            total = self.totals()
        return total


# the int8 encoder's calibration: the rig's scenes (judged with these; calibrated on the
# bundle's calib_mix the same graph read Motorcycle's bad-3 7.05 instead of 6.94 %: the bars
# lie within calibration's spread, docs/experiments.md)
ENCODER_CALIB = "synthetic:16"


def int8_encoder(run: GraphChoices, calib: str | None = ENCODER_CALIB,
                 label: str = "the bundle's calibration frames") -> dict | None:
    """Where the encoder stays float: an int8 one beside it for the CPUs on which the float one
    would run in f32 without int8 dot products (`backends.resolve_int8_encoder`; an AVX2-only
    x86: 16.9 → 12.2 ms, the real pairs held, docs/speed.md), its stem float (the full-
    resolution first convolution on the raw image: no faster in int8 and most of the shift).
    Kept if the int8 precision with it moves the disparity (and confidence) within the graph
    limit on ONNX Runtime (on the bundle's calibration frames); model.json's "int8_encoder"
    says what it is. `calib`: its calibration frames (a `calibration_frames` spec), or None
    for the bundle's own (a robot's recordings, `adapt`), then named by `label`."""
    src = run.bundle / run.files["encoder"]
    dst = run.bundle / run.files["encoder"].replace(".onnx", ".int8.onnx")
    stem = conv_nodes(src)[:1]
    record: dict[str, list] = {}
    if calib is None:
        record["encoder"] = run.record["encoder"]
    else:
        for frame in calibration_frames(calib, run.fp32.size):
            run.fp32.infer(*frame, iters=1, record=record)
    quantize_graph(src, dst, record["encoder"], stem)
    entry = dict(file=dst.name, float_nodes=stem, calibration=label if calib is None else calib)
    engine = network_engine(run.bundle, "int8", run.threads, dict(run.meta, int8_encoder=entry),
                            runtime=RUNTIME, int8_encoder="on")
    shift = agreement(engine, run.fp32, run.frames, run.iters)
    if run.over(shift, run.max_graph_px) > 1:
        dst.unlink()
        return None
    return dict(entry, mean_abs_px_vs_fp32=shift["px"], confidence_vs_fp32=shift["confidence"],
                where="the int8 precision on OpenVINO where the float encoder would run in "
                      "f32 on a CPU without int8 dot products")


def quantize_bundle(bundle: Path, calib: str | list, max_graph_px: float = 0.1, iters: int = 4,
                    eval_dir: Path | None = None, threads: int = 2,
                    node_search: bool = True, calib_label: str | None = None,
                    max_total_px: float = 0.05, timing_runtime: str = "auto",
                    min_gain: float = 0.05, max_confidence: float = 0.03) -> dict:
    """calib: a `calibration_frames` spec, or the frames themselves ((left, right, sparse)
    tuples of (H, W) arrays, e.g. a robot's recordings), then named by `calib_label`."""
    meta = load_bundle_meta(bundle)
    meta.pop("int8_encoder", None)  # made again below, where the encoder stays float
    timing = resolve_runtime(timing_runtime)
    run = GraphChoices(bundle, meta, [], iters, threads, timing, max_graph_px, max_total_px,
                       max_confidence, min_gain, node_search)
    given = not isinstance(calib, str)  # a robot's own frames
    if not given:
        run.frames = list(calibration_frames(calib, run.fp32.size))
    else:
        run.frames, calib = list(calib), calib_label or f"{len(calib)} frames"
    if not run.frames:
        raise SystemExit(f"--calib {calib}: no frames")
    run.calibrate()
    for part in PARTS:
        run.choose(part)
    total = run.cap_total()
    # the rig's scenes where a spec names the frames (the shipped bundle's judgement); a
    # robot's own recordings where they were given
    alternative = None if run.graphs["encoder"]["int8"] else int8_encoder(
        run, None if given else ENCODER_CALIB, str(calib))
    if alternative is not None:
        meta["int8_encoder"] = alternative
    meta["quantization"] = dict(
        format="QDQ", activations="QUInt8", weights="QInt8 per-channel",
        op_types=["Conv"],
        float_ops="correlation (MatMul), lookup (GatherElements), CSPN, convex upsampling "
                  "softmax: kept float (quantizing them cost agreement, gained no speed)",
        calibration=calib, calibration_frames=len(run.frames), iters=iters,
        max_graph_px=max_graph_px, max_total_px=max_total_px, graphs=run.graphs,
        timing_runtime=timing, min_gain=min_gain, max_confidence=max_confidence,
        mean_abs_px_vs_fp32=total[RUNTIME]["px"], vs_fp32=total,
        cpu=cpu_description(),  # the speed half of each choice was measured on it
    )
    if eval_dir is not None:
        meta["quantization"]["eval"] = evaluate_precisions(
            run.fp32, network_engine(bundle, "int8", threads, meta, runtime=RUNTIME),
            eval_dir, iters)
    (bundle / "model.json").write_text(json.dumps(meta, indent=2))
    return meta["quantization"]


def evaluate_precisions(fp32: Engine, int8: Engine, eval_dir: Path, iters: int) -> dict:
    """Both precisions on the --eval scene folders: EPE, its change and the speed-up."""
    folders = list_scene_folders(eval_dir)
    if not folders:
        raise SystemExit(f"--eval {eval_dir}: no scene folders")
    res = {"fp32": evaluate(fp32, folders, iters), "int8": evaluate(int8, folders, iters)}
    res["epe_change_pct"] = 100 * (res["int8"]["epe"] / res["fp32"]["epe"] - 1)
    res["speedup"] = res["fp32"]["ms_median"] / res["int8"]["ms_median"]
    res["data"] = str(eval_dir)
    return res


def graph_line(part: str, g: dict) -> str:
    """One graph's choice, for the printout: int8 or float, and why."""
    kept = ""
    if g["float_nodes"]:
        moved = g.get("mean_abs_px_with_float_nodes")
        kept = (f"; kept float: {', '.join(g['float_nodes'])}"
                + (f" -> moves {moved:.4f} px" if moved is not None
                   else " (every convolution: no int8 graph)"))
    return (f"{part}: {'int8' if g['int8'] else 'float'} (alone: moves disparity "
            f"{g['mean_abs_px_alone']:.4f} px, engine {g['engine_ms_fp32']:.1f} -> "
            f"{g['engine_ms_with_this_int8']:.1f} ms median, int8/float "
            f"{g['int8_to_fp32_ratio']:.2f} median of paired calls)" + kept
            + ("; back to float: the int8 graphs together moved the disparity or the "
               "confidence too much" if g.get("float_for_the_total") else "")
            + "".join(f"; {rt}: {a['px']:.4f} px, confidence {a['confidence']:.4f}"
                      for rt, a in g.get("alone", {}).items()))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("bundle", type=Path)
    p.add_argument("--calib", default="synthetic:16",
                   help="scene folders, or synthetic:N rig scenes (training seeds); "
                        "default synthetic:16")
    p.add_argument("--eval", type=Path, default=None, help="scene folders with GT to compare")
    p.add_argument("--iters", type=int, default=4)
    p.add_argument("--max-graph-px", type=float, default=0.1,
                   help="keep a graph in float if quantizing it alone moves the disparity "
                        "by more than this (mean px)")
    p.add_argument("--max-total-px", type=float, default=0.05,
                   help="then, while all the int8 graphs together move it by more than "
                        "this, the one that moves it most alone goes back to float")
    p.add_argument("--timing-runtime", default="auto",
                   choices=("auto", "onnxruntime", "openvino"),
                   help="the runtime the speed test runs on: the one the engine will use")
    p.add_argument("--min-gain", type=float, default=0.05,
                   help="a graph goes int8 only if the engine gets at least this much faster")
    p.add_argument("--max-confidence", type=float, default=0.03,
                   help="the same limits for the confidence map (mean |difference|, 0-1): a "
                        "graph, and then all of them, checked on both runtimes")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--no-node-search", action="store_true",
                   help="skip the per-convolution sensitivity pass")
    args = p.parse_args(argv)
    if not (args.bundle / "model.json").is_file():
        p.error(f"{args.bundle}: not a bundle (no model.json; run tools/export.py)")
    q = quantize_bundle(args.bundle, args.calib, args.max_graph_px, args.iters, args.eval,
                        args.threads, not args.no_node_search,
                        max_total_px=args.max_total_px,
                        timing_runtime=args.timing_runtime, min_gain=args.min_gain,
                        max_confidence=args.max_confidence)
    for part, g in q["graphs"].items():
        print(graph_line(part, g))
    alternative = load_bundle_meta(args.bundle).get("int8_encoder")
    if alternative is not None:
        print(f"int8 encoder beside the float one ({alternative['file']}, kept float: "
              f"{', '.join(alternative['float_nodes'])}): the int8 precision with it moves the "
              f"disparity {alternative['mean_abs_px_vs_fp32']:.4f} px; run where the float "
              "encoder would run in f32 without int8 dot products")
    for rt, t in q["vs_fp32"].items():
        print(f"int8 vs fp32 on the calibration frames, {rt}: disparity {t['px']:.4f} px, "
              f"confidence {t['confidence']:.4f} (mean |difference|)")
    if "eval" in q:
        e = q["eval"]
        print(f"EPE fp32 {e['fp32']['epe']:.3f} -> int8 {e['int8']['epe']:.3f} "
              f"({e['epe_change_pct']:+.1f} %), bad-3 {e['fp32']['bad3']:.2f} -> "
              f"{e['int8']['bad3']:.2f}; median {e['fp32']['ms_median']:.1f} -> "
              f"{e['int8']['ms_median']:.1f} ms (x{e['speedup']:.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
