"""The budgeted inference engine: an exported bundle run with ONNX Runtime or OpenVINO, no
torch (`edge.runtime.backends`).

The encoder runs once per frame, the update step up to `iters` times, the convex upsampling
once after the last step (with a bundle that has the refinement stage, it also returns the
per-pixel confidence 0-1 that the disparity is within 1 px). With a deadline, the engine
stops iterating when the next step, predicted from this frame's steps so far plus the
upsampling time of earlier frames, would finish after it; it always runs at least one step.
"""

from __future__ import annotations

import json
import os
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

from edge_depth.errors import ConfigError, InvalidDataError
from edge_depth.runtime.backends import BF16_GRAPHS, cpu_has_bf16, open_session, resolve_runtime
from edge_depth.runtime.edge_match import (
    AUTO,
    ROW_STEPS,
    EdgeMatch,
    check_matcher,
    check_row_step,
    disparities_for,
)
from edge_depth.runtime.edge_median import OFF, PATTERNS, check_pattern, settings_text
from edge_depth.runtime.edge_select import EdgeSelect
from edge_depth.runtime.fit import FitPlan
from edge_depth.runtime.lidar_select import LidarSelect
from edge_depth.types import DepthResult

DEFAULT_BUNDLE = Path(__file__).resolve().parents[1] / "models" / "default"
MIN_DISPARITY = 0.5  # px: below this the depth is reported invalid (beyond f·B/0.5)


def load_bundle_meta(bundle: Path) -> dict:
    path = Path(bundle) / "model.json"
    if not path.is_file():
        raise ConfigError("bundle", "a directory with model.json (tools/export.py)", str(bundle))
    try:
        meta = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError("bundle", f"valid JSON in {path}", str(exc)) from None
    missing = [k for k in ("size", "downsample", "precisions") if not isinstance(meta, dict)
               or k not in meta]
    if missing:
        raise ConfigError("bundle", f"{path} with the keys size, downsample and precisions "
                          "(tools/export.py writes them)", f"missing {missing}")
    return meta


ENGINE_DEFAULTS = {"edge_match": 0, "edge_match_rows": 1,  # where a bundle declares nothing
                   "edge_median": OFF}


def bundle_engine_defaults(meta: dict, bundle: Path | str = "") -> dict:
    """The engine settings a bundle was made for (model.json's "engine", written by
    tools/export.py: version 10's head is trained to hand its unsure edges to the matching),
    over `ENGINE_DEFAULTS`; ConfigError naming the bundle when a value is not one the engine
    takes (a hand-edited model.json)."""
    declared = meta.get("engine") or {}
    if not isinstance(declared, dict):
        raise ConfigError("bundle", "model.json's \"engine\" as a table of settings",
                          f"{declared!r} in {bundle}")
    values = {**ENGINE_DEFAULTS, **{k: v for k, v in declared.items() if k in ENGINE_DEFAULTS}}
    match = values["edge_match"]
    if not (match == AUTO or (isinstance(match, int) and not isinstance(match, bool)
                              and match >= 0 and match % 16 == 0)):
        raise ConfigError("bundle", f"model.json's engine.edge_match {AUTO!r} or a multiple "
                          "of 16 (0 = off)", f"{match!r} in {bundle}")
    if values["edge_match_rows"] not in ROW_STEPS:
        raise ConfigError("bundle", "model.json's engine.edge_match_rows "
                          + " or ".join(map(str, ROW_STEPS)),
                          f"{values['edge_match_rows']!r} in {bundle}")
    if values["edge_median"] != OFF and values["edge_median"] not in PATTERNS:
        raise ConfigError("bundle", "model.json's engine.edge_median " + settings_text(),
                          f"{values['edge_median']!r} in {bundle}")
    return values


class Engine:
    """`Engine(bundle, precision='int8', threads=2)`; `infer(left, right, sparse)`.

    Any camera size runs: images that are not the bundle's size are scaled by `scale` (None
    or 0: the largest factor ≤ 1 that fits) and padded to it, and the outputs come back at the
    camera's size (`edge.runtime.fit`). `runtime`: "auto" | "onnxruntime" | "openvino";
    `bf16` (OpenVINO only): run the graphs in `BF16_GRAPHS` in bf16; None = where the CPU
    has it natively. `lidar_select`: run the bundle's LiDAR selection
    (`edge.runtime.lidar_select`) when it has one; `edge_select`: on frames without LiDAR
    points, its edge selection (`edge.runtime.edge_select`) when it has one. `edge_match`:
    0 (off), StereoBM's disparity count or "auto" (each frame's, from the network's own
    disparity) for the full-resolution matching at the network's uncertain edges
    (`edge.runtime.edge_match`), after the selections. With a fixed count the block matching
    runs beside the graphs; "auto" needs the network's disparity: where the graphs leave a
    core idle (`threads` below the usable cores) the choice's pair-only terms run beside the
    encoder and StereoBM starts with the count guessed from the disparity one step before the
    last, beside that step (again after the graphs, should the final disparity need another
    count: `match_starts` counts both), else after the graphs, beside the choice's preparation
    (`EdgeMatch.prepare`); the outputs are the same either way. `edge_match_rows`:
    2 matches every other row (half StereoBM's time), 1 every row. None (the default) for
    either: what the bundle declares in model.json's "engine" (`bundle_engine_defaults`:
    the shipped bundle's head is made for the matching, "auto" on every other row); 0 and
    1 where it declares nothing. Tools that fit or check the network's own output pass 0.
    `edge_matcher`: the matching's block matcher, "bm" (StereoBM) or "sgbm" (fewer holes at
    about SGBM's time: for a robot with the cores). `edge_median`: the matching's last step,
    a grey-guided weighted median over its gate (`edge.runtime.edge_median`: a pattern of
    its PATTERNS, or "off"); None: the bundle's (the shipped one's "9x9/2"), "off" where it
    declares nothing."""

    def __init__(self, bundle: Path | str = DEFAULT_BUNDLE, precision: str = "int8",
                 threads: int = 2, meta: dict | None = None, scale: float | None = None,
                 runtime: str = "auto", bf16: bool | None = None,
                 lidar_select: bool = True, edge_select: bool = True,
                 edge_match: int | str | None = None,
                 edge_match_rows: int | None = None, edge_matcher: str = "bm",
                 edge_median: str | None = None) -> None:
        self.runtime = resolve_runtime(runtime)
        if bf16 is None:
            bf16 = self.runtime == "openvino" and cpu_has_bf16()
        self.bf16 = bool(bf16) and self.runtime == "openvino"
        self.bundle = Path(bundle)
        self.meta = meta or load_bundle_meta(self.bundle)
        files = self.meta["precisions"].get(precision)
        if files is None:
            raise ConfigError("precision", f"one of {sorted(self.meta['precisions'])}",
                              precision)
        self.precision = precision
        self.width, self.height = self.meta["size"]
        self.downsample = int(self.meta["downsample"])
        self.default_iters = int(self.meta.get("default_iters", 4))
        self.sessions = {}
        # the encoder last: it computes only what the step and the upsampling read (OpenVINO;
        # version 10's upsampling reads no 1/4 features: 1.4 ms of a frame at one thread)
        for part in sorted(files, key=lambda p: p == "encoder"):
            name = files[part]
            read = None if part != "encoder" else {"disparity", "hidden"}.union(
                *(self.sessions[p].input_names for p in self.sessions))
            try:
                self.sessions[part] = open_session(self.bundle / name, self.runtime, threads,
                                                   self.bf16 and part in BF16_GRAPHS, read)
            except Exception as exc:  # noqa: BLE001 - the runtimes' errors have no base
                first = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else ""
                raise ConfigError("bundle", f"a loadable ONNX graph at {self.bundle / name} "
                                  "(re-export with tools/export.py)",
                                  f"{type(exc).__name__}: {first}") from None
        self._enc_outputs = self.sessions["encoder"].output_names
        self._step_state = [n for n in self.sessions["step"].input_names
                            if n not in ("disparity", "hidden")]
        upsample = self.sessions["upsample"]
        # the step and the upsampling read what the encoder wrote, by name: graphs from two
        # exports (newer bundles pass the context as two precomputed terms, older ones as itself; a
        # refinement's version decides what the upsampling reads) would fail on frame 1
        fed = {"disparity", "hidden", *self._enc_outputs}
        for part, extra in (("step", set()), ("upsample", {"left", "right", "sparse", "valid"})):
            missing = [n for n in self.sessions[part].input_names if n not in fed | extra]
            if missing:
                raise ConfigError("bundle", f"graphs exported together (tools/export.py): "
                                  f"{part}.onnx reads what encoder.onnx writes",
                                  f"{part}.onnx needs {', '.join(missing)}, which "
                                  f"{self.bundle / 'encoder.onnx'} does not output")
        # a refining upsample graph also takes the images (and, versions 2-3, the LiDAR;
        # version 4: the encoder's 1/4 features and the LiDAR)
        self._upsample_inputs = [n for n in upsample.input_names
                                 if n in ("left", "right", "sparse", "valid")]
        self._upsample_state = [n for n in upsample.input_names if n in self._enc_outputs
                                and n not in ("disparity", "hidden")]
        self.has_confidence = len(upsample.output_names) > 1
        shape = (1, 1, self.height, self.width)
        self._inputs = {k: np.zeros(shape, np.float32) for k in ("left", "right", "sparse",
                                                                 "valid")}
        self.select = LidarSelect.from_meta(self.meta["lidar_select"]) \
            if lidar_select and "lidar_select" in self.meta else None
        self.edge_select = EdgeSelect.from_meta(self.meta["edge_select"]) \
            if edge_select and "edge_select" in self.meta else None
        declared = bundle_engine_defaults(self.meta, self.bundle)
        self.edge_match_source = "bundle" if edge_match is None and edge_median is None \
            else "given"
        edge_match = declared["edge_match"] if edge_match is None else edge_match
        edge_match_rows = declared["edge_match_rows"] if edge_match_rows is None \
            else edge_match_rows
        edge_median = declared["edge_median"] if edge_median is None else edge_median
        self.edge_match = None
        check_row_step(edge_match_rows)  # also when the matching is off: a bad value is said
        check_matcher(edge_matcher)
        if edge_median != OFF:
            check_pattern(edge_median)
        options = dict(row_step=edge_match_rows, matcher=edge_matcher, median=edge_median)
        if edge_match == AUTO:  # the count per frame, from the network's own disparity
            self.edge_match = EdgeMatch(0, **options)
        elif edge_match:
            if not isinstance(edge_match, int) or isinstance(edge_match, bool):
                raise ConfigError("edge_match", f"{AUTO!r}, 0 (off) or a multiple of 16",
                                  edge_match)
            self.edge_match = EdgeMatch(edge_match, **options)
            if edge_match >= self.width:  # StereoBM would silently find nothing
                raise ConfigError("edge_match", f"below the bundle's input width "
                                  f"({self.width} px)", edge_match)
        # its block matching needs only the images: it runs beside the network's graphs,
        # whose small 1/8-resolution tensors leave the second core partly idle
        self._matching: ThreadPoolExecutor | None = None  # started on first use
        # frames whose matching started before the network's end, and of those, how many
        # matched again because the final disparity needed another count than the guess
        self.match_starts = {"early": 0, "again": 0}
        # "auto" starts early only where the graphs leave a core idle: with every core in the
        # graphs, StereoBM beside them slowed them by as much as it saved (docs/experiments.md)
        self.match_early = int(threads) < usable_cores()
        self._upsample_ms = 0.0  # running estimate for the deadline
        self.scale = scale
        self._plans: dict[tuple[int, int], FitPlan] = {}

    def _matcher_thread(self) -> ThreadPoolExecutor:
        """The matching's own thread (started on first use): OpenCV's StereoBM releases the
        GIL, so it runs beside the graphs (a fixed count) or beside the choice's preparation
        ("auto")."""
        if self._matching is None:
            self._matching = ThreadPoolExecutor(1, "edge-match")
        return self._matching

    def _pair_copies(self) -> list[np.ndarray]:
        """This frame's left, right and sparse inputs, copied for the matching's thread (the
        buffers get reused)."""
        return [self._inputs[k][0, 0].copy() for k in ("left", "right", "sparse")]

    def _match_early(self, count: int, copies: list[np.ndarray] | None = None,
                     terms: Future | None = None):
        """StereoBM with `count` on the matching's thread, from copies of this frame's pair
        (`copies`, else made here), and the choice's pair-only terms (`EdgeMatch.pair_terms`:
        computed there after it, or already submitted as `terms`): (count, the job, whose
        result is (matched, terms))."""
        match = self.edge_match
        left, right, sparse = copies or self._pair_copies()
        if terms is None:
            terms = self._matcher_thread().submit(match.pair_terms, left, right, sparse)
        # the thread runs one job at a time, in order: `terms` is done before this one starts
        return count, self._matcher_thread().submit(
            lambda: (match.matched(left, right, count), terms.result()))

    def _guess_count(self, disparity: np.ndarray) -> int:
        """The "auto" count a low-resolution step output (1, 1, h, w) would give: its largest
        value brought to full-resolution pixels (the convex upsampling never exceeds it)."""
        return disparities_for(disparity[0, 0] * self.downsample, self.width)

    def plan_for(self, camera: tuple[int, int]) -> FitPlan:
        """How a (w, h) camera runs on this bundle (ConfigError for an impossible scale)."""
        if camera not in self._plans:
            self._plans[camera] = FitPlan.make(camera, self.size, self.scale)
        return self._plans[camera]

    def warm_up(self, iters: int = 1) -> None:
        """One untimed inference on a blank frame: the first run of each session allocates
        and plans, and would otherwise land on the first real frame's latency."""
        blank = np.zeros((self.height, self.width), np.uint8)
        self.infer(blank, blank, np.zeros((self.height, self.width), np.float32), iters=iters)

    def describe(self) -> str:
        """'int8 on openvino (bf16 encoder), edge matching auto on every 2nd row, weighted
        median 9x9/2 (the bundle's)': what runs, for the first log line."""
        text = f"{self.precision} on {self.runtime}" + (" (bf16 encoder)" if self.bf16 else "")
        m = self.edge_match
        source = " (the bundle's)" if self.edge_match_source == "bundle" else ""
        if m is None:
            return text + f", edge matching off{source}"
        count = m.num_disparities or AUTO
        rows = " on every 2nd row" if m.row_step == 2 else ""
        sgbm = " with SGBM" if m.matcher == "sgbm" else ""
        median = f", weighted median {m.median}" if m.median != OFF else ""
        return text + f", edge matching {count}{sgbm}{rows}{median}{source}"

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    def infer(self, left: np.ndarray, right: np.ndarray, sparse: np.ndarray,
              iters: int | None = None, deadline_ms: float | None = None,
              focal_px: float | None = None, baseline_m: float | None = None,
              stamp_ns: int = 0, started: float | None = None,
              record: dict[str, list] | None = None) -> DepthResult:
        """Rectified grey pair (H, W) and sparse disparity (H, W, px, 0 = none) -> DepthResult.

        `started` (time.perf_counter()) is when the deadline's clock began; default now.
        `record`, if given, collects each graph's input feeds (quantization calibration)."""
        t_engine = time.perf_counter()
        t0 = t_engine if started is None else started
        iters = self.default_iters if iters is None else int(iters)
        if iters < 1:
            raise ConfigError("iters", ">= 1", iters)
        for name, image in (("right", right), ("sparse", sparse)):
            if image.shape != left.shape:
                raise InvalidDataError(f"{name} image", f"the left image's shape {left.shape}",
                                       image.shape)
        if left.ndim != 2 or min(left.shape) < 8:
            raise InvalidDataError("left image", "(H, W) grey, at least 8x8", left.shape)
        plan = self.plan_for((left.shape[1], left.shape[0]))
        if not plan.identity:
            left, right, sparse = plan.prepare(left, right, sparse)
        buf = self._inputs
        np.copyto(buf["left"][0, 0], left, casting="unsafe")
        np.copyto(buf["right"][0, 0], right, casting="unsafe")
        finite = np.isfinite(sparse) & (sparse > 0)
        np.copyto(buf["valid"][0, 0], finite, casting="unsafe")
        np.copyto(buf["sparse"][0, 0], np.where(finite, sparse, 0.0), casting="unsafe")

        match = self.edge_match if self.has_confidence else None  # it gates on the confidence
        early = None  # (count, the matching thread's job): started before the network ends
        if match is not None and match.num_disparities:
            early = self._match_early(match.num_disparities)
        # "auto", where the graphs leave a core idle: the choice's pair-only terms beside the
        # encoder, then StereoBM with the count guessed from the disparity with one step to go
        # (after the encoder at one step), beside the last step (docs/experiments.md: beside the
        # memory-bound upsampling, it slowed that graph by more than it saved)
        guess_after = iters - 2 if match is not None and early is None and \
            self.match_early else iters
        copies = terms_job = None
        if guess_after < iters:
            copies = self._pair_copies()
            terms_job = self._matcher_thread().submit(match.pair_terms, *copies)

        def feed(part: str, feeds: dict) -> dict:
            if record is not None:
                record.setdefault(part, []).append({k: v.copy() for k, v in feeds.items()})
            return feeds

        timings: dict[str, float] = {}
        t = time.perf_counter()
        outputs = self.sessions["encoder"].run(feed("encoder", buf))
        enc = dict(zip(self._enc_outputs, outputs, strict=True))
        timings["encoder"] = (time.perf_counter() - t) * 1000
        state = {k: enc[k] for k in self._step_state}
        disparity, hidden = enc["disparity"], enc["hidden"]
        if guess_after == -1:
            early = self._match_early(self._guess_count(disparity), copies, terms_job)
        step_ms: list[float] = []
        step = self.sessions["step"]
        for i in range(iters):
            if deadline_ms is not None and i > 0:
                elapsed = (time.perf_counter() - t0) * 1000
                predicted = elapsed + max(step_ms) + self._upsample_ms
                if predicted > deadline_ms:
                    break
            t = time.perf_counter()
            feeds = dict(state, disparity=disparity, hidden=hidden)
            disparity, hidden = step.run(feed("step", feeds))
            step_ms.append((time.perf_counter() - t) * 1000)
            if i == guess_after:
                early = self._match_early(self._guess_count(disparity), copies, terms_job)
        timings["steps"] = float(sum(step_ms))
        timings["step_mean"] = float(np.mean(step_ms))
        t = time.perf_counter()
        feeds = dict(disparity=disparity, hidden=hidden)
        feeds.update({k: buf[k] for k in self._upsample_inputs})
        feeds.update({k: enc[k] for k in self._upsample_state})
        full, *rest = self.sessions["upsample"].run(feed("upsample", feeds))
        up_ms = (time.perf_counter() - t) * 1000
        timings["upsample"] = up_ms
        disp = np.ascontiguousarray(full[0, 0], dtype=np.float32)
        confidence = np.ascontiguousarray(rest[0][0, 0], dtype=np.float32) if rest else None
        if confidence is not None and confidence.shape != disp.shape:
            # bundles since stage 11 return it at the refinement's 1/4 resolution
            confidence = cv2.resize(confidence, disp.shape[::-1],
                                    interpolation=cv2.INTER_LINEAR)
        selected = edge_px = None
        if self.edge_select is not None and confidence is not None and not finite.any():
            # no LiDAR point: the edge selection instead of the LiDAR one (never both, so the
            # slowest frame's time does not grow)
            t = time.perf_counter()
            disp, confidence, edge_px = self.edge_select.apply(
                buf["left"][0, 0], buf["right"][0, 0], disp, confidence)
            timings["edge_select"] = (time.perf_counter() - t) * 1000
            up_ms += timings["edge_select"]
        elif self.select is not None and confidence is not None:
            t = time.perf_counter()
            disp, confidence, selected = self.select.apply(
                buf["left"][0, 0], buf["right"][0, 0], disp, confidence, buf["sparse"][0, 0])
            timings["select"] = (time.perf_counter() - t) * 1000
            up_ms += timings["select"]
        matched = beyond = None
        if match is not None and confidence is not None:
            t = time.perf_counter()  # from here: the wait for the matching, then the choice
            pair = (buf["left"][0, 0], buf["right"][0, 0])
            count = match.num_disparities or disparities_for(disp, self.width)
            beyond = match.beyond_px(disp, count)
            # the terms already computed beside the encoder (a deadline may have stopped
            # the steps before the guess)
            terms = None if terms_job is None else terms_job.result()
            if early is not None:
                early_count, job = early
                found, terms = job.result()
                self.match_starts["early"] += 1
                if early_count != count:  # the guess missed: StereoBM again, the count right
                    self.match_starts["again"] += 1
                    early = None
            # late (no guess, or a missed one): StereoBM matches while the choice prepares
            job = None if early is not None else \
                self._matcher_thread().submit(match.matched, *pair, count)
            prepared = match.prepare(*pair, disp, confidence, buf["sparse"][0, 0], terms)
            disp, matched = match.finish(prepared, disp, found if job is None else job.result())
            timings["edge_match"] = (time.perf_counter() - t) * 1000
            up_ms += timings["edge_match"]
        # what follows the last step, for the deadline's prediction
        self._upsample_ms = up_ms if self._upsample_ms == 0 else 0.8 * self._upsample_ms + \
            0.2 * up_ms
        if not plan.identity:
            disp = plan.restore(disp, disparity=True)
            confidence = None if confidence is None else plan.restore(confidence, False)
        depth, valid = disparity_to_depth(disp, focal_px, baseline_m)
        # the engine's own time; the deadline counted from `started` (the daemon: the frame's
        # preparation), which made this include rectification and projection before
        timings["engine"] = (time.perf_counter() - t_engine) * 1000
        return DepthResult(stamp_ns=int(stamp_ns), disparity=disp, depth=depth, valid=valid,
                           iterations=len(step_ms), timings_ms=timings, confidence=confidence,
                           selected_px=selected, edge_px=edge_px, matched_px=matched,
                           match_beyond_px=beyond)


def usable_cores() -> int:
    """The CPUs this process may run on (its affinity where the OS says, else all)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def disparity_to_depth(disparity: np.ndarray, focal_px: float | None,
                       baseline_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """depth = f·B / d where d ≥ MIN_DISPARITY and finite; 0 and invalid elsewhere."""
    valid = np.isfinite(disparity) & (disparity >= MIN_DISPARITY)
    if focal_px is None or baseline_m is None:
        return np.zeros_like(disparity, dtype=np.float32), valid
    depth = np.zeros_like(disparity, dtype=np.float32)
    np.divide(float(focal_px) * float(baseline_m), disparity, out=depth, where=valid)
    return depth, valid
