"""Quantization (`tools/quantize.py`): what it records, what it keeps float and why, how it
times int8 against float (split from tests/test_deploy.py, which holds the export and the
engine)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge_depth.runtime.engine import Engine
from tests.test_deploy import scene_inputs

pytest.importorskip("torch")


@pytest.mark.slow
def test_quantize_records_its_choices_and_stays_close_to_fp32(small_bundle, tmp_path):
    import shutil

    from edge_depth.runtime.backends import cpu_description
    from edge_depth.tools.quantize import quantize_bundle

    bundle = tmp_path / "b"
    shutil.copytree(small_bundle[0], bundle)
    q = quantize_bundle(bundle, "synthetic:2", max_graph_px=10.0, iters=2, threads=1)
    meta = json.loads((bundle / "model.json").read_text())
    assert meta["quantization"] == q
    assert set(q["graphs"]) == {"encoder", "step", "upsample"}
    assert q["op_types"] == ["Conv"] and q["calibration_frames"] == 2
    # the host its speed choices were timed on (they differ with and without VNNI / AMX)
    assert q["cpu"] == cpu_description()
    for part, g in q["graphs"].items():
        name = meta["precisions"]["int8"][part]
        assert name.endswith(".int8.onnx") == g["int8"]
        assert (bundle / name).is_file()
    _, left, right, sparse = scene_inputs(7)
    fp32 = Engine(bundle, precision="fp32", threads=1).infer(left, right, sparse, iters=2).disparity
    int8 = Engine(bundle, precision="int8", threads=1).infer(left, right, sparse, iters=2).disparity
    assert float(np.abs(int8 - fp32).mean()) < 0.5


def test_quantize_keeps_the_confidence_head_float(small_bundle, tmp_path):
    import onnx

    from edge_depth.tools.quantize import ALWAYS_FLOAT, quantize_graph, random_feeds

    src, dst = small_bundle[0] / "upsample.onnx", tmp_path / "upsample.int8.onnx"
    quantize_graph(src, dst, [random_feeds(src)])
    graph = onnx.load(str(dst)).graph
    made_by = {out: n.op_type for n in graph.node for out in n.output}
    weights = {n.name: made_by.get(n.input[1]) for n in graph.node if n.op_type == "Conv"}
    confidence = {k: v for k, v in weights.items() if k.startswith(ALWAYS_FLOAT)}
    # the shipped head (version 10: two convolutions on the last hidden state) stays float
    assert len(confidence) == 2 and set(confidence.values()) == {None}  # float initialisers
    assert "DequantizeLinear" in {v for k, v in weights.items() if k not in confidence}


def pinned_agreement(engine_a, engine_b, frames, iters) -> dict[str, float]:
    """What int8 moves, pinned: 0.1 px and 0.005 of confidence per int8 graph of engine_a.
    The quantizer's decisions are under test, not this host's int8 kernels (without VNNI
    they move the confidence by more than the 0.03 the quantizer allows a graph)."""
    files = dict(engine_a.meta["precisions"][engine_a.precision])
    if engine_a.int8_encoder:
        files["encoder"] = engine_a.meta["int8_encoder"]["file"]
    int8 = sum(f.endswith(".int8.onnx") for f in files.values())
    return dict(px=0.1 * int8, confidence=0.005 * int8)


def test_quantize_checks_the_confidence_on_the_runtime_that_will_run_it(
        small_bundle, tmp_path, monkeypatch):
    """A confidence map that only OpenVINO's int8 ruins (as it did stage 12's: 0.99
    everywhere) sends the graphs back to float when the bundle is timed for OpenVINO, and
    not when it is timed for ONNX Runtime alone; both runtimes' numbers are recorded."""
    import shutil

    from edge_depth.tools import quantize

    monkeypatch.setattr(quantize, "paired_ms", lambda engines, frames, iters: (10.0, 5.0, 0.5))

    def openvino_ruins_the_confidence(engine_a, engine_b, frames, iters):
        out = pinned_agreement(engine_a, engine_b, frames, iters)
        files = engine_a.meta["precisions"][engine_a.precision].values()
        if engine_a.runtime == "openvino" and any(f.endswith(".int8.onnx") for f in files):
            out["confidence"] += 0.5
        return out

    monkeypatch.setattr(quantize, "agreement", openvino_ruins_the_confidence)
    for timing, int8 in (("openvino", False), ("onnxruntime", True)):
        bundle = tmp_path / timing
        shutil.copytree(small_bundle[0], bundle)
        q = quantize.quantize_bundle(bundle, "synthetic:1", max_graph_px=10.0, iters=1,
                                     threads=1, node_search=False, max_total_px=10.0,
                                     timing_runtime=timing)
        assert {g["int8"] for g in q["graphs"].values()} == {int8}
        assert not any(g.get("float_for_the_total") for g in q["graphs"].values())
        assert set(q["vs_fp32"]) == {"onnxruntime", timing}
        for graph in q["graphs"].values():  # each graph checked alone on both runtimes
            assert set(graph["alone"]) == {"onnxruntime", timing}
            assert (graph["alone"][timing]["confidence"] > 0.5) == (timing == "openvino")
        # the int8 that ships, against fp32: a real, small change where the graphs stayed
        # int8; none where they all went back to float
        confidence = q["vs_fp32"]["onnxruntime"]["confidence"]
        assert 0.0 < confidence < 0.03 if int8 else confidence == 0.0


def test_quantize_keeps_a_graph_float_when_it_moves_the_disparity(small_bundle, tmp_path,
                                                                   monkeypatch):
    import shutil

    from edge_depth.tools import quantize

    # every graph "faster" in int8, so each one's convolutions are tried in float one by one:
    # a graph whose every convolution then stays float (version 10's upsampling: one besides
    # its float head) is no int8 graph, though it moves the disparity by nothing
    monkeypatch.setattr(quantize, "paired_ms", lambda engines, frames, iters: (10.0, 5.0, 0.5))
    bundle = tmp_path / "b"
    shutil.copytree(small_bundle[0], bundle)
    q = quantize.quantize_bundle(bundle, "synthetic:1", max_graph_px=0.0, iters=1, threads=1)
    assert q["graphs"]["upsample"]["float_nodes"] == ["/mask.0/Conv"]
    meta = json.loads((bundle / "model.json").read_text())
    assert not any(g["int8"] for g in q["graphs"].values())
    assert meta["precisions"]["int8"] == meta["precisions"]["fp32"]
    assert not list(bundle.glob("*.int8.onnx"))


def test_quantize_times_int8_against_float_call_by_call():
    """A host whose speed swings every few calls (as in the minute after a training run
    ended, when the int8 step was judged slower than float) slows both calls of a pair
    alike: the ratio is the engines' own, 0.8 (blocks of 5 calls per engine on this host
    would time float in the fast phases and int8 in the slow ones)."""
    from types import SimpleNamespace

    from edge_depth.tools import quantize

    calls = []

    class Clocked:
        def __init__(self, ms: float) -> None:
            self.ms = ms

        def infer(self, *frame, iters):
            calls.append(self)
            slow = 3.0 if (len(calls) // 5) % 2 else 1.0  # 5 calls fast, 5 slow, ...
            return SimpleNamespace(timings_ms={"engine": self.ms * slow})

    fp32, int8 = Clocked(10.0), Clocked(8.0)
    ms_fp32, ms_int8, ratio = quantize.paired_ms([fp32, int8], [()] * 4, iters=1)
    assert len(calls) == 2 + 2 * 3 * 4  # one untimed call each, then 3 rounds of 4 pairs
    # the pairs straddling a swing are outliers; the median ratio is the engines' own
    assert ratio == pytest.approx(0.8)
    assert ms_int8 < ms_fp32


def test_quantize_sends_graphs_back_to_float_while_together_they_move_too_much(
        small_bundle, tmp_path, monkeypatch):
    """Every graph passes alone (the speed test forced: a busy machine can pass it by
    chance); with a total cap of 0 px they all go back to float, the one that moved the
    disparity most alone first; with a loose cap they stay int8."""
    import shutil

    from edge_depth.tools import quantize

    timed = []
    monkeypatch.setattr(quantize, "paired_ms", lambda engines, frames, iters:
                        timed.append([e.runtime for e in engines]) or (10.0, 5.0, 0.5))
    monkeypatch.setattr(quantize, "agreement", pinned_agreement)
    bundle = tmp_path / "b"
    shutil.copytree(small_bundle[0], bundle)
    q = quantize.quantize_bundle(bundle, "synthetic:1", max_graph_px=10.0, iters=1, threads=1,
                                 node_search=False, max_total_px=0.0,
                                 timing_runtime="onnxruntime")
    # the speed test ran on the runtime asked for, once per graph
    assert timed == [["onnxruntime", "onnxruntime"]] * 3
    assert q["timing_runtime"] == "onnxruntime"
    assert not any(g["int8"] for g in q["graphs"].values())
    assert all(g["float_for_the_total"] for g in q["graphs"].values())
    assert q["mean_abs_px_vs_fp32"] == 0.0
    # the float encoder gets its int8 alternative, judged alone by the graph limit (0.1 px
    # pinned, under 10), for the CPUs where the float one would run in f32
    meta = json.loads((bundle / "model.json").read_text())
    assert [p.name for p in bundle.glob("*.int8.onnx")] == ["encoder.int8.onnx"]
    assert meta["int8_encoder"]["file"] == "encoder.int8.onnx"
    assert meta["int8_encoder"]["mean_abs_px_vs_fp32"] == pytest.approx(0.1)
    assert meta["int8_encoder"]["float_nodes"] == [
        n for n in quantize.conv_nodes(bundle / "encoder.onnx")][:1]
    shutil.rmtree(bundle)
    shutil.copytree(small_bundle[0], bundle)
    q = quantize.quantize_bundle(bundle, "synthetic:1", max_graph_px=10.0, iters=1, threads=1,
                                 node_search=False, max_total_px=10.0)
    assert all(g["int8"] for g in q["graphs"].values())
    assert 0.0 < q["mean_abs_px_vs_fp32"] <= 10.0
    # the encoder is int8 itself: no alternative
    assert "int8_encoder" not in json.loads((bundle / "model.json").read_text())


def test_the_printout_says_why_a_graph_stayed_float():
    from edge_depth.tools.quantize import graph_line

    base = dict(int8=False, mean_abs_px_alone=0.23, engine_ms_fp32=87.8,
                engine_ms_with_this_int8=72.5, int8_to_fp32_ratio=0.89)
    # a graph every convolution of which moved the disparity: no int8 graph was tried
    every = graph_line("encoder", dict(base, float_nodes=["/a/Conv", "/b/Conv"]))
    assert every.startswith("encoder: float (alone: moves disparity 0.2300 px")
    assert "kept float: /a/Conv, /b/Conv (every convolution: no int8 graph)" in every
    some = graph_line("step", dict(base, int8=True, float_nodes=["/a/Conv"],
                                   mean_abs_px_with_float_nodes=0.05))
    assert "step: int8" in some and "kept float: /a/Conv -> moves 0.0500 px" in some
    assert "kept float" not in graph_line("upsample", dict(base, float_nodes=[]))


def test_the_command_line_says_which_graphs_went_int8_and_names_the_int8_encoder(
        small_bundle, tmp_path, monkeypatch, capsys):
    """The encoder too slow in int8 here (the speed test pinned): it stays float, and the
    printout names the int8 encoder written beside it for the CPUs where the float one would
    run in f32."""
    import shutil

    from edge_depth.tools import quantize

    monkeypatch.setattr(quantize, "paired_ms", lambda engines, frames, iters: (
        (10.0, 12.0, 1.2) if engines[1].meta["precisions"]["int8"]["encoder"].endswith(
            ".int8.onnx") else (10.0, 5.0, 0.5)))
    monkeypatch.setattr(quantize, "agreement", pinned_agreement)
    bundle = tmp_path / "b"
    shutil.copytree(small_bundle[0], bundle)
    assert quantize.main([str(bundle), "--calib", "synthetic:1", "--iters", "1", "--threads",
                          "1", "--no-node-search", "--max-total-px", "10", "--max-graph-px", "10",
                          "--timing-runtime", "onnxruntime"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("encoder: float (alone: moves disparity 0.1000 px")
    assert "step: int8" in out and "upsample: int8" in out
    # the int8 precision with it: step, upsampling and encoder int8, 0.1 px each (pinned)
    assert "int8 encoder beside the float one (encoder.int8.onnx, kept float: " in out
    assert "moves the disparity 0.3000 px" in out
