"""A camera at its own resolution: graphs that take any size, `scale = "native"` (and "budget",
the bundle's pixel count at the camera's aspect) in the engine, the robot file and the command
line, and OpenVINO compiling such a graph for the size it gets."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from edge_depth.config import load_robot_config
from edge_depth.errors import ConfigError
from edge_depth.metrics import disparity_metrics
from edge_depth.runtime.backends import openvino_available
from edge_depth.runtime.engine import DEFAULT_BUNDLE, Engine
from edge_depth.runtime.options import EngineOptions, add_engine_arguments, options_from_args
from edge_depth.sim import RigConfig, make_sample


def scene(size, seed=1_000_003, lidar="beams64"):
    sample = make_sample(seed, RigConfig(width=size[0], height=size[1]), lidar)
    sparse, valid = sample.sparse_disparity("left")
    return sample, (sparse * valid).astype(np.float32)


def test_the_exported_graphs_give_torchs_disparity_at_a_size_they_were_not_traced_at(
        small_bundle):
    torch = pytest.importorskip("torch")
    from edge_depth.tools.export import load_checkpoint

    bundle, meta = small_bundle
    assert meta["any_size"] is True
    other = meta["export_check"]["other_size"]
    assert other["size"] != meta["size"] and other["max_abs_px"] < 0.01
    # a third size, of odd width at 1/8 and taller than wide, against PyTorch
    size = (136, 200)
    sample, sparse = scene(size, lidar="beams32")
    net, _ = load_checkpoint(DEFAULT_BUNDLE.parent / "sparse_stereo.pt")
    t = [torch.from_numpy(a.astype(np.float32))[None, None] for a in
         (sample.left, sample.right, sparse, (sparse > 0).astype(np.float32))]
    with torch.no_grad():
        ref = net(*t, iters=4)[-1][0, 0].numpy()
    engine = Engine(bundle, precision="fp32", threads=1, runtime="onnxruntime", edge_median="off",
                    refine="off", scale="native")
    got = engine.infer(sample.left, sample.right, sparse, iters=4).disparity
    assert got.shape == (200, 136)
    assert float(np.abs(got - ref).max()) < 0.01


def test_native_runs_the_shipped_bundle_at_the_cameras_size_padded_to_the_stride():
    size = (1242, 375)
    sample, sparse = scene(size)
    native = Engine(scale="native", threads=2)
    assert native.any_size and "own size" in native.describe()
    plan = native.plan_for(size)
    assert plan.scale == 1.0 and plan.bundle == (1248, 376)
    result = native.infer(sample.left, sample.right, sparse, iters=4)
    assert result.disparity.shape == (375, 1242)
    assert native._inputs["left"].shape == (1, 1, 376, 1248)   # no resize: padded only
    fit = Engine(threads=2, scale="fit").infer(sample.left, sample.right, sparse, iters=4)
    m_native = disparity_metrics(result.disparity, sample.disp_left)
    m_fit = disparity_metrics(fit.disparity, sample.disp_left)
    assert m_native["density"] > 99 and m_native["epe"] < 2.0, m_native
    # twice the pixels the scaled-down run saw: not worse than it
    assert m_native["epe"] <= m_fit["epe"] * 1.05, (m_native, m_fit)
    # a small camera off the stride is padded to it, then cropped (calibrations under 64 px a
    # side are refused, so the engine's own 64 px minimum is not reached from a camera)
    small = Engine(scale="native", threads=1)
    sample, sparse = scene((100, 70), lidar="beams16")
    assert small.plan_for((100, 70)).bundle == (104, 72)
    assert small.infer(sample.left, sample.right, sparse, iters=2).disparity.shape == (70, 100)


@pytest.mark.parametrize("camera, padded", [((1242, 375), (912, 280)), ((1280, 800), (640, 400)),
                                            ((640, 480), (576, 432)), ((320, 200), (320, 200))])
def test_budget_keeps_the_bundles_pixel_count_at_the_cameras_aspect(camera, padded):
    engine = Engine(scale="budget", threads=1)
    plan = engine.plan_for(camera)
    w, h = plan.bundle
    assert (w, h) == padded and w % 8 == 0 and h % 8 == 0
    assert w * h <= 640 * 400 and plan.scale <= 1.0
    sw, sh = plan.scaled  # the scaled image fits its padded input
    assert sw <= w and sh <= h and abs(sw / camera[0] - sh / camera[1]) < 0.01
    if camera == (1242, 375):  # a wide camera keeps more than "fit" gives it (640x193)
        assert sw * sh > 1.8 * 640 * 193
        sample, sparse = scene(camera, lidar="beams32")
        disparity = engine.infer(sample.left, sample.right, sparse, iters=2).disparity
        assert disparity.shape == (375, 1242) and engine._inputs["left"].shape == (1, 1, h, w)


def test_a_bundle_of_one_size_refuses_native_in_one_line(small_bundle, tmp_path):
    bundle = tmp_path / "old"
    shutil.copytree(small_bundle[0], bundle)
    meta = json.loads((bundle / "model.json").read_text())
    del meta["any_size"]
    (bundle / "model.json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match="export it again"):
        Engine(bundle, scale="native", precision="fp32", threads=1)
    # "budget" (the default) is "fit" there: its pixel budget is its shape
    engine = Engine(bundle, precision="fp32", threads=1)
    assert engine.scale == "fit" and engine.plan_for((1280, 800)).bundle == tuple(meta["size"])


@pytest.mark.skipif(not openvino_available(), reason="OpenVINO not installed")
def test_openvino_compiles_an_any_size_graph_for_each_size_it_gets():
    for size in ((488, 136), (320, 240)):  # a wide one and a 4:3 one, neither the bundle's
        sample, sparse = scene(size, lidar="beams32")
        got = {runtime: Engine(scale="native", runtime=runtime, precision="fp32", threads=1,
                               refine="off", edge_median="off", bf16=False).infer(
                                   sample.left, sample.right, sparse, iters=4).disparity
               for runtime in ("onnxruntime", "openvino")}
        assert got["openvino"].shape == (size[1], size[0])
        assert float(np.abs(got["openvino"] - got["onnxruntime"]).mean()) < 0.01
    # one session, two sizes in turn: compiled again for the second, and back
    engine = Engine(scale="native", runtime="openvino", threads=1, refine="off", edge_median="off")
    for size in ((320, 240), (256, 192), (320, 240)):
        sample, sparse = scene(size, lidar="beams16")
        assert engine.infer(sample.left, sample.right, sparse, iters=1).disparity.shape == \
            (size[1], size[0])


def test_scale_is_fit_native_or_a_factor_in_the_robot_file_and_on_the_command_line(tmp_path):
    import argparse

    assert EngineOptions().scale == "budget"
    path = tmp_path / "robot.toml"
    for text, expected in (('"native"', "native"), ('"fit"', "fit"), ('"budget"', "budget"),
                           ("0.5", 0.5)):
        path.write_text(f"[engine]\nscale = {text}\n")
        assert load_robot_config(path).engine.scale == expected
    for text in ('"wide"', "1.5", "true"):
        path.write_text(f"[engine]\nscale = {text}\n")
        with pytest.raises(ConfigError, match="scale"):
            load_robot_config(path)
    parser = argparse.ArgumentParser()
    add_engine_arguments(parser)
    assert options_from_args(parser.parse_args(["--scale", "native"])).scale == "native"
    assert options_from_args(parser.parse_args(["--scale", "0.25"])).scale == 0.25
    assert options_from_args(parser.parse_args([])).scale == "budget"
    with pytest.raises(SystemExit):
        parser.parse_args(["--scale", "huge"])
    # the spelling older callers use: 0 = fit
    assert EngineOptions.with_overrides(scale=0).scale == "fit"
