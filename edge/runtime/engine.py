"""The budgeted inference engine: an exported bundle run with ONNX Runtime or OpenVINO, no
torch (`edge.runtime.backends`).

The encoder runs once per frame, the update step up to `iters` times, the convex upsampling
once after the last step (with a bundle that has the refinement stage, it also returns the
per-pixel confidence 0-1 that the disparity is within 1 px). With a deadline, the engine
stops iterating when the next step, predicted from this frame's steps so far plus the
running times of the stages after the steps on earlier frames, would finish after it (it
always runs at least one step), and skips the band refinement where it would end after it
(`Engine._refine`).
"""

from __future__ import annotations

import importlib
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from edge_depth.errors import ConfigError, InvalidDataError
from edge_depth.runtime.backends import (
    cpu_has_bf16,
    resolve_int8_encoder,
    resolve_precision,
    resolve_runtime,
)
from edge_depth.runtime.edge_median import OFF, EdgeMedian, unsure_edges
from edge_depth.runtime.fit import FitPlan
from edge_depth.runtime.graphs import BundleGraphs, load_bundle_meta
from edge_depth.runtime.lidar_align import LidarAlign, Offset
from edge_depth.runtime.lidar_denoise import LidarDenoise
from edge_depth.runtime.lidar_select import LidarSelect
from edge_depth.runtime.options import BUDGET, FIT, NATIVE, EngineOptions, bundle_preset
from edge_depth.types import DepthResult
from edge_depth.workers import one_openblas_thread

DEFAULT_BUNDLE = Path(__file__).resolve().parents[1] / "models" / "default"
MIN_DISPARITY = 0.5  # px: below this the depth is reported invalid (beyond f·B/0.5)
# "native": a side of at least this many network strides (the correlation pyramid's coarsest
# level, 1/64 of the width, keeps a column)
NATIVE_MIN_STRIDES = 8
# the encoder's outputs made from the LiDAR (the seed and the anchors at 1/8); the others are
# the images' alone, so a stereo-only pass can reuse them (`Engine.stereo_only`)
LIDAR_OUTPUTS = ("disparity", "sparse_low", "valid_low")
# with a deadline the band refinement runs after this many skips in a row anyway, to measure
# its time again (`Engine._band_late`): one frame in eleven may end late while it does not fit
RETRY_BAND_AFTER = 10


class Engine:
    """`Engine(bundle, options)` or `Engine(**overrides)`; `infer(left, right, sparse)`.

    `options` (`edge.runtime.options.EngineOptions`; the fields given as keyword arguments
    override it) say everything the engine does; the bundle's preset fills those left at
    "bundle" once, here. Any camera size runs: with `scale` "fit" (or a factor) images that
    are not the bundle's size are scaled into it and padded; on a bundle whose graphs take any
    size (model.json's "any_size"), "budget" scales them to the bundle's pixel count at their
    own aspect and "native" runs them at their own size, padded to the network's stride; the
    outputs come back at the camera's size (`edge.runtime.fit`). The stages are `infer`'s.
    Every OpenBLAS in the process runs one thread from the first engine on
    (`edge.workers.one_openblas_thread`: their spinning threads took a core from it)."""

    def __init__(self, bundle: Path | str | None = None, options: EngineOptions | None = None,
                 meta: dict | None = None, **overrides) -> None:
        one_openblas_thread()
        options = EngineOptions.with_overrides(options, bundle=bundle, **overrides)
        self.options = options
        self.runtime = resolve_runtime(options.runtime)
        bf16 = options.bf16_choice
        if bf16 is None:
            bf16 = self.runtime == "openvino" and cpu_has_bf16()
        self.bf16 = bool(bf16) and self.runtime == "openvino"
        self.bundle = Path(options.bundle or DEFAULT_BUNDLE)
        self.meta = meta or load_bundle_meta(self.bundle)
        self.precision = resolve_precision(options.precision, self.runtime,
                                           self.meta["precisions"])
        self.int8_encoder = resolve_int8_encoder(options.int8_encoder, self.precision,
                                                 "int8_encoder" in self.meta, self.bf16,
                                                 self.runtime)
        self.bf16 = self.bf16 and not self.int8_encoder  # bf16 is the float encoder's
        self.width, self.height = self.meta["size"]
        self.downsample = int(self.meta["downsample"])
        self.default_iters = int(self.meta.get("default_iters", 4))
        self.any_size = bool(self.meta.get("any_size"))
        self.scale = options.scale
        if self.scale == BUDGET and not self.any_size:
            self.scale = FIT  # a bundle of one size: its pixel budget is its shape
        if self.scale == NATIVE and not self.any_size:
            raise ConfigError("scale", 'a bundle whose graphs take any size for "native" '
                              "(export it again with tools/export.py)",
                              f"native with {self.bundle}, exported for "
                              f"{self.width}x{self.height} only")
        self.graphs = BundleGraphs(self.bundle, self.meta, self.precision, self.runtime,
                                   options.threads, self.bf16, self.int8_encoder)
        self.sessions = self.graphs.sessions
        self.has_confidence = self.graphs.has_confidence
        self._inputs: dict[str, np.ndarray] = {}
        self._buffers((self.width, self.height))
        self.select = LidarSelect.from_meta(self.meta["lidar_select"]) \
            if options.lidar_select and "lidar_select" in self.meta else None
        self.lidar_denoise = LidarDenoise() if options.denoise_lidar else None
        self.lidar_align = LidarAlign() if options.align_lidar else None
        self.median_source = "bundle" if options.from_bundle() else "given"
        resolved = options.resolved(bundle_preset(self.meta, str(self.bundle)))
        self.band = load_band_refinement(options)
        # the weighted median over the network's unsure edges follows the band (or, with
        # refine "off", the network's estimate after the selection): `_refine`
        self.median = None if resolved.edge_median == OFF else \
            EdgeMedian(str(resolved.edge_median))
        # each stage after the steps: its running time estimate (ms), for the deadline
        self._after_ms: dict[str, float] = {}
        self._band_skips = 0  # frames in a row whose band the deadline skipped
        self._last: tuple[dict, FitPlan] | None = None  # the last frame's encoding
        self._plans: dict[tuple[int, int], FitPlan] = {}

    def plan_for(self, camera: tuple[int, int]) -> FitPlan:
        """How a (w, h) camera runs on this bundle (ConfigError for an impossible scale):
        "native" at its own size, "budget" scaled to the bundle's pixel count, each padded to
        the network's stride (and to at least NATIVE_MIN_STRIDES strides a side, for the
        correlation pyramid's coarsest level); otherwise scaled into the bundle's size."""
        if camera not in self._plans:
            if self.scale in (NATIVE, BUDGET):
                factor = 1.0 if self.scale == NATIVE else self._budget_factor(camera)
                network = self._network_size(camera, factor)
                self._plans[camera] = FitPlan.make(camera, network, factor)
            else:
                scale = None if self.scale == FIT else float(self.scale)
                self._plans[camera] = FitPlan.make(camera, self.size, scale)
        return self._plans[camera]

    def _network_size(self, camera: tuple[int, int], factor: float) -> tuple[int, int]:
        """The padded network input for a camera scaled by `factor`."""
        side, step = self.downsample * NATIVE_MIN_STRIDES, self.downsample
        w, h = (max(side, -(-math.ceil(n * factor - 1e-9) // step) * step) for n in camera)
        return w, h

    def _budget_factor(self, camera: tuple[int, int]) -> float:
        """The largest factor ≤ 1 whose padded input has no more pixels than the bundle's."""
        budget = self.width * self.height
        factor = min(1.0, math.sqrt(budget / (camera[0] * camera[1])))
        while factor > 0.05:
            w, h = self._network_size(camera, factor)
            if w * h <= budget:
                break
            factor *= 0.995
        return factor

    def _buffers(self, size: tuple[int, int]) -> dict[str, np.ndarray]:
        """The graphs' input buffers for a (w, h) network input (kept while it stays)."""
        first = next(iter(self._inputs.values()), None)
        if first is None or first.shape[2:] != (size[1], size[0]):
            shape = (1, 1, size[1], size[0])
            self._inputs = {k: np.zeros(shape, np.float32)
                            for k in ("left", "right", "sparse", "valid")}
        return self._inputs

    def _stage_pair(self) -> tuple[np.ndarray, np.ndarray]:
        """The (left, right) pair the stages after the network read, at the graphs' size."""
        return self._inputs["left"][0, 0], self._inputs["right"][0, 0]

    def warm_up(self, iters: int = 1, camera: tuple[int, int] | None = None) -> None:
        """One untimed inference on a blank frame of the camera's (w, h) (default: the
        bundle's size): the first run of each session allocates and plans (and OpenVINO
        compiles a graph that takes any size for this one), which would otherwise land on
        the first real frame's latency."""
        w, h = camera or self.size
        blank = np.zeros((h, w), np.uint8)
        self.infer(blank, blank, np.zeros((h, w), np.float32), iters=iters)
        self._after_ms = {}  # its times (numba's kernels loaded, pages first touched) mislead

    @property
    def bf16_encoder(self) -> bool:
        """Whether the encoder runs in bf16: asked for, and compiled so (a CPU that reports
        bf16 but cannot compile it runs f32, `backends.OpenVinoSession`)."""
        return self.bf16 and bool(getattr(self.sessions["encoder"], "bf16", False))

    def describe(self) -> str:
        """'int8 on openvino (bf16 encoder), band refinement, weighted median 9x9/2 (the
        bundle's)': what runs, for the first log line (the default "budget" scale goes without
        saying)."""
        text = f"{self.precision} on {self.runtime}" + \
            (" (bf16 encoder)" if self.bf16_encoder else "") + \
            (" (int8 encoder)" if self.int8_encoder else "")
        if self.scale == NATIVE:  # the default ("budget") goes without saying
            text += ", at the camera's own size"
        source = " (the bundle's)" if self.median_source == "bundle" else ""
        median = "" if self.median is None or not self.has_confidence else \
            f", weighted median {self.median.pattern}{source}"  # it gates on the confidence
        refined = ", band refinement" if self.band is not None else ", no refinement"
        return text + refined + median

    @property
    def size(self) -> tuple[int, int]:
        return self.width, self.height

    def infer(self, left: np.ndarray, right: np.ndarray, sparse: np.ndarray,
              iters: int | None = None, deadline_ms: float | None = None,
              focal_px: float | None = None, baseline_m: float | None = None,
              stamp_ns: int = 0, started: float | None = None,
              record: dict[str, list] | None = None) -> DepthResult:
        """Rectified grey pair (H, W) and sparse disparity (H, W, px, 0 = none) -> DepthResult.

        The stages in order: prepare (the LiDAR map's checks, scale and pad to the bundle) →
        encode → iterate (the GRU steps under the deadline) → upsample (and the confidence)
        → select (the LiDAR selection) → refine (the band refinement, `edge.runtime.band_sgm`,
        unless `refine = "off"`) → median (over the network's unsure edges) → restore (to the
        camera's size) → depth. `started` (time.perf_counter()) is when the deadline's clock
        began; default now. `record`, if given, collects each graph's input feeds
        (quantization calibration)."""
        t_engine = time.perf_counter()
        deadline_ms = deadline_ms or None  # 0: none
        iters = self.default_iters if iters is None else int(iters)
        if iters < 1:
            raise ConfigError("iters", ">= 1", iters)
        frame = _Frame(t_engine if started is None else started, record)
        plan = self._prepare(frame, left, right, sparse)
        enc = self._encode(frame)
        self._last = (enc, plan)
        disparity, hidden = self._iterate(frame, enc, iters, deadline_ms)
        disp, confidence = self._upsample(frame, enc, disparity, hidden)
        frame.counts["counted_px"] = disp.size  # the grid the stages count on
        disp, confidence = self._select(frame, disp, confidence)
        disp = self._refine(frame, disp, confidence, deadline_ms)
        disp = self._median(frame, disp, confidence)
        for name in frame.after_steps:  # for the deadline
            ms = frame.timings[name]
            self._after_ms[name] = 0.8 * self._after_ms.get(name, ms) + 0.2 * ms
        if not plan.identity:
            disp = plan.restore(disp, disparity=True)
            confidence = None if confidence is None else plan.restore(confidence, False)
        depth, valid = disparity_to_depth(disp, focal_px, baseline_m)
        # the engine's own time; the deadline counted from `started` (the daemon: the frame's
        # preparation), which made this include rectification and projection before
        frame.timings["engine"] = (time.perf_counter() - t_engine) * 1000
        return DepthResult(stamp_ns=int(stamp_ns), disparity=disp, depth=depth, valid=valid,
                           iterations=frame.steps, timings_ms=frame.timings,
                           confidence=confidence,
                           lidar_offset=frame.lidar_offset,
                           lidar_noise_px=frame.lidar_noise_px, **frame.counts)

    def stereo_only(self, iters: int = 2) -> np.ndarray:
        """The last frame's network disparity without the LiDAR, (H, W) float32 at the
        camera's size: its encoder's image features again (they do not depend on the LiDAR),
        the seed and the anchors zeroed (`LIDAR_OUTPUTS`), `iters` steps, upsampled; no
        selection, refinement or median. A reference that never saw the LiDAR, for
        `edge.calibration_watch`; call it after `infer`, on the same thread."""
        if self._last is None:
            raise RuntimeError("stereo_only follows an infer of the frame")
        enc, plan = self._last
        enc = dict(enc, **{k: np.zeros_like(enc[k]) for k in LIDAR_OUTPUTS if k in enc})
        frame = _Frame(time.perf_counter())
        disparity, hidden = self._iterate(frame, enc, max(1, int(iters)), None)
        full = self.graphs.disparity_upsample().run(
            self._upsample_feeds(enc, disparity, hidden))[0]
        disp = np.ascontiguousarray(full[0, 0], dtype=np.float32)
        return disp if plan.identity else plan.restore(disp, disparity=True)

    def _prepare(self, frame: _Frame, left: np.ndarray, right: np.ndarray,
                 sparse: np.ndarray) -> FitPlan:
        """Checks, a noisy LiDAR map smoothed (`edge.runtime.lidar_denoise`) and moved back
        onto the image's edges where it sits off them (`edge.runtime.lidar_align`), then the
        frame scaled and padded to the bundle into the graphs' input buffers; the plan to
        restore it."""
        for name, image in (("right", right), ("sparse", sparse)):
            if image.shape != left.shape:
                raise InvalidDataError(f"{name} image", f"the left image's shape {left.shape}",
                                       image.shape)
        if left.ndim != 2 or min(left.shape) < 8:
            raise InvalidDataError("left image", "(H, W) grey, at least 8x8", left.shape)
        if self.lidar_denoise is not None:  # a noisy LiDAR map smoothed along its rows
            sparse, frame.lidar_noise_px = self.lidar_denoise.apply(sparse)
        if self.lidar_align is not None:  # the LiDAR map back onto the image's edges
            sparse, found = self.lidar_align.apply(left, sparse)
            frame.lidar_offset = found
            if frame.lidar_noise_px is None:  # its noise level, measured for the edges
                frame.lidar_noise_px = found.noise_px
        plan = self.plan_for((left.shape[1], left.shape[0]))
        if not plan.identity:
            left, right, sparse = plan.prepare(left, right, sparse)
        buf = self._buffers(plan.bundle)
        np.copyto(buf["left"][0, 0], left, casting="unsafe")
        np.copyto(buf["right"][0, 0], right, casting="unsafe")
        finite = np.isfinite(sparse) & (sparse > 0)
        np.copyto(buf["valid"][0, 0], finite, casting="unsafe")
        np.copyto(buf["sparse"][0, 0], np.where(finite, sparse, 0.0), casting="unsafe")
        return plan

    def _encode(self, frame: _Frame) -> dict[str, np.ndarray]:
        t = time.perf_counter()
        outputs = self.sessions["encoder"].run(frame.feed("encoder", self._inputs))
        frame.timings["encoder"] = (time.perf_counter() - t) * 1000
        return dict(zip(self.graphs.enc_outputs, outputs, strict=True))

    def _iterate(self, frame: _Frame, enc: dict, iters: int,
                 deadline_ms: float | None) -> tuple[np.ndarray, np.ndarray]:
        """Up to `iters` GRU steps; with a deadline, none that the prediction (this frame's
        slowest step plus what follows the steps) says would end after it; at least one.
        What follows includes the band refinement while it can still end in time (it has
        the first claim on the time left); once it cannot, the steps take that time and
        `_refine` skips it."""
        state = {k: enc[k] for k in self.graphs.step_state}
        disparity, hidden = enc["disparity"], enc["hidden"]
        step_ms: list[float] = []
        for i in range(iters):
            if deadline_ms is not None and i > 0:
                elapsed = (time.perf_counter() - frame.t0) * 1000
                after = sum(self._after_ms.values())
                if elapsed + after > deadline_ms:  # the band cannot end in time: not waited for
                    after -= self._after_ms.get("band_refine", 0.0)
                if elapsed + max(step_ms) + after > deadline_ms:
                    break
            t = time.perf_counter()
            feeds = dict(state, disparity=disparity, hidden=hidden)
            disparity, hidden = self.sessions["step"].run(frame.feed("step", feeds))
            step_ms.append((time.perf_counter() - t) * 1000)
        frame.steps = len(step_ms)
        frame.timings["steps"] = float(sum(step_ms))
        frame.timings["step_mean"] = float(np.mean(step_ms))
        return disparity, hidden

    def _upsample_feeds(self, enc: dict, disparity: np.ndarray, hidden: np.ndarray) -> dict:
        """The upsampling's inputs: the last step's state, the frame's buffers it reads and
        the encoder's outputs it reads."""
        feeds = dict(disparity=disparity, hidden=hidden)
        feeds.update({k: self._inputs[k] for k in self.graphs.upsample_inputs})
        feeds.update({k: enc[k] for k in self.graphs.upsample_state})
        return feeds

    def _upsample(self, frame: _Frame, enc: dict, disparity: np.ndarray,
                  hidden: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The convex upsampling to full resolution, and the confidence where the bundle has
        it (resized from the refinement's 1/4 resolution)."""
        t = time.perf_counter()
        feeds = self._upsample_feeds(enc, disparity, hidden)
        full, *rest = self.sessions["upsample"].run(frame.feed("upsample", feeds))
        frame.stage("upsample", t)
        disp = np.ascontiguousarray(full[0, 0], dtype=np.float32)
        confidence = np.ascontiguousarray(rest[0][0, 0], dtype=np.float32) if rest else None
        if confidence is not None and confidence.shape != disp.shape:
            confidence = cv2.resize(confidence, disp.shape[::-1],
                                    interpolation=cv2.INTER_LINEAR)
        return disp, confidence

    def _select(self, frame: _Frame, disp: np.ndarray,
                confidence: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """The LiDAR selection, where the bundle has it (on a frame without points it
        replaces nothing)."""
        if confidence is None:
            return disp, confidence
        left, right = self._stage_pair()
        t = time.perf_counter()
        if self.select is not None:
            disp, confidence, frame.counts["selected_px"] = self.select.apply(
                left, right, disp, confidence, self._inputs["sparse"][0, 0])
            frame.stage("select", t)
        return disp, confidence

    def _refine(self, frame: _Frame, disp: np.ndarray, confidence: np.ndarray | None,
                deadline_ms: float | None = None) -> np.ndarray:
        """The band refinement (`edge.runtime.band_sgm`), unless `refine` is "off" (without
        the bundle's confidence every band is its widest); its changed pixels are the frame's
        refined ones. With a deadline, skipped (`band_skipped` 1 in the frame's timings)
        where it and the median after it would end after it, as their recent times predict:
        the steps are cut first (`_iterate` counts the band's time in), the band last. Its
        threads are set on every call: numba keeps them per calling thread (the pipelined
        daemon and the ROS 2 node infer on threads of their own)."""
        if self.band is None:
            return disp
        if deadline_ms is not None and self._band_late(frame, deadline_ms):
            frame.timings["band_skipped"] = 1.0
            return disp
        left, right = self._stage_pair()
        t = time.perf_counter()
        self.band.use_threads(self.options.threads)
        disp, frame.counts["refined_px"] = self.band.refine(
            left, right, disp, confidence, self._inputs["sparse"][0, 0])
        frame.stage("band_refine", t)
        return disp

    def _band_late(self, frame: _Frame, deadline_ms: float) -> bool:
        """Whether the band refinement and the median after it would end after the deadline,
        as their running times predict. An estimate that only skips is never measured again,
        so after RETRY_BAND_AFTER skips in a row the band runs once anyway (ending late) and
        its time replaces the estimate: a slow minute need not skip it for good."""
        estimate = self._after_ms.get("band_refine")
        if estimate is None:
            return False
        elapsed = (time.perf_counter() - frame.t0) * 1000
        if elapsed + estimate + self._after_ms.get("edge_median", 0.0) <= deadline_ms:
            self._band_skips = 0
            return False
        self._band_skips += 1
        if self._band_skips < RETRY_BAND_AFTER:
            return True
        self._band_skips = 0
        del self._after_ms["band_refine"]  # this run's time is the estimate again
        return False

    def _median(self, frame: _Frame, disp: np.ndarray,
                confidence: np.ndarray | None) -> np.ndarray:
        """The grey-guided weighted median over the network's unsure edges of the (refined)
        disparity (`edge.runtime.edge_median`), where the bundle or the caller asks for it
        and the bundle has a confidence."""
        if self.median is None or confidence is None:
            return disp
        t = time.perf_counter()
        disp = self.median.apply(disp, self._stage_pair()[0], unsure_edges(disp, confidence))
        frame.stage("edge_median", t)
        return disp


@dataclass
class _Frame:
    """One inference's bookkeeping: its clock, timings (ms), step count, the stages' pixel
    counts and, for quantization, the graphs' recorded feeds."""

    t0: float
    record: dict[str, list] | None = None
    timings: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int | None] = field(default_factory=lambda: dict(
        selected_px=None, refined_px=None, counted_px=None))
    steps: int = 0
    lidar_offset: Offset | None = None  # the LiDAR map's misregistration, where looked for
    lidar_noise_px: float | None = None  # the LiDAR map's noise level, where measured
    after_steps: list[str] = field(default_factory=list)  # the stages after the steps, run

    def feed(self, part: str, feeds: dict) -> dict:
        if self.record is not None:
            self.record.setdefault(part, []).append({k: v.copy() for k, v in feeds.items()})
        return feeds

    def stage(self, name: str, started: float) -> None:
        """A stage after the steps took from `started` (perf_counter) to now."""
        self.timings[name] = (time.perf_counter() - started) * 1000
        self.after_steps.append(name)


def load_band_refinement(options: EngineOptions):
    """`edge.runtime.band_sgm` where `refine` is "band" (its numba kernels compiled or loaded
    from numba's cache on first use), else None; ConfigError naming the extra when numba is
    missing."""
    if options.refine != "band":
        return None
    try:
        band_sgm = importlib.import_module("edge_depth.runtime.band_sgm")
    except ImportError as exc:
        raise ConfigError("refine", "numba installed for \"band\", the default (pip install "
                          "numba), or refine = \"off\"", f"band without it ({exc})") from None
    return band_sgm


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
