"""tools/train.py checkpoints and resumes; tools/evaluate.py scores methods on scene folders."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest
import torch

from edge_depth.cli import main as cli
from edge_depth.tools import evaluate, train


def test_train_writes_checkpoints_and_resumes_where_it_stopped(tmp_path):
    out = tmp_path / "run"
    args = ["--out", str(out), "--batch", "1", "--crop", "64x64", "--iters", "2",
            "--workers", "0", "--ckpt-every", "1"]
    assert train.main(args + ["--steps", "2"]) == 0
    ckpt = torch.load(out / "last.pt", weights_only=False)
    assert ckpt["step"] == 2 and ckpt["config"]["gru_iters"] == 2
    assert train.main(args + ["--steps", "3", "--resume"]) == 0
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert [int(r["step"]) for r in rows] == [1, 2, 3]
    assert all(float(r["loss"]) > 0 for r in rows)
    assert (out / "loss.png").stat().st_size > 0


def test_a_run_resumed_without_steps_goes_on_to_the_end_it_was_started_for(tmp_path):
    """A run started for 3 steps that stopped at step 2 (its last.pt says so) continues to
    step 3 on a plain --resume; --steps is not the parser's default there. Where it trained
    is not restored: a run from a GPU machine resumes on this CPU one."""
    out = tmp_path / "run"
    args = ["--out", str(out), "--batch", "1", "--crop", "64x64", "--iters", "2",
            "--workers", "0", "--ckpt-every", "1"]
    assert train.main(args + ["--steps", "2"]) == 0
    ckpt = torch.load(out / "last.pt", weights_only=False)
    ckpt["args"]["steps"] = 3  # as if the run had been started for 3 and stopped after 2
    ckpt["args"]["device"] = "cuda:0"  # ... on a GPU
    torch.save(ckpt, out / "last.pt")
    # --workers: not restored either (a new machine's cores), and no loader processes forked
    # inside the test's process
    assert train.main(["--out", str(out), "--resume", "--workers", "0"]) == 0
    assert torch.load(out / "last.pt", weights_only=False)["step"] == 3


def test_resume_continues_the_run_as_it_was_started(tmp_path, capsys):
    """--resume with only --out and --steps takes --init, --refine and the rest from the run's
    checkpoint (the model would not match it otherwise); a flag given again with another value
    is one clear error, while --steps may change."""
    first = tmp_path / "a"
    small = ["--batch", "1", "--crop", "64x64", "--iters", "2", "--workers", "0"]
    assert train.main(["--out", str(first), "--steps", "1"] + small) == 0
    run = tmp_path / "b"
    assert train.main(["--out", str(run), "--steps", "1", "--refine", "10", "--lr", "1e-4",
                       "--ckpt-every", "1", "--init", str(first / "final.pt")] + small) == 0
    capsys.readouterr()
    assert train.main(["--out", str(run), "--steps", "2", "--resume", "--workers", "0"]) == 0
    out = capsys.readouterr().out
    assert "--resume: as the run was started" in out and "--refine 10" in out
    assert f"--init {first / 'final.pt'}" in out and "--crop 64x64" in out
    assert "resumed from" in out and "at step 1" in out
    ckpt = torch.load(run / "last.pt", weights_only=False)
    assert ckpt["step"] == 2 and ckpt["config"]["refine"] == 10
    assert ckpt["args"]["lr"] == 1e-4 and ckpt["args"]["steps"] == 2
    with pytest.raises(SystemExit):
        train.main(["--out", str(run), "--steps", "3", "--resume", "--lr", "2e-4"])
    err = capsys.readouterr().err
    assert "these differ from it: --lr 0.0002 (the run: 0.0001)" in err


def test_self_supervised_training_runs_from_an_initial_checkpoint(tmp_path):
    first = tmp_path / "a"
    assert train.main(["--out", str(first), "--steps", "1", "--batch", "1", "--crop", "64x64",
                       "--iters", "2", "--workers", "0"]) == 0
    second = tmp_path / "b"
    assert train.main(["--out", str(second), "--steps", "1", "--batch", "1", "--crop",
                       "64x64", "--iters", "2", "--workers", "0", "--mode", "self",
                       "--init", str(first / "final.pt")]) == 0
    row = next(csv.DictReader(open(second / "metrics.csv")))
    assert float(row["appearance"]) > 0 and float(row["sparse"]) > 0


def test_evaluate_reports_every_method_and_writes_json(tmp_path, capsys):
    assert cli(["synth", "--out", str(tmp_path / "scenes"), "--count", "2", "--size", "96x64",
                "--lidar", "beams64"]) == 0
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "1", "--batch", "1", "--crop", "64x64",
                       "--iters", "2", "--workers", "0"]) == 0
    out = tmp_path / "eval.json"
    assert evaluate.main([str(tmp_path / "scenes"), "--model", str(run / "final.pt"),
                          "--iters", "1,2", "--json", str(out), "--plot",
                          str(tmp_path / "curve.png")]) == 0
    summary = json.loads(out.read_text())
    assert set(summary) == {"net@1", "net@2", "sgbm", "lidar-nearest", "lidar-linear"}
    for metrics in summary.values():
        assert metrics["samples"] == 2 and metrics["epe"] >= 0 and 0 <= metrics["bad3"] <= 100
        assert metrics["ms"] > 0 and "rmse_mm" in metrics
    assert summary["lidar-nearest"]["density"] == 100.0
    assert "| sgbm |" in capsys.readouterr().out
    assert (tmp_path / "curve.png").stat().st_size > 0


@pytest.mark.slow
def test_bench_reports_medians_engine_table_and_ratios(tmp_path, monkeypatch):
    from collections import Counter

    from edge_depth.tools import bench

    calls = Counter()  # (precision, iters) of every engine call: what each column timed
    infer = bench.Engine.infer

    def spy(engine, *args, iters=None, **kwargs):
        calls[engine.precision, iters] += 1
        return infer(engine, *args, iters=iters, **kwargs)

    monkeypatch.setattr(bench.Engine, "infer", spy)
    out, md = tmp_path / "bench.json", tmp_path / "bench.md"
    before = cv2.getNumThreads()
    try:
        # --iters without the bundle's own count (3): the ratio's column is timed anyway
        assert bench.main(["--scenes", "1", "--repeat", "2", "--iters", "1", "--rss-frames",
                           "1", "--runs", "2", "--runtime", "onnxruntime", "--threads", "1",
                           "--json", str(out), "--markdown", str(md)]) == 0
    finally:
        cv2.setNumThreads(before)
    result = json.loads(out.read_text())
    stages = result["stages"]
    for stage in ("rectify", "project_filter", "sgbm", "log", "frame", "encoder", "step",
                  "upsample", "engine_int8_3", "band_refine", "edge_median"):
        assert 0 < stages[stage]["median_ms"] <= stages[stage]["p95_ms"], stage
    assert stages["sgbm"]["runs"] == 2
    assert result["sgbm_ms"] == stages["sgbm"]["median_ms"]
    assert set(result["engine_ms"]) == {"fp32", "int8"}
    assert set(result["engine_ms"]["int8"]) == {"1", "3"}
    # each column timed its own precision and iterations: (1 untimed + 1 scene) x 2 blocks x
    # 2 runs (no "1 iteration is faster" here: a timing assertion fails on a busy machine);
    # the two daemon pipelines' warm-ups (the frame's, the calibration watch's) add two int8
    # calls at 1 iteration per run, the paired ratio one int8 call at 3 per scene, block and run
    assert calls["fp32", 1] == calls["fp32", 3] == 8 and calls["int8", 3] == 12, calls
    assert calls["int8", 1] == 12, calls
    from edge_depth.calibration_watch import EVERY

    watch = result["calibration_watch"]  # a sample on each scene of each block, paired
    assert watch["every"] == EVERY and watch["per_frame_ms"] == pytest.approx(
        watch["sample_ms"] / EVERY) and 0 < watch["share_of_frame_pct"] < 100
    assert "calibration watch:" in md.read_text()
    outside = result["outside_engine"]  # the frame's own timings: (1 untimed + 1) x 2 blocks
    assert outside["frames"] == 4 and 0 < outside["ms"] and 0 < outside["share_pct"] < 100
    assert "the daemon's frame outside the engine" in md.read_text()
    assert result["ratios"]["int8_vs_sgbm"] == pytest.approx(
        result["engine_ms"]["int8"]["3"] / result["sgbm_ms"])
    assert 50 < result["replay_peak_rss_mb"] < 4000
    assert "int8 engine / SGBM" in md.read_text()
    assert result["ratios"]["band_refine_vs_sgbm"] == pytest.approx(
        stages["band_refine"]["median_ms"] / result["sgbm_ms"])
    assert "edge_match_vs_sgbm" not in result["ratios"]
    assert "the engine's band_refine stage / SGBM" in md.read_text()
    assert result["engine"].endswith("band refinement, weighted median 9x9/2 (the bundle's)")
    assert "match_starts" not in result  # the matching's early start: not run with the band
    # two runs: the median of the per-run ratios, and how busy the machine was in each
    assert len(result["runs"]) == 2 and result["runtime"] == "onnxruntime"
    assert result["threads"] == result["opencv_threads"] == 1   # SGBM with the engine's count
    assert result["ratio_median"] == pytest.approx(
        float(np.median([r["int8_vs_sgbm"] for r in result["runs"]])))
    share = result["runs"][0]["others_cpu_share"]
    assert share is None or 0.0 <= share <= 1.0
    assert result["runs"][0]["busy"] == (share is not None and share > bench.BUSY_SHARE)
    assert "2 runs: int8 engine / SGBM per run" in md.read_text()
    assert "the engine's band_refine stage / SGBM per run" in md.read_text()
    assert all(r["band_refine_vs_sgbm"] > 0 for r in result["runs"])
    lo, hi = result["ratios"]["int8_vs_sgbm_paired_p10_p90"]
    assert 0 < lo <= result["ratios"]["int8_vs_sgbm_paired"] <= hi
    assert all(r["int8_vs_sgbm_paired"] > 0 for r in result["runs"])
    assert "paired, frame by frame" in md.read_text() and "paired per run" in md.read_text()


def test_paired_ratios_time_engine_and_sgbm_back_to_back_in_alternating_order(monkeypatch):
    from edge_depth.tools import bench

    clock, order = [0.0], []

    def engine(left, right, sparse):   # 3 units a call, SGBM 1: every ratio is 3
        order.append("engine")
        clock[0] += 3.0

    def sgbm(left, right):
        order.append("sgbm")
        clock[0] += 1.0

    monkeypatch.setattr(bench.time, "perf_counter", lambda: clock[0])
    frames = [(None, None, None)] * 3
    assert bench.paired_ratios(engine, sgbm, frames, 2) == [3.0] * 6
    assert order[:6] == ["engine", "sgbm", "sgbm", "engine", "engine", "sgbm"]
    assert order.count("engine") == order.count("sgbm") == 6


def test_ship_checkpoint_keeps_weights_and_appends_the_stage(tmp_path):
    from edge_depth.tools import ship_checkpoint

    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "1", "--batch", "1", "--crop", "64x64",
                       "--iters", "2", "--workers", "0", "--refine", "--lr", "1e-4"]) == 0
    prev = tmp_path / "prev.pt"
    torch.save(dict(model={}, config={}, training=dict(stages=[dict(steps=5, note="a")])),
               prev)
    out = tmp_path / "shipped.pt"
    assert ship_checkpoint.main([str(run / "final.pt"), "--note", "b", "--previous",
                                 str(prev), "--out", str(out)]) == 0
    shipped = torch.load(out, weights_only=False)
    assert "optimizer" not in shipped and shipped["config"]["refine"] == 10
    stages = shipped["training"]["stages"]
    assert [s["note"] for s in stages] == ["a", "b"]
    assert stages[1]["steps"] == 1 and stages[1]["lr"] == 1e-4 and stages[1]["refine"] == 10
    assert shipped["training"]["total_steps"] == 6
    final = torch.load(run / "final.pt", weights_only=False)
    for key, value in final["model"].items():
        assert torch.equal(shipped["model"][key], value)


def test_evaluate_reports_the_confidence_calibration_of_a_refining_model(tmp_path):
    assert cli(["synth", "--out", str(tmp_path / "scenes"), "--count", "1", "--size", "96x64",
                "--lidar", "beams64"]) == 0
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "1", "--batch", "1", "--crop", "64x64",
                       "--iters", "2", "--workers", "0", "--refine", "--lr", "0"]) == 0
    out = tmp_path / "eval.json"
    assert evaluate.main([str(tmp_path / "scenes"), "--model", str(run / "final.pt"),
                          "--methods", "net,sgbm+lidar", "--json", str(out)]) == 0
    net = json.loads(out.read_text())["net"]
    # the head as initialised (lr 0: not moved): a higher threshold keeps fewer pixels
    assert 100.0 >= net["kept@0.5"] >= net["kept@0.7"] >= net["kept@0.9"] >= 0.0
    assert all(0 <= net[f"bad1@{t}"] <= 100 for t in ("0.5", "0.7", "0.9")
               if net[f"kept@{t}"] > 0)


def test_a_resumed_run_appends_in_the_columns_its_log_already_has(tmp_path):
    """A metrics.csv written before a column was added keeps its layout when the run is
    resumed: the appended row's loss lands under "loss", not one column off."""
    out = tmp_path / "run"
    args = ["--out", str(out), "--batch", "1", "--crop", "64x64", "--iters", "2",
            "--workers", "0", "--ckpt-every", "1"]
    assert train.main(args + ["--steps", "1"]) == 0
    with open(out / "metrics.csv", newline="") as f:
        rows = list(csv.reader(f))
    old = [c for c in rows[0] if c != "val_bad3"]  # a header before "val_bad3" existed
    with open(out / "metrics.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(old)
        writer.writerow([dict(zip(rows[0], rows[1], strict=True))[c] for c in old])
    assert train.main(args + ["--steps", "2", "--resume"]) == 0
    with open(out / "metrics.csv", newline="") as f:
        resumed = list(csv.DictReader(f))
    assert list(resumed[0]) == old
    assert [int(r["step"]) for r in resumed] == [1, 2]
    assert None not in resumed[1]  # no value beyond the header's columns
    assert float(resumed[1]["loss"]) > 0 and float(resumed[1]["seconds"]) >= 0


def test_freeze_trunk_trains_only_a_fresh_head_at_its_own_rate(tmp_path, capsys):
    """--refine 10 --init <a checkpoint without the head> --freeze-trunk: the head starts
    fresh (said so) in its own optimizer group at --fresh-lr-mult, on --resume too, and every
    trunk tensor (batch-norm statistics included) stays as the checkpoint had it."""
    common = ["--batch", "1", "--crop", "64x64", "--iters", "2", "--workers", "0"]
    plain = tmp_path / "plain"
    assert train.main(["--out", str(plain), "--steps", "1"] + common) == 0
    head = tmp_path / "head"
    args = ["--out", str(head), "--refine", "10", "--init", str(plain / "final.pt"),
            "--freeze-trunk", "--fresh-lr-mult", "10", "--ckpt-every", "1"] + common
    capsys.readouterr()
    assert train.main(args + ["--steps", "2"]) == 0
    assert "4 tensors of the refinement stages start fresh (refine.head.0.bias" in \
        capsys.readouterr().out
    assert train.main(args + ["--steps", "3", "--resume"]) == 0
    before = torch.load(plain / "final.pt", weights_only=False)["model"]
    after = torch.load(head / "final.pt", weights_only=False)
    assert after["config"]["refine"] == 10
    assert any("running_mean" in k for k in before)
    assert all(torch.equal(before[k], after["model"][k]) for k in before)
    groups = after["optimizer"]["param_groups"]
    fresh = [k for k in after["model"] if k.startswith("refine.")]
    assert [len(g["params"]) for g in groups] == [len(fresh)] == [4]
    assert [g["max_lr"] for g in groups] == pytest.approx([2e-3])


def test_freeze_trunk_and_fresh_lr_need_a_checkpoint_and_a_refinement_stage(tmp_path, capsys):
    for extra in (["--freeze-trunk"], ["--freeze-trunk", "--init", str(tmp_path / "x.pt")],
                  ["--fresh-lr-mult", "10"]):
        with pytest.raises(SystemExit):
            train.main(["--out", str(tmp_path / "r"), "--steps", "1"] + extra)
    err = capsys.readouterr().err
    assert "--freeze-trunk needs --init" in err and "give --refine 10" in err
    assert "--fresh-lr-mult needs --init" in err


def test_device_flag_is_checked_and_checkpoints_load_on_the_cpu(tmp_path, capsys):
    """--device names where the network trains; one the machine lacks is one clear line, and
    the checkpoints hold CPU tensors whatever trained them, so a run moves between machines."""
    small = ["--batch", "1", "--crop", "64x64", "--iters", "2", "--workers", "0"]
    for device, says in (("mps", "only cpu and cuda are supported"),
                         ("nonsense:x", "not a device")):
        with pytest.raises(SystemExit):
            train.main(["--out", str(tmp_path / "r"), "--device", device] + small)
        assert says in capsys.readouterr().err
    if not torch.cuda.is_available():
        with pytest.raises(SystemExit):
            train.main(["--out", str(tmp_path / "r"), "--device", "cuda"] + small)
        assert "--device cuda: this torch sees no CUDA GPU" in capsys.readouterr().err
    run = tmp_path / "run"
    assert train.main(["--out", str(run), "--steps", "1", "--ckpt-every", "1",
                       "--device", "cpu"] + small) == 0
    ckpt = torch.load(run / "last.pt", weights_only=False)
    assert ckpt["args"]["device"] == "cpu"
    tensors = list(ckpt["model"].values()) + [
        v for state in ckpt["optimizer"]["state"].values() for v in state.values()
        if isinstance(v, torch.Tensor)]
    assert tensors and all(t.device.type == "cpu" for t in tensors)
    # where it trains may change on --resume (the rest of the run may not)
    assert train.main(["--out", str(run), "--steps", "2", "--resume", "--device", "auto",
                       "--workers", "0"]) == 0
    assert torch.load(run / "last.pt", weights_only=False)["step"] == 2


def test_a_teacher_adds_the_distance_to_its_own_final_disparity(tmp_path, capsys):
    """--teacher: the loss gains --teacher-weight × the sequence loss towards the frozen
    teacher's final disparity after as many iterations; a network that is its own teacher
    (both in eval mode) is at distance 0, and a run with one logs the term."""
    from argparse import Namespace

    from edge_depth.model.config import ModelConfig
    from edge_depth.model.network import SparseStereoNet

    torch.manual_seed(0)
    net = SparseStereoNet(ModelConfig(widths=(8, 8, 8), feature_dim=8, context_dim=8,
                                      hidden_dim=8, motion_dim=8, head_dim=8)).eval()
    rng = np.random.default_rng(0)
    images = [torch.from_numpy(rng.uniform(0, 255, (2, 1, 32, 128)).astype(np.float32))
              for _ in range(2)]
    valid = torch.from_numpy((rng.uniform(size=(2, 1, 32, 128)) < 0.1).astype(np.float32))
    gt = torch.full((2, 1, 32, 128), 5.0)
    batch = dict(left=images[0], right=images[1], sparse=gt * valid, valid=valid, gt=gt)
    args = Namespace(mode="supervised", iters=2, edge_weight=0.0, teacher_weight=0.5)
    plain, terms, _ = train.batch_loss(net, batch, args)
    assert "teacher" not in terms
    _, terms, _ = train.batch_loss(net, batch, args, teacher=net)
    assert terms["teacher"] == pytest.approx(0.0, abs=1e-6)
    other = SparseStereoNet(net.config).eval()
    with torch.no_grad():
        taught = other(batch["left"], batch["right"], batch["sparse"], valid, 2)[-1]
        preds = net(batch["left"], batch["right"], batch["sparse"], valid, 2)
    expected = sum(0.9 ** (1 - i) * (p - taught).abs().mean() for i, p in enumerate(preds))
    loss, terms, _ = train.batch_loss(net, batch, args, teacher=other)
    assert terms["teacher"] == pytest.approx(float(expected), rel=1e-4)
    assert float(loss.detach()) == pytest.approx(
        float(plain.detach()) + 0.5 * float(expected), rel=1e-4)

    first = tmp_path / "a"
    small = ["--batch", "1", "--crop", "64x64", "--iters", "2", "--workers", "0"]
    assert train.main(["--out", str(first), "--steps", "1"] + small) == 0
    run = tmp_path / "b"
    assert train.main(["--out", str(run), "--steps", "1", "--teacher", str(first / "final.pt"),
                       "--init", str(first / "final.pt")] + small) == 0
    row = next(csv.DictReader(open(run / "metrics.csv")))
    assert float(row["teacher"]) >= 0 and float(row["loss"]) > float(row["teacher"]) * 0.99
    with pytest.raises(SystemExit):
        train.main(["--out", str(run), "--mode", "self", "--teacher", str(first / "final.pt")])
    assert "--teacher distils in supervised mode" in capsys.readouterr().err
