"""The MCAP layer, replay, the pipeline and the commands built on them, on real files."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from edge_depth.calibration.io import dumps_calibration
from edge_depth.capture.replay import McapSource, ReplayError, TopicMap
from edge_depth.capture.sim import SimSource
from edge_depth.cli import main
from edge_depth.daemon import Pipeline
from edge_depth.mcap_log import RAW_TOPICS, TOPICS, McapLogger
from edge_depth.runner import StopFlag, run
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim_recording import write_sim_recording
from edge_depth.types import Calibration, GroundTruth, LidarScan, StereoFrame

ROOT = Path(__file__).resolve().parents[1]
SEED = 1_000_000


def topic_counts(path: Path) -> dict[str, int]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None, f"{path} has no summary"
    channels = summary.channels
    return {channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}


def test_recording_round_trips_frames_scans_gt_and_calibration(recording):
    events = list(McapSource(recording))
    frames = [e for e in events if isinstance(e, StereoFrame)]
    scans = [e for e in events if isinstance(e, LidarScan)]
    gts = [e for e in events if isinstance(e, GroundTruth)]
    calibs = [e for e in events if isinstance(e, Calibration)]
    assert (len(frames), len(scans), len(gts)) == (3, 3, 3)
    for i, frame in enumerate(frames):
        sample = make_sample(SEED + i, stamp_ns=frame.stamp_ns - 5_000_000)
        np.testing.assert_array_equal(frame.left, sample.left)
        np.testing.assert_array_equal(frame.right, sample.right)
        assert frame.rectified and frame.stamp_ns == 1_000_000_000 + i * 100_000_000
        np.testing.assert_array_equal(scans[i].points, sample.scan.points)
        np.testing.assert_array_equal(gts[i].disparity, sample.disp_left)
    toml_calib = [c for c in calibs if c.toml]
    info_calib = [c for c in calibs if c.focal_px]
    assert len(toml_calib) == 1 and "T_cam_lidar" in toml_calib[0].toml
    assert info_calib[0].focal_px == pytest.approx(450.0)
    assert info_calib[0].baseline_m == pytest.approx(0.075)
    assert topic_counts(recording)[TOPICS["left"]] == 3


def test_a_cut_off_recording_replays_up_to_its_last_complete_chunk(recording, tmp_path,
                                                                  caplog):
    data = recording.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    source = McapSource(cut)
    frames = [e for e in source if isinstance(e, StereoFrame)]
    assert 1 <= len(frames) < 3
    assert source.stats.truncated and "is cut off" in caplog.text and "replayed the" in caplog.text
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(ReplayError, match="not a readable MCAP"):
        McapSource(garbage).scan_calibration()


def test_a_mapped_topic_the_file_lacks_is_an_error_listing_its_topics(recording):
    source = McapSource(recording, TopicMap(left="/camera/left/image_raw"))
    with pytest.raises(ReplayError, match=r"/camera/left/image_raw.*/stereo/right/image_rect"):
        list(source)
    with pytest.raises(ReplayError, match="unknown roles"):
        TopicMap.from_dict({"depth": "/x"})


def test_replay_command_writes_results_and_scores_against_gt(recording, tmp_path, capsys):
    out = tmp_path / "out.mcap"
    assert main(["replay", str(recording), "--out", str(out), "--iters", "2"]) == 0
    text = capsys.readouterr().out
    assert text.count("EPE") == 4 and "overall EPE" in text and "2 it" in text
    overall = float(text.split("overall EPE ")[1].split()[0])
    assert 0 < overall < 3.0  # SGBM is ~4 px on these scenes (README)
    counts = topic_counts(out)
    for key in ("left", "right", "lidar", "sparse", "disparity", "depth", "points"):
        assert counts[TOPICS[key]] == 3, key
    # the output replays again (its results are ignored, its inputs are used)
    events = list(McapSource(out))
    assert sum(isinstance(e, StereoFrame) for e in events) == 3


@pytest.fixture(scope="module")
def rig_sample():
    """One 640x400 rig scene for the tests that only need frames (rendered once)."""
    return make_sample(SEED)


def test_faults_in_a_recording_are_counted_and_skipped(tmp_path, engine, rig_sample):
    sample = rig_sample
    stereo, lidar = SimSource(1).calibration
    path = tmp_path / "faulty.mcap"
    t = 1_000_000_000
    with McapLogger(path, topics=RAW_TOPICS,
                    calibration_toml=dumps_calibration(stereo, lidar)) as logger:
        logger.log_frame(sample.frame(t - 100_000_000, 0))                  # fine
        small = np.zeros((200, 320), np.uint8)
        logger.log_frame(StereoFrame(t, 0, small, small, rectified=True))   # wrong size
        nan_points = sample.scan.points.copy()
        nan_points[:] = np.nan
        logger.log_scan(LidarScan(t + 50_000_000, nan_points))           # all NaN
        logger.log_frame(sample.frame(t + 100_000_000, 1))                  # no usable LiDAR
        logger.log_scan(LidarScan(t + 150_000_000, np.zeros((0, 3), np.float32)))  # empty
        logger.log_scan(LidarScan(t + 195_000_000, sample.scan.points))
        logger.log_frame(sample.frame(t + 200_000_000, 2))                  # fine
    out = tmp_path / "out.mcap"
    with McapLogger(out) as logger:
        pipeline = Pipeline(engine, stereo, lidar, logger)
        stats = run(McapSource(path), pipeline)
    # a later odd-sized frame is skipped and counted (a first one stops the run: see
    # test_replay_sync)
    assert stats.frames == 3 and stats.errors["frame size"] == 1 and stats.fatal is None
    assert stats.errors["lidar scan without finite points"] == 2
    assert topic_counts(out)[TOPICS["disparity"]] == 3


@pytest.fixture
def notify_server(tmp_path, monkeypatch):
    """A datagram socket standing in for systemd's $NOTIFY_SOCKET."""
    sock_path = str(tmp_path / "notify.sock")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(sock_path)
    server.settimeout(2)
    monkeypatch.setenv("NOTIFY_SOCKET", sock_path)
    yield server
    server.close()


def test_pipeline_logs_diagnostics_and_notifies_systemd(tmp_path, engine, notify_server):
    source = SimSource(2, SEED)
    out = tmp_path / "d.mcap"
    with McapLogger(out) as logger:
        pipeline = Pipeline(engine, *source.calibration, logger)
        run(source, pipeline, diagnostics_period_s=0.0)
    messages = [notify_server.recv(100).decode() for _ in range(4)]
    assert messages == ["READY=1", "WATCHDOG=1", "WATCHDOG=1", "STOPPING=1"]
    with open(out, "rb") as f:
        diags = [json.loads(m.data) for _, c, m in make_reader(f).iter_messages(
            topics=[TOPICS["diagnostics"]])]
    assert [d["frames"] for d in diags] == [1, 2]
    assert diags[-1]["drops"] == 0 and diags[-1]["iterations"] == [3]
    assert diags[-1]["latency_ms"]["engine"]["median"] > 0


def test_a_live_source_that_outpaces_inference_drops_the_oldest_frames(engine, rig_sample):
    class Burst:
        """Frames arrive all at once: the queue of 2 must drop."""

        def __init__(self) -> None:
            self.sample = rig_sample

        def close(self) -> None:
            pass

        def __iter__(self):
            for i in range(8):
                yield self.sample.frame(1_000_000_000 + i * 1_000_000, i)

    source = Burst()
    stereo, lidar = SimSource(1).calibration
    pipeline = Pipeline(engine, stereo, lidar)
    seen = []
    stats = run(source, pipeline, threaded=True, queue_size=2,
                on_output=lambda frame, out: seen.append(frame.seq))
    assert stats.drops > 0 and stats.frames + stats.drops == 8
    assert seen == sorted(seen) and seen[-1] == 7  # the newest frame is never dropped


@pytest.mark.parametrize("pipelined", [False, True])
def test_a_burst_keeps_the_newest_frame_pipelined_or_not(engine, pipelined, rig_sample):
    class Burst:
        sample = rig_sample

        def close(self) -> None:
            pass

        def __iter__(self):
            for i in range(8):
                yield self.sample.frame(1_000_000_000 + i * 1_000_000, i)

    stereo, lidar = SimSource(1).calibration
    seen = []
    stats = run(Burst(), Pipeline(engine, stereo, lidar), threaded=True, queue_size=2,
                on_output=lambda frame, out: seen.append(frame.seq), pipelined=pipelined)
    assert stats.drops > 0 and stats.frames + stats.drops == 8
    assert seen == sorted(seen) and seen[-1] == 7
    # each frame's wait in the capture queue, and its whole time in the daemon
    for t in stats.timings:
        assert t["capture_queue"] >= -0.5  # two clocks: monotonic for the LiDAR's wait
        assert t["end_to_end"] >= max(t["frame"], t["capture_queue"]) - 0.5
    if not pipelined:  # the burst came at once: the last frame waited for those before it
        *before, last = stats.timings
        assert last["capture_queue"] >= sum(t["frame"] for t in before) * 0.5


@pytest.mark.slow
def test_the_pipelined_daemon_gives_the_sequential_results(tmp_path):
    """The stages overlap in threads, the frames and their results do not change: a paced sim
    camera, pipelined against sequential, frame by frame (on a busy machine a frame may
    drop: the frames both kept are compared)."""
    from edge_depth.runtime.engine import Engine

    engine = Engine(precision="int8", threads=2, runtime="onnxruntime")
    outputs = {}
    for pipelined in (False, True):
        source = SimSource(5, SEED, period_ms=400.0, realtime=True, distinct=2)
        seen = {}
        with McapLogger(tmp_path / f"p{pipelined}.mcap") as logger:
            stats = run(source, Pipeline(engine, *source.calibration, logger), threaded=True,
                        pipelined=pipelined,
                        on_output=lambda f, o, seen=seen: seen.update({f.seq: o.result}))
        assert stats.frames + stats.drops == 5 and stats.frames >= 2, pipelined
        assert all("engine_queue" in t for t in stats.timings)
        assert stats.throughput() is not None
        outputs[pipelined] = seen
    common = sorted(set(outputs[False]) & set(outputs[True]))
    assert common
    for seq in common:
        np.testing.assert_array_equal(outputs[True][seq].disparity,
                                      outputs[False][seq].disparity)
        # the cycled scenes repeat: frame seq is scene seq % 2, at its own stamp
        assert outputs[True][seq].stamp_ns == 1_000_000_000 + seq * 400_000_000


def test_a_failing_output_callback_stops_a_pipelined_run_instead_of_hanging_it(engine):
    import threading

    source = SimSource(6, SEED, period_ms=50.0, realtime=True, distinct=1)

    def broken(frame, out):
        raise RuntimeError("the caller's callback failed")

    box = {}
    worker = threading.Thread(target=lambda: box.update(stats=run(
        source, Pipeline(engine, *source.calibration), threaded=True, pipelined=True,
        on_output=broken)), daemon=True)
    worker.start()
    worker.join(timeout=60)
    assert not worker.is_alive(), "the pipelined run hung"
    assert box["stats"].errors["output: RuntimeError"] >= 1


def test_logger_rotates_by_duration_and_every_file_is_complete(tmp_path):
    sample = make_sample(SEED, RigConfig(width=160, height=96))
    with McapLogger(tmp_path / "rot.mcap", rotate_s=0.25) as logger:
        logger.set_calibration(sample.calibration())
        for i in range(6):
            logger.log_frame(sample.frame(1_000_000_000 + i * 100_000_000, i))
    assert [p.name for p in logger.files] == ["rot_0001.mcap", "rot_0002.mcap"]
    counts = [topic_counts(p)[TOPICS["left"]] for p in logger.files]
    assert counts == [3, 3]
    # every file carries the calibration, so each replays on its own
    for path in logger.files:
        counts = topic_counts(path)
        assert counts[TOPICS["calibration_file"]] == 1
        assert counts[TOPICS["left_calibration"]] == counts[TOPICS["right_calibration"]] == 1


@pytest.mark.slow
def test_sigterm_finishes_the_frame_and_closes_the_output(recording, tmp_path):
    long_rec = tmp_path / "long.mcap"
    write_sim_recording(long_rec, 12, SEED, period_ms=300.0)
    out = tmp_path / "out.mcap"
    code = ("import sys; from edge_depth.cli import main; rc = main(sys.argv[1:]); "
            "assert 'torch' not in sys.modules, 'torch imported'; sys.exit(rc)")
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "replay", str(long_rec), "--out", str(out), "--realtime"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT)))
    lines = []
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        lines.append(line)
        if line.startswith("frame 1:"):
            break
    proc.send_signal(signal.SIGTERM)
    rest, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    processed = [ln for ln in lines + rest.splitlines() if ln.startswith("frame ")]
    assert 2 <= len(processed) < 12
    assert topic_counts(out)[TOPICS["disparity"]] == len(processed)


def test_topic_map_file_errors_are_one_line(tmp_path, recording, capsys):
    bad = tmp_path / "topics.toml"
    bad.write_text("[nottopics]\nleft = '/x'\n")
    assert main(["replay", str(recording), "--out", str(tmp_path / "o.mcap"),
                 "--topics", str(bad)]) == 1
    assert "[topics] table" in capsys.readouterr().err


def test_demo_writes_mcap_and_picture_and_compares_with_sgbm(tmp_path, capsys):
    import cv2

    assert main(["demo", "--out", str(tmp_path), "--frames", "2"]) == 0
    out = capsys.readouterr().out
    assert "network (int8) EPE" in out and "OpenCV SGBM" in out
    # what runs, said first: the band refinement and the shipped bundle's median included
    assert ("band refinement, weighted median 9x9/2 (the bundle's), 3 iterations"
            in out.splitlines()[0])
    # and on which CPU, so its milliseconds can be compared with like
    from edge_depth.runtime.backends import cpu_description
    assert f"({', '.join(cpu_description()['isa'])}, " in out.splitlines()[0]
    net = float(out.split("network (int8) EPE ")[1].split()[0])
    sgbm = float(out.split("OpenCV SGBM     EPE ")[1].split()[0])
    assert net < sgbm
    # the shipped model has a confidence output: a third row (confidence, confident pixels)
    assert cv2.imread(str(tmp_path / "demo.png")).shape == (1200, 2560, 3)
    counts = topic_counts(tmp_path / "demo.mcap")
    assert counts[TOPICS["depth"]] == 2 and counts[TOPICS["confidence"]] == 2


def test_stop_flag_stops_a_sequential_replay(recording, engine):
    stop = StopFlag()
    stereo, lidar = SimSource(1).calibration
    pipeline = Pipeline(engine, stereo, lidar)
    outputs = []

    def on_output(frame, out):
        outputs.append(frame.seq)
        stop.set()

    run(McapSource(recording), pipeline, stop, on_output=on_output)
    assert outputs == [0]


def test_a_ros2_bag_replays_to_the_same_frames_points_and_calibration(tmp_path):
    from tests.ros2_bag import write_bag

    samples = [make_sample(SEED + i, RigConfig(width=160, height=96)) for i in range(2)]
    path = tmp_path / "ros2.mcap"
    write_bag(path, samples)
    topics = TopicMap(left="/left/image_rect", right="/right/image_rect", lidar="/points",
                      left_info="/left/camera_info", right_info="/right/camera_info",
                      calibration="", gt="")
    events = list(McapSource(path, topics))
    frames = [e for e in events if isinstance(e, StereoFrame)]
    scans = [e for e in events if isinstance(e, LidarScan)]
    (calib,) = [e for e in events if isinstance(e, Calibration)]
    assert len(frames) == 2 and len(scans) == 2
    for frame, scan, s in zip(frames, scans, samples, strict=True):
        np.testing.assert_array_equal(frame.left, s.left)
        np.testing.assert_array_equal(frame.right, s.right)
        np.testing.assert_array_equal(scan.points, s.scan.points)
    assert frames[1].stamp_ns == 1_100_000_000 and scans[0].stamp_ns == 995_000_000
    rig = samples[0].rig
    assert calib.focal_px == rig.focal_px and calib.baseline_m == pytest.approx(rig.baseline_m)
    assert calib.principal_point == (rig.cx, rig.cy)
    laser = [e for e in McapSource(path, dataclasses_replace(topics, lidar="/scan"))
             if isinstance(e, LidarScan)]
    np.testing.assert_allclose(laser[0].points, [[1, 0, 0], [0, 2, 0], [0, -4, 0]], atol=1e-5)
    compressed = [e for e in McapSource(path, dataclasses_replace(topics,
                                                                  right="/right/compressed"))
                  if isinstance(e, StereoFrame)]
    for frame, s in zip(compressed, samples, strict=True):
        np.testing.assert_array_equal(frame.right, s.right)


def dataclasses_replace(obj, **changes):
    import dataclasses

    return dataclasses.replace(obj, **changes)


def test_truncation_at_random_offsets_never_raises_past_the_warning(recording, tmp_path):
    data = recording.read_bytes()
    rng = np.random.default_rng(1)
    for cut_at in sorted(rng.integers(1, len(data), 8)):
        cut = tmp_path / f"cut{cut_at}.mcap"
        cut.write_bytes(data[:cut_at])
        source = McapSource(cut)
        try:
            frames = [e for e in source if isinstance(e, StereoFrame)]
        except ReplayError as exc:  # cut before the first image: a clear error
            assert "no messages on /stereo/left/image_rect" in str(exc)
            continue
        assert len(frames) <= 3 and source.stats.truncated


def test_an_engine_failure_costs_one_frame_and_a_dying_source_is_reported(engine, monkeypatch,
                                                                         rig_sample):
    source = SimSource(3, SEED)
    pipeline = Pipeline(engine, *source.calibration)
    real = engine.infer
    calls = []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("onnxruntime: simulated failure")
        return real(*args, **kwargs)

    monkeypatch.setattr(engine, "infer", flaky)
    stats = run(source, pipeline)
    assert stats.frames == 2 and stats.errors["frame: RuntimeError"] == 1

    class Dying:
        def close(self) -> None:
            pass

        def __iter__(self):
            yield rig_sample.frame(1_000_000_000, 0)
            raise OSError("USB gone")

    monkeypatch.setattr(engine, "infer", real)
    stats = run(Dying(), Pipeline(engine, *source.calibration), threaded=True)
    assert stats.source_failed and stats.errors["source"] == 1 and stats.frames == 1


def test_the_watchdog_is_fed_while_no_frame_arrives(engine, notify_server):

    class Silent:
        """A camera that is reconnecting: nothing for 0.6 s."""

        def close(self) -> None:
            pass

        def __iter__(self):
            time.sleep(0.6)
            return iter(())

    run(Silent(), Pipeline(engine, *SimSource(1).calibration), threaded=True,
        diagnostics_period_s=0.1)
    messages = []
    notify_server.settimeout(0.2)
    try:
        while True:
            messages.append(notify_server.recv(100).decode())
    except TimeoutError:
        pass
    assert messages[0] == "READY=1" and messages[-1] == "STOPPING=1"
    assert messages.count("WATCHDOG=1") >= 3


def test_frames_paired_with_one_scan_project_it_once(engine, rig_sample, monkeypatch):
    import edge_depth.daemon as daemon

    calls = []
    real = daemon.project_to_disparity

    def counted(points, *args, **kwargs):
        calls.append(len(points))
        return real(points, *args, **kwargs)

    monkeypatch.setattr(daemon, "project_to_disparity", counted)
    stereo, lidar = SimSource(1).calibration
    pipeline = Pipeline(engine, stereo, lidar)
    scan = LidarScan(1_000_000_000, rig_sample.scan.points)
    pipeline.on_scan(scan)
    # a fast camera beside a 10 Hz LiDAR: three frames within the sync's window of one scan
    outs = [pipeline.on_frame(rig_sample.frame(1_000_000_000 + k * 20_000_000, k))
            for k in range(3)]
    assert len(calls) == 1 and all(o is not None for o in outs)
    np.testing.assert_array_equal(outs[0].sparse, outs[2].sparse)
    assert (outs[0].sparse > 0).sum() > 1000
    pipeline.on_scan(LidarScan(1_100_000_000, rig_sample.scan.points[::2]))  # the next one
    later = pipeline.on_frame(rig_sample.frame(1_100_000_000, 3))
    assert len(calls) == 2 and later is not None
    assert 0 < (later.sparse > 0).sum() < (outs[0].sparse > 0).sum()
