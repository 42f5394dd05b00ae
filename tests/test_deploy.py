"""Export and the engine: ONNX Runtime against PyTorch, the shipped bundle, the deadline
logic, any camera size, the selections (quantization: tests/test_quantize.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge_depth.baselines import make_sgbm, sgbm_disparity
from edge_depth.errors import InvalidDataError
from edge_depth.metrics import disparity_metrics
from edge_depth.runtime import engine as engine_module
from edge_depth.runtime.engine import DEFAULT_BUNDLE, Engine, disparity_to_depth
from edge_depth.sim import RigConfig, make_sample
from tests.conftest import SMALL_BUNDLE as SMALL

torch = pytest.importorskip("torch")

CHECKPOINT = DEFAULT_BUNDLE.parent / "sparse_stereo.pt"


def scene_inputs(seed: int, size=SMALL, lidar="beams32"):
    sample = make_sample(seed, RigConfig(width=size[0], height=size[1]), lidar)
    sparse, valid = sample.sparse_disparity("left")
    return sample, sample.left, sample.right, (sparse * valid).astype(np.float32)


def test_onnx_runtime_matches_pytorch_at_four_iterations(small_bundle):
    from edge_depth.tools.export import load_checkpoint

    bundle, meta = small_bundle
    assert meta["export_check"]["max_abs_px"] < 0.01
    assert meta["size"] == list(SMALL) and meta["default_iters"] == 3
    assert meta["flops"]["iters_4"] == pytest.approx(
        meta["flops"]["encoder"] + 4 * meta["flops"]["step"] + meta["flops"]["upsample"])
    # an independent scene (training seed range), left images differ from the export check
    _, left, right, sparse = scene_inputs(123)
    net, _ = load_checkpoint(CHECKPOINT)
    t = [torch.from_numpy(a.astype(np.float32))[None, None] for a in
         (left, right, sparse, (sparse > 0).astype(np.float32))]
    with torch.no_grad():
        ref = net(*t, iters=4)[-1][0, 0].numpy()
    # the export's fidelity, on the runtime the export check uses (OpenVINO: test_backends)
    got = Engine(bundle, precision="fp32", threads=1, runtime="onnxruntime", edge_median="off",
                 refine="off").infer(
        left, right, sparse, iters=4)
    assert got.iterations == 4
    assert float(np.abs(got.disparity - ref).max()) < 0.01
    # the engine's iteration count is a runtime choice: 1 step differs from 4
    one = Engine(bundle, precision="fp32", threads=1).infer(left, right, sparse, iters=1)
    assert one.iterations == 1
    assert float(np.abs(one.disparity - ref).mean()) > 0.01


def test_new_bundles_feed_the_context_terms_and_mixed_graphs_are_refused(small_bundle,
                                                                           tmp_path):
    import onnx

    from edge_depth.errors import ConfigError

    bundle, _ = small_bundle
    names = lambda path, part: [v.name for v in getattr(onnx.load(str(path)).graph, part)]  # noqa: E731
    # the step reads the GRU's context terms, which the encoder computes once
    assert {"context_zr", "context_q"} <= set(names(bundle / "step.onnx", "input"))
    assert "context" not in names(bundle / "step.onnx", "input")
    assert {"context_zr", "context_q"} <= set(names(bundle / "encoder.onnx", "output"))
    # the shipped bundle too, since stage 16 (docs/experiments.md)
    assert {"context_zr", "context_q"} <= set(names(DEFAULT_BUNDLE / "step.onnx", "input"))
    # a step from one export with an encoder from the other (an older one
    # writes "context", not its terms): refused when the bundle loads
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for f in bundle.iterdir():
        (mixed / f.name).write_bytes(f.read_bytes())
    encoder = onnx.load(str(bundle / "encoder.onnx"))
    for out in [o for o in encoder.graph.output if o.name in ("context_zr", "context_q")]:
        encoder.graph.output.remove(out)
    onnx.save(encoder, str(mixed / "encoder.onnx"))
    with pytest.raises(ConfigError, match="step.onnx needs context_zr, context_q, which "
                                          ".*encoder.onnx"):
        Engine(mixed, precision="fp32", threads=1)


def test_shipped_int8_bundle_beats_sgbm_on_a_test_scene():
    meta = json.loads((DEFAULT_BUNDLE / "model.json").read_text())
    assert meta["size"] == [640, 400]
    assert meta["quantization"]["eval"]["epe_change_pct"] < 5.0
    sample, left, right, sparse = scene_inputs(1_000_003, (640, 400), "beams16")
    engine = Engine(precision="int8", threads=2)
    result = engine.infer(left, right, sparse, focal_px=450.0, baseline_m=0.075)
    assert result.iterations == meta["default_iters"] == 3
    assert {"encoder", "steps", "upsample", "engine"} <= set(result.timings_ms)
    net = disparity_metrics(result.disparity, sample.disp_left)
    sgbm = disparity_metrics(sgbm_disparity(left, right, make_sgbm()), sample.disp_left)
    assert net["epe"] < 0.6 * sgbm["epe"]
    ok = result.valid
    np.testing.assert_allclose(result.depth[ok] * result.disparity[ok], 450.0 * 0.075,
                               rtol=1e-5)


def test_engine_rejects_mismatched_shapes_and_ignores_nan_lidar():
    engine = Engine(precision="int8", threads=1)
    small = np.zeros((200, 320), np.uint8)
    with pytest.raises(InvalidDataError, match="left image's shape"):
        engine.infer(small, small, np.zeros((400, 640), np.float32))
    _, left, right, sparse = scene_inputs(1_000_004, (640, 400), "beams16")
    clean = engine.infer(left, right, sparse, iters=1).disparity
    dirty = sparse.copy()
    dirty[::7, ::5] = np.nan
    dirty[1::7, ::5] = -np.inf
    dirty[dirty == 0] = 0.0
    got = engine.infer(left, right, dirty, iters=1).disparity
    assert np.isfinite(got).all()
    kept = sparse.copy()
    kept[::7, ::5] = 0
    kept[1::7, ::5] = 0
    np.testing.assert_allclose(got, engine.infer(left, right, kept, iters=1).disparity)
    assert float(np.abs(got - clean).mean()) < 0.5


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class TimedSession:
    """Wraps an engine session; each run advances the fake clock by `ms`."""

    def __init__(self, session, clock: FakeClock, ms: float) -> None:
        self.session, self.clock, self.ms = session, clock, ms
        self.input_names, self.output_names = session.input_names, session.output_names

    def run(self, feeds):
        self.clock.now += self.ms / 1000
        return self.session.run(feeds)


@pytest.mark.parametrize("deadline, expected", [(None, 6), (1e6, 6), (0.0, 6), (1e-3, 1),
                                                (37.0, 2), (47.0, 3)])
def test_deadline_stops_before_the_step_that_would_miss_it(monkeypatch, deadline, expected):
    clock = FakeClock()
    monkeypatch.setattr(engine_module.time, "perf_counter", clock)
    engine = Engine(precision="fp32", threads=1)
    for part, ms in (("encoder", 10.0), ("step", 10.0), ("upsample", 5.0)):
        engine.sessions[part] = TimedSession(engine.sessions[part], clock, ms)
    engine._after_ms = {"upsample": 5.0}  # as learnt from earlier frames
    _, left, right, sparse = scene_inputs(1_000_005, (640, 400), "beams16")
    result = engine.infer(left, right, sparse, iters=6, deadline_ms=deadline)
    # encoder ends at 10 ms; after k steps 10 + 10 k; step k + 1 is run if
    # 10 + 10 k + 10 + 5 <= deadline (0: no deadline, as the options say)
    assert result.iterations == expected


def test_the_deadline_counts_from_started_and_the_engine_time_is_its_own(monkeypatch):
    """The daemon starts the deadline's clock when it begins preparing the frame: 20 ms of
    preparation leave a 47 ms deadline room for one step, not two; the engine's timing is
    still its own 10 + 10 + 5 ms, not the frame's."""
    clock = FakeClock()
    monkeypatch.setattr(engine_module.time, "perf_counter", clock)
    engine = Engine(precision="fp32", threads=1)
    for part, ms in (("encoder", 10.0), ("step", 10.0), ("upsample", 5.0)):
        engine.sessions[part] = TimedSession(engine.sessions[part], clock, ms)
    engine._after_ms = {"upsample": 5.0}
    _, left, right, sparse = scene_inputs(1_000_005, (640, 400), "beams16")
    clock.now = 0.020
    result = engine.infer(left, right, sparse, iters=6, deadline_ms=47.0, started=0.0)
    assert result.iterations == 1  # 20 + 10 + 10 + 10 + 5 > 47
    assert result.timings_ms["engine"] == pytest.approx(25.0)


class TimedBand:
    """The band refinement, taking `ms` of the fake clock."""

    def __init__(self, band, clock, ms):
        self.band, self.clock, self.ms = band, clock, ms

    def use_threads(self, threads):
        self.band.use_threads(threads)

    def refine(self, *args, **kwargs):
        self.clock.now += self.ms / 1000
        return self.band.refine(*args, **kwargs)


def engine_with_a_timed_band(monkeypatch):
    """An engine on a fake clock: encoder 10 ms, steps 10, upsampling 5 and the band 20 (as
    learnt from earlier frames); and a frame's inputs."""
    clock = FakeClock()
    monkeypatch.setattr(engine_module.time, "perf_counter", clock)
    engine = Engine(precision="fp32", threads=1)
    for part, ms in (("encoder", 10.0), ("step", 10.0), ("upsample", 5.0)):
        engine.sessions[part] = TimedSession(engine.sessions[part], clock, ms)
    engine.band = TimedBand(engine.band, clock, 20.0)
    engine._after_ms = {"upsample": 5.0, "band_refine": 20.0}
    return engine, scene_inputs(1_000_005, (640, 400), "beams16")[1:]


@pytest.mark.parametrize("deadline, steps, skipped", [(1e6, 6, False), (47.0, 1, False),
                                                      (30.0, 1, True), (42.0, 2, True)])
def test_the_deadline_cuts_the_steps_first_and_then_the_band(monkeypatch, deadline, steps,
                                                              skipped):
    """Encoder 10 ms, steps 10, upsampling 5, the band 20 (as learnt): at 47 ms one step
    leaves room for the band (10 + 10 + 5 + 20), at 30 ms not even one does; at 42 ms the
    band cannot end in time after the first step (20 + 5 + 20 > 42), so the steps take the
    time it would have had (a second ends at 30, + 5 ≤ 42; a third would not)."""
    engine, (left, right, sparse) = engine_with_a_timed_band(monkeypatch)
    result = engine.infer(left, right, sparse, iters=6, deadline_ms=deadline)
    assert result.iterations == steps
    assert ("band_skipped" in result.timings_ms) == skipped
    assert (result.refined_px is None) == skipped
    assert ("band_refine" in result.timings_ms) != skipped


def test_a_band_that_never_fits_is_skipped_and_measured_again_every_eleventh_frame(monkeypatch):
    """The band takes 20 ms where 30 - 25 = 5 are left: skipped, its estimate kept (not let
    fall towards a time it does not take), run once after RETRY_BAND_AFTER skips in a row,
    and its measured time is the estimate again. A deadline of 0 is none."""
    engine, (left, right, sparse) = engine_with_a_timed_band(monkeypatch)
    ran = ["band_skipped" not in engine.infer(left, right, sparse, iters=2,
                                              deadline_ms=30.0).timings_ms
           for _ in range(2 * engine_module.RETRY_BAND_AFTER + 2)]
    every = engine_module.RETRY_BAND_AFTER
    assert [i for i, r in enumerate(ran) if r] == [every - 1, 2 * every - 1]
    assert engine._after_ms["band_refine"] == pytest.approx(20.0)
    unbounded = engine.infer(left, right, sparse, iters=2, deadline_ms=0.0)
    assert unbounded.iterations == 2 and "band_skipped" not in unbounded.timings_ms


def test_the_closing_summary_counts_the_frames_whose_band_the_deadline_skipped():
    from edge_depth.frame_summary import selection_summary, summarise

    timings = [dict(engine=40.0, band_skipped=1.0), dict(engine=70.0, band_refine=25.0,
                                                          refined_pct=4.0),
               dict(engine=41.0, band_skipped=1.0), dict(propagate=5.0)]  # a carried frame
    assert "Band refinement: skipped in 2 of 3 frames the engine ran on" in \
        selection_summary(timings)
    assert "band_skipped" not in summarise(timings)  # a count, not a latency
    assert selection_summary(timings[1:2]).count("skipped") == 0


def test_depth_is_zero_and_invalid_below_the_minimum_disparity():
    d = np.array([[0.0, 0.2, 0.5, 10.0, np.nan]], np.float32)
    depth, valid = disparity_to_depth(d, 400.0, 0.1)
    assert valid.tolist() == [[False, False, True, True, False]]
    np.testing.assert_allclose(depth, [[0, 0, 80.0, 4.0, 0]])


def test_evaluate_runs_the_shipped_bundle_by_default(tmp_path, capsys):
    from edge_depth.cli import main as cli
    from edge_depth.tools import evaluate

    data = tmp_path / "scenes"
    assert cli(["synth", "--out", str(data), "--count", "1", "--seed", "1000002"]) == 0
    out = tmp_path / "eval.json"
    assert evaluate.main([str(data), "--methods", "net,sgbm", "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary["net"]["epe"] < summary["sgbm"]["epe"]
    small = tmp_path / "small"  # another camera size runs on the 640x400 bundle (fit)
    assert cli(["synth", "--out", str(small), "--count", "1", "--size", "320x200"]) == 0
    assert evaluate.main([str(small), "--methods", "net", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["net"]["density"] > 99


def test_confidence_bundle_returns_confidence_through_engine_and_mcap(tmp_path):
    """The confidence head (refine 10) re-initialised, exported, run: the engine's disparity
    and confidence match torch's, the bundle declares the matching it was made for, and the
    confidence reaches the MCAP output."""
    from mcap.reader import make_reader

    from edge_depth.mcap_log import McapLogger
    from edge_depth.model.config import ModelConfig
    from edge_depth.model.network import SparseStereoNet
    from edge_depth.tools.export import export

    torch.manual_seed(0)
    ckpt = torch.load(CHECKPOINT, weights_only=False)
    config = ModelConfig.from_dict({**ckpt["config"], "refine": 10})
    net = SparseStereoNet(config)
    net.load_state_dict(ckpt["model"])
    for p in net.refine.parameters():  # a head that says something else than the shipped
        torch.nn.init.normal_(p, std=0.05)
    path = tmp_path / "confidence.pt"
    torch.save(dict(model=net.state_dict(), config=config.to_dict(), step=1), path)
    meta = export(path, tmp_path / "bundle", SMALL, default_iters=2)
    assert meta["export_check"]["max_abs_px"] < 0.01
    assert meta["engine"] == {"edge_median": "9x9/2"}  # the median the bundle declares
    band = Engine(tmp_path / "bundle", precision="fp32", threads=1, runtime="onnxruntime")
    assert band.describe().endswith("band refinement, weighted median 9x9/2 (the bundle's)")
    # a bundle exported before the band declared the edge matching too: read, the matching's
    # keys ignored (no such stage now), its median taken
    older = dict(meta, engine={"edge_match": "auto", "edge_match_rows": 2,
                               "edge_median": "9x9/4"})
    assert Engine(tmp_path / "bundle", precision="fp32", threads=1, runtime="onnxruntime",
                  meta=older).describe().endswith("weighted median 9x9/4 (the bundle's)")
    _, left, right, sparse = scene_inputs(77)
    t = [torch.from_numpy(a.astype(np.float32))[None, None] for a in
         (left, right, sparse, (sparse > 0).astype(np.float32))]
    with torch.no_grad():
        outs, logit = net.eval()(*t, iters=2, with_confidence=True)
    engine = Engine(tmp_path / "bundle", precision="fp32", threads=1, runtime="onnxruntime",
                    refine="off", edge_median="off")
    assert engine.has_confidence and engine.describe().endswith("no refinement")
    result = engine.infer(left, right, sparse, iters=2)
    np.testing.assert_allclose(result.disparity, outs[-1][0, 0].numpy(), atol=0.01)
    np.testing.assert_allclose(result.confidence, torch.sigmoid(logit)[0, 0].numpy(),
                               atol=1e-4)
    assert 0 <= result.confidence.min() and result.confidence.max() <= 1
    with McapLogger(tmp_path / "out.mcap") as logger:
        logger.log_result(result)
    with open(tmp_path / "out.mcap", "rb") as f:
        topics = [c.topic for _, c, _ in make_reader(f).iter_messages()]
    assert "/depth/confidence" in topics


def test_a_checkpoint_of_a_removed_stage_is_refused_naming_it():
    from edge_depth.errors import ConfigError
    from edge_depth.model.config import ModelConfig

    for config in ({"refine": 3}, {"aux_offsets": True}, {"refine_scale": 2}):
        with pytest.raises(ConfigError, match="model-versions-archive"):
            ModelConfig.from_dict(config)
    old = ModelConfig.from_dict({"refine": 10, "aux_offsets": False, "refine_scale": 4})
    assert old.refine == 10   # an older checkpoint of a kept version still loads


@pytest.mark.parametrize("size", [(640, 480), (1242, 375), (1280, 800), (320, 200)])
def test_any_camera_size_runs_on_the_shipped_int8_bundle(size):
    engine = Engine(precision="int8", threads=2)
    sample, left, right, sparse = scene_inputs(1_000_001, size, "beams64")
    result = engine.infer(left, right, sparse, iters=4, focal_px=sample.rig.focal_px,
                          baseline_m=sample.rig.baseline_m)
    assert result.disparity.shape == (size[1], size[0])
    plan = engine.plan_for(size)  # "budget": the bundle's pixel count at the camera's aspect
    assert plan.scale == pytest.approx(min(1.0, (640 * 400 / (size[0] * size[1])) ** 0.5),
                                       rel=0.03)
    assert plan.bundle[0] * plan.bundle[1] <= 640 * 400
    # disparities come back in camera pixels: the rig's GT at that size
    m = disparity_metrics(result.disparity, sample.disp_left)
    assert m["epe"] < 3.0 and m["density"] > 99, m


def test_an_engine_scale_beyond_the_bundle_is_a_config_error():
    from edge_depth.errors import ConfigError

    engine = Engine(precision="int8", threads=1, scale=1.0)
    with pytest.raises(ConfigError, match="at most 0.500"):
        engine.plan_for((1280, 800))
    assert Engine(threads=1, scale="fit").plan_for((640, 480)).scale == pytest.approx(400 / 480)


def test_random_feeds_take_each_graphs_declared_shapes(small_bundle):
    from edge_depth.tools.quantize import random_feeds

    bundle = small_bundle[0]
    assert random_feeds(bundle / "upsample.onnx")["disparity"].shape == \
        (1, 1, SMALL[1] // 8, SMALL[0] // 8)
    assert random_feeds(bundle / "encoder.onnx")["left"].shape == (1, 1, SMALL[1], SMALL[0])


def test_engine_runs_the_bundles_lidar_selection_and_can_leave_it_out(small_bundle, tmp_path):
    import shutil

    from edge_depth.baselines import lidar_nearest
    from edge_depth.runtime.cells import cell_lidar, cell_mean
    from edge_depth.runtime.lidar_select import FEATURES, LidarSelect

    bundle = tmp_path / "bundle"
    shutil.copytree(small_bundle[0], bundle)
    f = len(FEATURES)
    always = LidarSelect(mean=np.zeros(f, np.float32), std=np.ones(f, np.float32),
                         w1=np.zeros((f, 2), np.float32), b1=np.zeros(2, np.float32),
                         w2=np.zeros(2, np.float32), b2=10.0)  # p = 0.99995: take the LiDAR
    meta = json.loads((bundle / "model.json").read_text())
    meta["lidar_select"] = always.to_meta()
    (bundle / "model.json").write_text(json.dumps(meta))
    _, left, right, sparse = scene_inputs(5)
    plain = Engine(bundle, precision="fp32", threads=1, runtime="onnxruntime", lidar_select=False,
                   refine="off", edge_median="off")  # the selection alone: nothing after it
    chosen = Engine(bundle, precision="fp32", threads=1, runtime="onnxruntime", edge_median="off",
                    refine="off")
    assert plain.select is None and chosen.select is not None
    before = plain.infer(left, right, sparse, iters=2)
    after = chosen.infer(left, right, sparse, iters=2)
    # per 2×2 cell: the cell's nearest LiDAR value wherever it differs from the cell's mean
    points = cell_lidar(sparse)
    nearest = lidar_nearest(points, points > 0)
    differ = np.abs(nearest - cell_mean(before.disparity)) > 0.5
    h, w = sparse.shape

    def full(cells):
        return np.repeat(np.repeat(cells, 2, axis=0), 2, axis=1)[:h, :w]

    nearest, differ = full(nearest), full(differ)
    assert differ.mean() > 0.05
    np.testing.assert_array_equal(after.disparity[differ], nearest[differ])
    np.testing.assert_allclose(after.disparity[~differ], before.disparity[~differ], atol=1e-4)
    assert after.timings_ms["select"] > 0 and "select" not in before.timings_ms
    assert after.selected_px == int(differ.sum()) and before.selected_px is None
    stereo_only = chosen.infer(left, right, np.zeros_like(sparse), iters=2)
    np.testing.assert_allclose(stereo_only.disparity,
                               plain.infer(left, right, np.zeros_like(sparse),
                                           iters=2).disparity, atol=1e-4)
    assert stereo_only.selected_px == 0
