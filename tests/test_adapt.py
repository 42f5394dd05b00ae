"""`edge-depth adapt`: the no-GT check measures, the time split, the decision and the
adapt → bundle → replay round trip on a tiny recording."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge_depth import selfcheck
from edge_depth.cli import main

pytest.importorskip("torch")

from edge_depth.tools.adapt import FineTune  # noqa: E402
from edge_depth.tools.adapt_check import decide, is_better  # noqa: E402
from edge_depth.tools.adapt_frames import Frame, split_by_time  # noqa: E402


def _textured_pair(disparity: float, shape=(64, 96), seed=0):
    rng = np.random.default_rng(seed)
    left = (rng.random(shape) * 255).astype(np.float32)
    left = np.clip(left, 0, 255)
    xs = np.arange(shape[1], dtype=np.float32)
    # right(x) = left(x + d): the left pixel x is seen at x - d in the right image
    right = np.stack([np.interp(xs + disparity, xs, row) for row in left])
    return left.astype(np.uint8), right.astype(np.uint8)


def test_photometric_error_is_lowest_at_the_true_disparity():
    left, right = _textured_pair(5.0)
    errors = {}
    for d in (3.0, 5.0, 7.0):
        disp = np.full(left.shape, d, np.float32)
        seen = selfcheck.visible(disp, disp)
        errors[d] = float(selfcheck.photometric_error(left, right, disp)[seen].mean())
    assert errors[5.0] < 0.02 < min(errors[3.0], errors[7.0])


def test_visible_and_lr_consistency_see_occlusion_and_disagreement():
    d = np.full((4, 20), 3.0, np.float32)
    seen = selfcheck.visible(d, d)
    assert not seen[:, :3].any() and seen[:, 3:].all()  # x - d < 0 is outside the right image
    nearer = d.copy()
    nearer[:, 5:8] = 6.0  # the right view sees something nearer where x = 8..10 lands
    assert not selfcheck.visible(d, nearer)[:, 8:11].any()
    assert selfcheck.lr_inconsistent_share(d, d) == 0.0
    assert selfcheck.lr_inconsistent_share(d, nearer) == pytest.approx(3 / 17)


def test_held_out_points_are_disjoint_and_scored_apart():
    valid = np.zeros((10, 10), bool)
    valid[::2] = True
    fed, held = selfcheck.split_points(valid, seed=1)
    assert not (fed & held).any() and ((fed | held) == valid).all() and fed.any() and held.any()
    lidar = np.where(valid, 4.0, 0.0).astype(np.float32)
    assert selfcheck.held_out_error(np.full((10, 10), 4.5, np.float32), lidar, held) == 0.5


def _frames(name, n):
    image = np.zeros((8, 8), np.uint8)
    empty = (np.zeros(0, np.int32), np.zeros(0, np.float32))
    return [Frame(name, 100 * i, image, image, empty, empty) for i in range(n)]


def test_check_frames_are_each_recordings_last_fifth():
    adapt_frames, check_frames = split_by_time([_frames("a", 10), _frames("b", 3)], 0.2)
    assert [(f.recording, f.stamp_ns) for f in check_frames] == [("a", 800), ("a", 900),
                                                                 ("b", 200)]
    assert len(adapt_frames) == 10
    with pytest.raises(ValueError, match="at least 2"):
        split_by_time([_frames("c", 1)])


def test_the_new_bundle_must_also_beat_the_old_weights_at_the_cameras_size():
    before = dict(photometric=0.10, held_out_px=0.45)
    unadapted = dict(photometric=0.08, held_out_px=0.26)  # the resolution's gain alone
    after = dict(photometric=0.09, held_out_px=0.25)      # better than before, not unadapted
    better, why = decide(dict(before=before, unadapted=unadapted, after=after))
    assert not better and 'scale = "native"' in why and "from adaptation 0.260 -> 0.250" in why
    after = dict(photometric=0.07, held_out_px=0.24)
    assert decide(dict(before=before, unadapted=unadapted, after=after))[0]
    assert decide(dict(before=before, after=after))[0]  # no unadapted run: as before


def test_better_needs_photometric_and_held_out_lidar_both_lower():
    old = dict(photometric=0.10, held_out_px=1.0)
    assert is_better(old, dict(photometric=0.09, held_out_px=0.9))[0]
    assert not is_better(old, dict(photometric=0.09, held_out_px=1.1))[0]
    assert not is_better(old, dict(photometric=0.11, held_out_px=0.9))[0]
    no_lidar = dict(photometric=0.10, held_out_px=float("nan"))
    better, why = is_better(no_lidar, dict(photometric=0.09, held_out_px=float("nan")))
    assert not better and "--photometric-only" in why       # NaN never passes
    assert is_better(no_lidar, dict(photometric=0.09, held_out_px=float("nan")),
                     photometric_only=True)[0]
    assert not is_better(no_lidar, dict(photometric=0.11), photometric_only=True)[0]
    assert not is_better(old, dict(photometric=float("nan"), held_out_px=0.5))[0]
    assert not is_better(old, dict(photometric=0.09, held_out_px=float("nan")))[0]


def test_fine_tune_needs_a_bound_and_stops_at_the_first():
    with pytest.raises(ValueError, match="--steps or --minutes"):
        FineTune()
    plan = FineTune(steps=100, minutes=1.0)
    assert plan.progress(50, 0.0) == 0.5 and plan.progress(10, 60.0) == 1.0


@pytest.mark.slow
def test_adapt_round_trip_writes_a_bundle_that_replays(tmp_path, capsys, monkeypatch):
    from edge_depth.tools import quantize

    # int8 pinned twice as fast as float: the quantizer's timing is tests/test_quantize.py's,
    # and the bundle written here does not depend on this host's speed or int8 kernels
    monkeypatch.setattr(quantize, "paired_ms", lambda engines, frames, iters: (10.0, 5.0, 0.5))
    rec = tmp_path / "rec.mcap"
    assert main(["synth", "--mcap", str(rec), "--frames", "5", "--seed", "7",
                 "--size", "192x128"]) == 0
    out = tmp_path / "robot"
    rc = main(["adapt", str(rec), "--out", str(out), "--steps", "1", "--batch", "1",
               "--no-node-search", "--force"])
    assert rc == 0
    meta = json.loads((out / "model.json").read_text())
    assert meta["size"] == [192, 128] and "int8" in meta["precisions"]
    # where the encoder stays float its int8 alternative is calibrated on the robot's frames
    encoder = meta.get("int8_encoder")
    assert encoder is None or encoder["calibration"] == meta["quantization"]["calibration"]
    assert (out / "checkpoint.pt").is_file() and (out / "report.png").is_file()
    import torch

    shipped = torch.load(out / "checkpoint.pt", weights_only=False)
    assert "optimizer" not in shipped and shipped["training"]["adapted"]["steps"] == 1
    report = json.loads((out / "report.json").read_text())
    assert report["frames"] == {"adapt": 4, "check": 1} and report["written"]
    assert report["training"]["steps"] == 1
    assert set(report["check"]) == {"before", "unadapted", "after"}  # 192x128 != 640x400
    # the shipped bundle takes any size: its weights ran at the camera's, nothing re-exported
    assert not (tmp_path / "robot.adapt" / "start_bundle").exists()
    assert "from the camera's resolution" in report["why"] and "from adaptation" in report["why"]
    for side in ("before", "after"):
        assert 0 < report["check"][side]["photometric"] < 1
        assert report["check"][side]["epe"] >= 0  # the recording carries GT
    replayed = tmp_path / "replayed.mcap"
    assert main(["replay", str(rec), "--out", str(replayed), "--bundle", str(out)]) == 0
    assert "5 frames" in capsys.readouterr().out
    # adapting the adapted bundle again starts from the weights it carries
    rc = main(["adapt", str(rec), "--out", str(tmp_path / "again"), "--from", str(out),
               "--steps", "1", "--batch", "1", "--no-node-search"])
    again = json.loads((tmp_path / "again.adapt" / "report.json").read_text())
    assert again["training"]["init"] == str(out / "checkpoint.pt")
    assert rc == (0 if again["better"] else 3)
    assert (tmp_path / "again").exists() == again["better"]


@pytest.mark.slow
def test_street_recording_lidar_lands_on_its_ground_truth(tmp_path):
    from edge_depth.tools.adapt_frames import load_frames

    rec = tmp_path / "street.mcap"
    assert main(["synth", "--world", "street", "--mcap", str(rec), "--frames", "1"]) == 0
    (frame,) = load_frames(rec)
    assert frame.left.shape == (375, 1242) and frame.gt is not None
    sparse = frame.sparse("left")
    points = sparse > 0
    assert points.sum() > 20_000  # 64 rows, every 2nd column, over the lower two thirds
    assert not points[:120].any()
    error = np.abs(sparse[points] - frame.gt[points])
    assert np.median(error) < 0.15 and np.mean(error < 0.5) > 0.95


def test_a_device_the_machine_lacks_is_one_line_before_any_work(tmp_path, capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    rec = tmp_path / "rec.mcap"
    rec.write_bytes(b"not read: the device is checked first")
    rc = main(["adapt", str(rec), "--out", str(tmp_path / "robot"), "--steps", "1",
               "--device", "cuda"])
    assert rc == 2
    out = capsys.readouterr().out.strip().splitlines()
    assert out == [f"edge-depth adapt: --device cuda: this torch sees no CUDA GPU "
                   f"(torch {torch.__version__}; use --device cpu)"]
    assert not (tmp_path / "robot").exists() and not (tmp_path / "robot.adapt").exists()


@pytest.mark.slow
def test_fine_tuning_bound_by_minutes_stops_and_resumes(tmp_path, monkeypatch):
    """The time bound is checked after each step: on a clock that advances 0.6 s per
    reading (two readings a step) a 3-second bound stops after the third step, at 3.6 s,
    however fast or slow the machine is."""
    from edge_depth.sim import RigConfig, make_sample
    from edge_depth.tools import adapt
    from edge_depth.tools.adapt import DEFAULT_CHECKPOINT, finetune
    from edge_depth.tools.adapt_frames import _compact

    class Clock:
        now = 1000.0

        def time(self) -> float:
            self.now += 0.6
            return self.now

    monkeypatch.setattr(adapt, "time", Clock())

    frames = []
    for seed in (11, 12):
        sample = make_sample(seed, RigConfig(width=192, height=128), "beams16")
        sparse, valid = sample.sparse_disparity("left")
        frames.append(Frame("rig", seed, sample.left, sample.right, _compact(sparse * valid),
                            _compact(np.zeros_like(sparse))))
    plan = FineTune(minutes=0.05, batch=1, ckpt_every=1)
    path, summary = finetune(DEFAULT_CHECKPOINT, frames, tmp_path, plan)
    assert path.is_file() and summary["steps"] == 3 and summary["minutes"] == 0.06
    again, resumed = finetune(DEFAULT_CHECKPOINT, frames, tmp_path, FineTune(
        steps=summary["steps"] + 1, batch=1), resume=True)
    assert resumed["steps"] == summary["steps"] + 1
    import torch

    assert resumed["device"] == ("cuda" if torch.cuda.is_available() else "cpu")
    saved = torch.load(tmp_path / "last.pt", weights_only=False)
    assert all(t.device.type == "cpu" for t in saved["model"].values())
