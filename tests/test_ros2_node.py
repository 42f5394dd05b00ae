"""`edge-depth ros2` over real DDS (Fast DDS from PyPI's ROS 2 wheels): the node runs in a
process of its own, as on a robot; this process publishes a recording and collects what the
node publishes. Each test has a DDS domain of its own and discovery stays on localhost."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="the ros2 extra: pip install 'edge-depth[ros2]'")

from edge_depth.calibration.io import save_calibration  # noqa: E402
from edge_depth.calibration.model import LidarExtrinsics  # noqa: E402
from edge_depth.ros2_node import spin_in_thread, wait_for  # noqa: E402
from edge_depth.ros2_play import Pacer, play_cdr, play_ours  # noqa: E402
from edge_depth.sim import RigConfig, make_sample  # noqa: E402
from tests.ros2_bag import write_bag  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RIG = RigConfig(width=160, height=96)
NODE = ("import sys; from edge_depth.cli import main; sys.exit(main(sys.argv[1:]))")


DOMAINS = iter(range(1, 1000))


@pytest.fixture
def domain(monkeypatch) -> int:
    """A DDS domain of the test's own, on localhost: xdist workers take turns through 1-100
    (gw0: 1, 5, 9, ...; gw1: 2, 6, ...), clear of Linux's ephemeral ports above 101."""
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:] or 0)
    number = 1 + (worker + 4 * next(DOMAINS)) % 100
    monkeypatch.setenv("ROS_DOMAIN_ID", str(number))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return number


def start_node(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", NODE, "ros2", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)))


class Graph:
    """This process's side of the graph: a node that publishes and collects."""

    def __init__(self, domain: int) -> None:
        from rclpy.signals import SignalHandlerOptions

        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("edge_depth_test", context=self.context)
        self.executor, self.thread = spin_in_thread(rclpy, self.node)
        self.got: dict[str, list] = {}
        self.stop = threading.Event()  # ends a play still going when the test is done
        self.players: list[threading.Thread] = []

    def collect(self, topic: str, msg_type) -> list:
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        box = self.got.setdefault(topic, [])
        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(msg_type, topic, box.append, qos)
        return box

    def play(self, path: Path, rate: float = 0.5) -> int:
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        return play_cdr(self.node, path, qos, Pacer(rate, self.stop), self.stop,
                        wait_s=30.0).published

    def play_ours(self, path: Path, rate: float = 0.5) -> int:
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        return play_ours(self.node, path, qos, Pacer(rate, self.stop), self.stop,
                         wait_s=30.0).published

    def play_in_thread(self, path: Path, rate: float) -> None:
        self.players.append(threading.Thread(target=self.play, args=(path, rate)))
        self.players[-1].start()

    def close(self) -> None:
        self.stop.set()
        for player in self.players:
            player.join(timeout=30.0)
        self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
        self.thread.join(timeout=5.0)


@pytest.fixture
def graph(domain):
    g = Graph(domain)
    yield g
    g.close()


@pytest.fixture(scope="module")
def samples():
    return [make_sample(800_000 + i, RIG, "beams16") for i in range(4)]


def peer_bag(tmp_path: Path, samples, **kwargs) -> tuple[Path, Path, Path]:
    """Another tool's bag (its topic names and frames), its calibration file, a topic map."""
    bag = tmp_path / "peer.mcap"
    write_bag(bag, samples, **kwargs)
    calib = tmp_path / "calib.toml"
    save_calibration(calib, samples[0].calibration(),
                     LidarExtrinsics(samples[0].T_cam_lidar))
    topics = tmp_path / "topics.toml"
    topics.write_text('[topics]\nleft = "/left/image_rect"\nright = "/right/image_rect"\n'
                      'left_info = "/left/camera_info"\nright_info = "/right/camera_info"\n'
                      'lidar = "/points"\n')
    return bag, calib, topics


def finish(node: subprocess.Popen, timeout: float = 60.0) -> str:
    out, _ = node.communicate(timeout=timeout)
    assert node.returncode == 0, out
    return out


def summary_line(out: str) -> str:
    """The node's closing line: frames, scans, drops, messages, errors."""
    return next(line for line in out.splitlines() if " frames in " in line)


def disparities(messages) -> dict[int, np.ndarray]:
    def stamp(m):
        return m.header.stamp.sec * 10**9 + m.header.stamp.nanosec

    return {stamp(m): np.frombuffer(bytes(m.image.data), "<f4").reshape(m.image.height,
                                                                        m.image.width)
            for m in messages}


def test_the_node_gives_replays_disparity_for_every_frame_of_a_peer_bag(graph, samples,
                                                                       tmp_path):
    from sensor_msgs.msg import CameraInfo, Image
    from stereo_msgs.msg import DisparityImage

    from edge_depth.arguments import load_topic_map
    from edge_depth.commands import replay_command
    from edge_depth.runtime.options import EngineOptions

    bag, calib, topics = peer_bag(tmp_path, samples, scans_after_frames=True)
    got = graph.collect("/disparity", DisparityImage)
    depth = graph.collect("/depth/image_rect", Image)
    info = graph.collect("/depth/camera_info", CameraInfo)
    node = start_node(["--calib", str(calib), "--topics", str(topics), "--qos", "reliable",
                       "--max-frames", str(len(samples)), "--iters", "2", "--queue", "8"])
    assert graph.play(bag) > 0
    out = finish(node)
    assert wait_for(lambda: len(got) == len(samples), 10.0), out
    assert f"frames with LiDAR: {len(samples)} of {len(samples)}" in out  # scans came late
    # replay of the same bag: the same frames, the same pixels
    replayed = tmp_path / "replay.mcap"
    assert replay_command(bag, replayed, EngineOptions(iters=2), calib,
                          load_topic_map(topics)) == 0
    want = read_disparities(replayed)
    live = disparities(got)
    assert sorted(live) == sorted(want)
    for stamp, image in live.items():
        assert np.abs(image - want[stamp]).max() < 1e-3
    assert {m.header.frame_id for m in got} == {"camera"}  # the input's frame, not ours
    finite = np.frombuffer(bytes(depth[0].data), "<f4")
    assert depth[0].encoding == "32FC1" and np.isfinite(finite).mean() > 0.5
    assert info and info[0].header.stamp == depth[0].header.stamp and info[0].width == RIG.width


def read_disparities(path: Path) -> dict[int, np.ndarray]:
    from edge_depth.capture.decode import decode_image, decode_message, message_decoders
    from edge_depth.capture.mcap_tolerant import ReadReport, iter_messages
    from edge_depth.mcap_log import TOPICS

    factories, decoders, out = message_decoders(), {}, {}
    for schema, channel, message in iter_messages(path, ReadReport()):
        if channel.topic == TOPICS["disparity"]:
            out[message.log_time] = decode_image(decode_message(schema, channel, message,
                                                                factories, decoders))
    return out


def test_a_laserscan_lidar_works_with_only_a_topics_file(graph, samples, tmp_path):
    bag, calib, topics = peer_bag(tmp_path, samples)
    topics.write_text(topics.read_text().replace('lidar = "/points"', 'lidar = "/scan"'))
    node = start_node(["--calib", str(calib), "--topics", str(topics), "--qos", "reliable",
                       "--max-frames", str(len(samples)), "--iters", "1", "--queue", "8",
                       "--rate", "camera"])
    graph.play(bag)
    out = finish(node)
    first = summary_line(out)
    assert first.startswith(f"{len(samples)} frames in ") and f", {len(samples)} scans" in first
    assert "input errors none" in first
    # at the camera's rate its closing lines say what the engine ran on: a scan a frame here
    assert re.search(rf"Camera rate: {len(samples)} key frames \(the engine\) on "
                     rf"{len(samples)} scans.*?, 0 carried", out), out


def bad_bag(path: Path, samples) -> None:
    """Two good frames with their scans, and between them what a broken driver sends: a left
    image in an encoding we do not read, one whose step is short of its width, an empty
    cloud and a cloud of NaN points."""
    from mcap_ros2.writer import Writer

    from edge_depth.ros2_log import cloud_msg, image_msg
    from edge_depth.ros2_msgs import MSGDEFS

    with open(path, "wb") as f:
        w = Writer(f)
        schemas = {k: w.register_msgdef(k, v) for k, v in MSGDEFS.items()}

        def put(topic: str, kind: str, message: dict, t: int) -> None:
            w.write_message(topic, schemas[f"sensor_msgs/msg/{kind}"], message, log_time=t)

        for i, s in enumerate(samples[:2]):
            t = 10**9 + 2 * i * 10**8
            put("/points", "PointCloud2", cloud_msg(s.scan.points, t - 5 * 10**6, "lidar"), t)
            put("/left/image_rect", "Image", image_msg(s.left, t, "camera"), t)
            put("/right/image_rect", "Image", image_msg(s.right, t, "camera"), t)
            bad_t = t + 10**8
            wrong = dict(image_msg(s.left, bad_t, "camera"), encoding="16UC1")
            short = dict(image_msg(s.right, bad_t, "camera"), step=3)
            put("/left/image_rect", "Image", wrong, bad_t)
            put("/right/image_rect", "Image", short, bad_t)
            put("/points", "PointCloud2", cloud_msg(np.zeros((0, 3), np.float32), bad_t,
                                                     "lidar"), bad_t)
            put("/points", "PointCloud2", cloud_msg(np.full((50, 3), np.nan, np.float32),
                                                     bad_t + 1, "lidar"), bad_t + 1)
        w.finish()


def test_malformed_messages_are_counted_and_skipped_and_the_good_frames_go_on(graph, samples,
                                                                             tmp_path):
    from stereo_msgs.msg import DisparityImage

    _, calib, topics = peer_bag(tmp_path, samples)
    bag = tmp_path / "bad.mcap"
    bad_bag(bag, samples)
    got = graph.collect("/disparity", DisparityImage)
    node = start_node(["--calib", str(calib), "--topics", str(topics), "--qos", "reliable",
                       "--max-frames", "2", "--iters", "1", "--queue", "8"])
    graph.play(bag)
    out = finish(node)
    assert wait_for(lambda: len(got) == 2, 10.0), out
    errors = summary_line(out).split("input errors ")[1]
    assert "16UC1" in errors and "short" in errors  # each named, counted, skipped


def test_sigint_mid_stream_ends_the_node_with_its_summary_and_no_thread_left(graph, samples,
                                                                            tmp_path, capsys):
    """The node in this process, its SIGINT sent mid-stream: it returns with its summary and
    every thread it started (the executor's, the runner's) has ended."""
    from stereo_msgs.msg import DisparityImage

    from edge_depth.cli import main
    from edge_depth.runtime.engine import Engine

    bag, calib, topics = peer_bag(tmp_path, samples * 3)
    got = graph.collect("/disparity", DisparityImage)
    Engine()  # the runtime's own threads (OpenVINO's telemetry pool) start before the count
    before = set(threading.enumerate())
    graph.play_in_thread(bag, 0.2)

    def interrupt() -> None:
        if wait_for(lambda: len(got) >= 1, 60.0):
            os.kill(os.getpid(), signal.SIGINT)

    interrupter = threading.Thread(target=interrupt, daemon=True)
    interrupter.start()
    code = main(["ros2", "--calib", str(calib), "--topics", str(topics), "--qos", "reliable",
                 "--iters", "1"])
    graph.stop.set()
    out = capsys.readouterr().out
    assert code == 0 and summary_line(out) and 1 <= len(got) < len(samples) * 3
    mine = before | set(graph.players) | {interrupter}
    assert wait_for(lambda: not [t for t in threading.enumerate() if t not in mine], 5.0), \
        [t.name for t in threading.enumerate() if t not in mine]


def test_a_bad_ros_parameter_is_one_line_naming_it(domain, samples, tmp_path):
    _, calib, _ = peer_bag(tmp_path, samples)
    node = start_node(["--calib", str(calib), "--ros-args", "-p", "qos:=fast"])
    out, _ = node.communicate(timeout=60)
    assert node.returncode == 1
    assert out.strip().splitlines()[-1] == ("edge-depth ros2: error: qos (ROS parameter): "
                                            "expected one of sensor_data, reliable, got 'fast'")


def test_a_node_stopped_before_any_input_says_which_topics_never_came(domain, samples,
                                                                       tmp_path):
    _, calib, _ = peer_bag(tmp_path, samples)
    node = start_node(["--calib", str(calib), "--ros-args", "-p", "topics.lidar:=/velodyne"])
    first = node.stdout.readline()  # the start line: the node is up
    assert first.startswith("edge-depth ros2: node /edge_depth")
    node.send_signal(signal.SIGINT)
    rest, _ = node.communicate(timeout=30)
    assert node.returncode == 1
    assert rest.strip().splitlines()[-1] == (
        "error: no frame was processed; never advertised: /velodyne, left/camera_info, "
        "left/image_rect, right/camera_info, right/image_rect")


def test_our_own_recording_played_to_the_nodes_default_topics_gives_replays_disparity(
        graph, tmp_path):
    from stereo_msgs.msg import DisparityImage

    from edge_depth.calibration.io import save_calibration as save
    from edge_depth.capture.recording_calibration import recording_calibration
    from edge_depth.capture.replay import McapSource
    from edge_depth.commands import replay_command
    from edge_depth.runtime.options import EngineOptions
    from edge_depth.sim_recording import write_sim_recording

    rec = tmp_path / "ours.mcap"
    write_sim_recording(rec, 3, seed=5, rig=RIG)
    calib = tmp_path / "calib.toml"
    save(calib, *recording_calibration(McapSource(rec))[:2])
    got = graph.collect("/disparity", DisparityImage)
    node = start_node(["--calib", str(calib), "--qos", "reliable", "--max-frames", "3",
                       "--iters", "2", "--queue", "8"])
    assert graph.play_ours(rec) > 0
    out = finish(node)
    assert wait_for(lambda: len(got) == 3, 10.0), out
    replayed = tmp_path / "replay.mcap"
    assert replay_command(rec, replayed, EngineOptions(iters=2)) == 0
    want, live = read_disparities(replayed), disparities(got)
    assert sorted(live) == sorted(want)
    assert max(np.abs(image - want[stamp]).max() for stamp, image in live.items()) < 1e-3


def test_at_the_camera_rate_the_node_carries_between_scans_as_replay_does(graph, tmp_path):
    """A moving world with a scan every third frame, played to the node at the camera's rate:
    key frames on the scans, the frames between carried, the same frames and pixels as
    `replay --rate camera` of the recording."""
    from stereo_msgs.msg import DisparityImage

    from edge_depth.calibration.io import save_calibration as save
    from edge_depth.capture.recording_calibration import recording_calibration
    from edge_depth.capture.replay import McapSource
    from edge_depth.cli import main as cli_main
    from edge_depth.commands import replay_command
    from edge_depth.runtime.options import EngineOptions

    rec = tmp_path / "forward.mcap"
    assert cli_main(["synth", "--mcap", str(rec), "--count", "6", "--size", "192x120",
                     "--motion", "forward", "--fps", "30", "--scan-every", "3"]) == 0
    calib = tmp_path / "calib.toml"
    save(calib, *recording_calibration(McapSource(rec))[:2])
    got = graph.collect("/disparity", DisparityImage)
    node = start_node(["--calib", str(calib), "--qos", "reliable", "--max-frames", "6",
                       "--iters", "2", "--queue", "8", "--rate", "camera"])
    assert graph.play_ours(rec) > 0
    out = finish(node)
    assert wait_for(lambda: len(got) == 6, 10.0), out
    found = re.search(r"Camera rate: (\d+) key frames \(the engine\) on 2 scans, (\d+) carried",
                      out)
    assert found, out
    assert int(found[1]) + int(found[2]) == 6 and int(found[2]) >= 2
    replayed = tmp_path / "replay.mcap"
    assert replay_command(rec, replayed, EngineOptions(iters=2, rate="camera")) == 0
    want, live = read_disparities(replayed), disparities(got)
    assert sorted(live) == sorted(want)
    assert max(np.abs(image - want[stamp]).max() for stamp, image in live.items()) < 1e-3
