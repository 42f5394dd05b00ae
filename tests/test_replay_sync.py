"""Replay and the pipeline on real files: pairing that waits for the LiDAR whatever the
order in the file, clocks that disagree, runs that produce nothing, recordings that must not
be destroyed, and camera sizes other than the bundle's."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from mcap.reader import make_reader

from edge_depth.capture.sim import SimSource
from edge_depth.cli import main
from edge_depth.daemon import Pipeline
from edge_depth.mcap_log import RAW_TOPICS, TOPICS, McapLogger
from edge_depth.runner import run
from edge_depth.types import LidarScan, StereoFrame
from tests.test_pipeline_mcap import SEED, topic_counts


class EventList:
    """A recording's events in a chosen order (what a replay source yields)."""

    def __init__(self, events) -> None:
        self.events = list(events)

    def __iter__(self):
        return iter(self.events)

    def close(self) -> None:
        pass


def sim_events(count: int, lag_ms: float, distinct: int | None = None):
    """Per moment: (scan, frame, gt) from the rig, the scan stamped lag_ms before its frame
    (negative: after it, as a spinning LiDAR's revolution ends after the frame taken in its
    middle); `distinct`: that many scenes rendered, cycled through."""
    events = list(SimSource(count, SEED, lidar_lag_ms=lag_ms, start_ns=10_000_000_000,
                            distinct=distinct))
    return [tuple(events[i:i + 3]) for i in range(0, len(events), 3)]


@pytest.mark.parametrize("lag_ms", [5.0, -30.0])
def test_pairing_does_not_depend_on_whether_scans_are_stored_before_or_after_frames(
        engine, lag_ms):
    moments = sim_events(3, lag_ms)
    stereo, lidar = SimSource(1).calibration
    sparse_by_order = {}
    for order in ("scans first", "scans after"):
        if order == "scans first":
            events = [e for scan, frame, gt in moments for e in (scan, frame, gt)]
        else:  # kitti2mcap's order: each scan after its frame's images
            events = [e for scan, frame, gt in moments for e in (frame, gt, scan)]
        pipeline = Pipeline(engine, stereo, lidar)
        outputs: list = []
        stats = run(EventList(events), pipeline, on_output=lambda f, o, out=outputs: out.append(o))
        assert stats.frames == 3
        counters = pipeline.sync.counters()
        assert counters["frames_with_lidar"] == 3, (order, counters)
        assert all((o.sparse > 0).sum() > 1000 for o in outputs)
        sparse_by_order[order] = [o.sparse for o in outputs]
    for a, b in zip(*sparse_by_order.values(), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_a_lidar_on_another_clock_warns_with_the_measured_gap(engine, caplog):
    moments = sim_events(60, 5.0, distinct=4)  # the stamps matter here, not the scenes
    shifted = []
    for scan, frame, gt in moments:  # the LiDAR's stamps 3 s behind the camera's
        shifted += [LidarScan(scan.stamp_ns - 3_000_000_000, scan.points), frame, gt]
    pipeline = Pipeline(engine, *SimSource(1).calibration)
    pipeline.engine = type("NoEngine", (), {
        "size": engine.size, "infer": lambda self, left, *a, **k: engine_result(left, k)})()
    with caplog.at_level("WARNING"):
        run(EventList(shifted), pipeline)
    assert pipeline.sync.counters()["frames_with_lidar"] == 0
    warning = [r.getMessage() for r in caplog.records if "no frame has paired" in r.getMessage()]
    assert len(warning) == 1
    # the LiDAR is 3 s behind; frames wait 200 ms of stream time for it, so the nearest scan
    # they see is 2.7-3.0 s older than they are
    gap = float(re.search(r"stamp ([-+]\d+) ms", warning[0]).group(1))
    assert -3005 <= gap <= -2700


def engine_result(left, kwargs):
    from edge_depth.types import DepthResult

    zeros = np.zeros(left.shape, np.float32)
    return DepthResult(kwargs.get("stamp_ns", 0), zeros, zeros, zeros > 0, 1)


def test_replay_whose_first_frame_has_another_size_stops_naming_both(tmp_path, capsys):
    moments = sim_events(2, 5.0)
    path = tmp_path / "small_frames.mcap"
    with McapLogger(path, topics=RAW_TOPICS) as logger:
        logger.set_calibration(*SimSource(1).calibration)   # says 640x400
        for scan, frame, _ in moments:                      # frames are 320x200
            logger.log_scan(scan)
            logger.log_frame(StereoFrame(frame.stamp_ns, frame.seq, frame.left[::2, ::2],
                                         frame.right[::2, ::2], rectified=True))
    assert main(["replay", str(path), "--out", str(tmp_path / "out.mcap")]) == 1
    captured = capsys.readouterr()
    assert "frames with LiDAR: 0 of 0" in captured.out
    assert "error: the camera's frames are 320x200 but the calibration is for 640x400" \
        in captured.err
    assert not re.search(r"^frame \d+:", captured.out, re.M)  # stopped at the first frame
    assert "wrote nothing: no frame was processed" in captured.out


def test_replay_summary_counts_frames_with_lidar(recording, tmp_path, capsys):
    assert main(["replay", str(recording), "--out", str(tmp_path / "o.mcap"), "--iters",
                 "1"]) == 0
    assert "frames with LiDAR: 3 of 3" in capsys.readouterr().out
    with open(tmp_path / "o.mcap", "rb") as f:
        diags = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages()
                 if c.topic == TOPICS["diagnostics"]]
    assert diags[-1]["lidar_sync"]["frames_with_lidar"] == 3
    assert diags[-1]["sources"]["messages"] > 0 and diags[-1]["sources"]["frames"] == 3


def test_a_restarted_rotating_logger_never_overwrites_its_predecessor(tmp_path):
    path = tmp_path / "depth.mcap"
    frame = next(e for e in SimSource(1, SEED) if isinstance(e, StereoFrame))
    for _ in range(2):  # two daemon runs with the same log.out
        with McapLogger(path, rotate_bytes=1 << 30) as logger:
            logger.log_frame(frame)
    first, second = tmp_path / "depth_0001.mcap", tmp_path / "depth_0002.mcap"
    assert logger.files == [second]
    assert topic_counts(first)[TOPICS["left"]] == 1 and topic_counts(second)[TOPICS["left"]] == 1


def test_replay_refuses_to_write_over_its_input(recording, tmp_path, capsys):
    copy = tmp_path / "rec.mcap"
    copy.write_bytes(recording.read_bytes())
    assert main(["replay", str(copy), "--out", str(copy)]) == 1
    assert "--out" in capsys.readouterr().err
    assert copy.read_bytes() == recording.read_bytes()


def test_a_1242x375_recording_replays_on_the_shipped_bundle(tmp_path, capsys):
    rec = tmp_path / "kitti_sized.mcap"
    assert main(["synth", "--mcap", str(rec), "--frames", "2", "--seed", str(SEED),
                 "--size", "1242x375"]) == 0
    out = tmp_path / "out.mcap"
    assert main(["replay", str(rec), "--out", str(out), "--iters", "2"]) == 0
    text = capsys.readouterr().out
    assert "2 frames" in text and "frames with LiDAR: 2 of 2" in text
    with open(out, "rb") as f:
        images = [m for _, c, m in make_reader(f).iter_messages()
                  if c.topic == TOPICS["disparity"]]
    assert len(images) == 2


@pytest.mark.parametrize("pipelined, bound_mb", [(False, 16), (True, 32)])
def test_two_hundred_dropped_frames_leave_nothing_behind(engine, pipelined, bound_mb):
    """A live source far faster than inference: frames drop, and neither they nor their
    ground truth (1 MB each) outlive them (RSS grew 192 MB over 182 drops).
    Measured as tracemalloc's peak (numpy's arrays are traced), not RSS, which the C
    allocator's reuse of freed memory makes noisy."""
    import time
    import tracemalloc

    from edge_depth.runner import Runner
    from edge_depth.types import GroundTruth

    (scan, frame, gt), = sim_events(1, 5.0)

    class Fast:
        def __iter__(self):
            for i in range(400):
                stamp = frame.stamp_ns + i * 1_000_000
                yield StereoFrame(stamp, i, frame.left.copy(), frame.right.copy(),
                                  rectified=True)
                yield GroundTruth(stamp, gt.disparity.copy())

        def close(self) -> None:
            pass

    def slow_infer(self, left, *args, **kwargs):
        time.sleep(0.004)
        return engine_result(left, kwargs)

    pipeline = Pipeline(engine, *SimSource(1).calibration)
    pipeline.engine = type("Slow", (), {"size": engine.size, "infer": slow_infer})()
    source = Fast()
    runner = Runner(source, pipeline, threaded=True, pipelined=pipelined)
    tracemalloc.start()
    try:
        stats = runner.run()
        peak_mb = tracemalloc.get_traced_memory()[1] / 2**20
    finally:
        tracemalloc.stop()
    assert stats.drops >= 200 and stats.frames + stats.drops == 400
    assert len(runner.gts) <= 2 and len(runner.frames) == 0
    # the most ever held at once: two queued frames and their truth, the frame in hand and
    # its result (~3 MB; pipelined, up to five in the stages and their hand-offs, ~5 MB
    # each) — not the truth of every frame dropped since the last one processed
    assert peak_mb < bound_mb


def test_duplicated_stamps_and_a_missing_partner_are_counted_not_silent(tmp_path, caplog):
    from edge_depth.capture.replay import McapSource
    from edge_depth.foxglove_msgs import image_message

    (scan, frame, _), = sim_events(1, 5.0)
    path = tmp_path / "odd.mcap"
    with McapLogger(path, topics=RAW_TOPICS) as logger:
        logger.set_calibration(*SimSource(1).calibration)
        t = frame.stamp_ns
        for stamp in (t, t + 100_000_000, t + 100_000_000, t + 200_000_000):  # one repeated
            logger.log_frame(StereoFrame(stamp, 0, frame.left, frame.right, rectified=True))
        logger._log("left", image_message(frame.left, t + 300_000_000), t + 300_000_000)
    source = McapSource(path)
    frames = [e for e in source if isinstance(e, StereoFrame)]
    assert len(frames) == 4
    errors = source.stats.errors
    assert errors["frame stamp not after the previous frame's (zero, duplicated or going "
                  "back)"] == 1
    assert errors["unpaired image"] == 1  # the lone left image the file ended on
    assert caplog.text.count("is not after the previous one") == 1


def test_the_lidar_line_counts_over_the_frames_that_were_paired_not_those_processed():
    """Pipelined, frames are paired with scans and then some are dropped before the engine:
    the closing line must not say "293 of 135"."""
    from types import SimpleNamespace

    from edge_depth.frame_summary import lidar_summary

    sync = SimpleNamespace(counters=lambda: dict(frames_with_lidar=293, frames_without_lidar=7,
                                                 frames_gone_before_their_scans=0),
                           median_gap_ms=lambda: 40.0)
    pipeline = SimpleNamespace(sync=sync, lidar=object(), ahead_frames=0,
                               stats=SimpleNamespace(frames=135, scans=300, deskewed=[]))
    line = lidar_summary(pipeline)
    assert line.startswith("frames with LiDAR: 293 of 300 paired (165 of them dropped before "
                           "the engine)")
    assert "+40 ms" in line and "camera's rate" not in line
    # at the camera's rate the frames gone on before their scans are counted apart, and in
    # the frames dropped before the engine
    pipeline.ahead_frames = 93
    line = lidar_summary(pipeline)
    assert line.startswith("frames with LiDAR: 293 of 300 paired, and 93 more gone on at the "
                           "camera's rate before their scans (258 of the 393 dropped before "
                           "the engine)")
    pipeline.stats.frames = 393  # none dropped
    assert lidar_summary(pipeline).startswith(
        "frames with LiDAR: 293 of 300, and 93 more gone on at the camera's rate before their "
        "scans (not paired)")


@pytest.mark.parametrize("scans_after_frames", [False, True])
def test_offline_readers_pair_each_frame_with_its_own_scan_in_either_storage_order(
        tmp_path, scans_after_frames, capsys):
    """adapt's frames (and every reader of synced_frames) pair as replay does: a scan stored
    after its frame (kitti2mcap's order) still reaches that frame, and the LiDAR reaches the
    training sample."""
    from edge_depth.calibration.model import LidarExtrinsics
    from edge_depth.mcap_log import RAW_TOPICS, McapLogger
    from edge_depth.sim import RigConfig, make_sample
    from edge_depth.sim.lidar import default_T_cam_lidar
    from edge_depth.tools.adapt_frames import load_frames
    from edge_depth.types import LidarScan

    rig = RigConfig(width=160, height=100, focal_px=112.5, max_disparity_px=16.0)
    samples = [make_sample(1_000_000 + i, rig, "beams16") for i in range(5)]
    path = tmp_path / "rec.mcap"
    with McapLogger(path, topics=RAW_TOPICS) as logger:
        logger.set_calibration(samples[0].calibration(), LidarExtrinsics(default_T_cam_lidar()))
        for i, s in enumerate(samples):
            stamp = 1_000_000_000 + i * 100_000_000
            scan = LidarScan(stamp - 5_000_000, s.scan.points, s.scan.intensity)
            if not scans_after_frames:
                logger.log_scan(scan)
            logger.log_frame(s.frame(stamp, i))
            logger.log_gt(stamp, s.disp_left)
            if scans_after_frames:
                logger.log_scan(scan)
    frames = load_frames(path)
    assert "frames with LiDAR: 5 of 5" in capsys.readouterr().out
    assert len(frames) == 5
    for frame, s in zip(frames, samples, strict=True):
        assert frame.gt is not None and (frame.sparse("left") > 0).sum() > 50
        arrays = frame.arrays()   # what the fine-tune's loss reads
        assert arrays["valid"].sum() == (frame.sparse("left") > 0).sum()
        # its own scan: the LiDAR disparity agrees with this frame's ground truth
        valid = arrays["valid"] & (s.disp_left > 0)
        assert np.median(np.abs(arrays["sparse"][valid] - s.disp_left[valid])) < 1.0


def test_native_replays_a_1242x375_recording_at_its_size_without_torch(tmp_path):
    """`--scale native` on the robot-side install: torch cannot be imported, and the engine
    runs the recording's 1242x375 frames padded to 1248x376, not scaled."""
    import subprocess
    import sys

    rec, out = tmp_path / "kitti_sized.mcap", tmp_path / "out.mcap"
    assert main(["synth", "--mcap", str(rec), "--frames", "2", "--seed", str(SEED),
                 "--size", "1242x375"]) == 0
    code = ("import sys\n"
            "class NoTorch:\n"  # `import torch` raises ImportError, as on the robot
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] == 'torch':\n"
            "            raise ImportError('no torch on the robot')\n"
            "sys.meta_path.insert(0, NoTorch())\n"
            "from edge_depth.cli import main\n"
            f"sys.exit(main(['replay', {str(rec)!r}, '--out', {str(out)!r}, '--iters', '2', "
            "'--scale', 'native']))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    text = done.stdout + done.stderr
    assert "at the camera's own size" in text and "frames with LiDAR: 2 of 2" in text
    from tests.test_ros2_profile import foxglove_images

    images = foxglove_images(out, TOPICS["disparity"])
    assert [image.shape for image in images] == [(375, 1242)] * 2


def test_the_watchs_sample_runs_after_its_frame_is_handed_to_the_logging_thread(engine):
    """Pipelined, a frame's latency must not carry the calibration watch's sample (20–60 ms
    of the engine's thread): the sample waits until its own frame is being finished, which
    it could not if it ran before the hand-off (it would wait out its timeout)."""
    import threading

    from edge_depth.runner import Runner

    moments = sim_events(3, 5.0)
    pipeline = Pipeline(engine, *SimSource(1).calibration, watch_every=1)
    finishing: dict[int, threading.Event] = {}
    order = []
    finish = pipeline.finish

    def finish_noting(p, result):
        finishing.setdefault(p.frame.stamp_ns, threading.Event()).set()
        return finish(p, result)

    def sample_after_its_frame(p):
        seen = finishing.setdefault(p.frame.stamp_ns, threading.Event()).wait(timeout=20)
        order.append((p.frame.stamp_ns, seen))

    pipeline.finish = finish_noting
    pipeline.watch_sample = sample_after_its_frame
    class Source:
        def __iter__(self):
            return (e for scan, frame, gt in moments for e in (scan, frame, gt))

        def close(self) -> None:
            pass

    stats = Runner(Source(), pipeline, threaded=True, pipelined=True).run()
    assert stats.frames >= 1 and len(order) == stats.frames  # live: some may drop
    assert all(seen for _, seen in order), order
