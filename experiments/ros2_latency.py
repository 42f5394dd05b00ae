"""The live ROS 2 node's rate and latency on the sim robot (README, docs/ros2.md).

    python experiments/ros2_latency.py [--seconds 30] [--warmup 5] [--avx2] [--motion KIND]
        [-- NODE FLAGS]

A camera driver's stand-in publishes the sim robot's pair at 30 Hz (640x400 mono8, eight
scenes rendered once and cycled, as the daemon's sim camera does) with wall-clock stamps, and
a LiDAR driver's, in a DDS participant of its own, its scans (16 beams) on every third frame
(10 Hz); `edge-depth ros2` runs in a process of its
own (`--avx2`: under experiments/avx2_kernels.sh, an AVX2-only CPU's kernels); this process
collects /disparity and prints the depth rate, the end-to-end latency (output received minus
its input's stamp, one host clock) median / p95 after the warm-up, and the node's closing
summary (its drops). The DDS domain is a random one, discovery on localhost.
`--motion KIND` (edge.sim.motion's kinds): one moving world instead of the eight scenes, 60
frames (2 s) rendered once and played forward and back as the sim robot's `sim_motion` does,
for `-- --rate camera` (between scans a new scene each frame is a lost flow: a key frame).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from edge_depth.sim.motion import KINDS

ROOT = Path(__file__).resolve().parents[1]
SCENES = 8
MOVING_FRAMES = 60


def start_node(calib: Path, avx2: bool, flags: list[str]) -> subprocess.Popen:
    command = [str(ROOT / ".venv/bin/edge-depth"), "ros2", "--calib", str(calib), *flags]
    if avx2:
        command = ["bash", str(ROOT / "experiments/avx2_kernels.sh"), *command]
    return subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def main() -> int:
    import rclpy
    from stereo_msgs.msg import DisparityImage

    from edge_depth.calibration.io import save_calibration
    from edge_depth.calibration.model import LidarExtrinsics
    from edge_depth.ros2_node import Ros2Outputs, spin_in_thread
    from edge_depth.ros2_play import RAW_NAMES, wait_for_subscribers
    from edge_depth.sim import RigConfig, make_sample
    from edge_depth.types import LidarScan, StereoFrame

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--warmup", type=float, default=5.0)
    p.add_argument("--avx2", action="store_true")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--motion", choices=sorted(KINDS), default=None)
    p.add_argument("node_flags", nargs="*")
    args = p.parse_args()
    os.environ["ROS_DOMAIN_ID"] = str(random.randrange(1, 200))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    if args.motion is None:
        samples = [make_sample(1_000_000 + i, RigConfig(), "beams16") for i in range(SCENES)]
    else:  # 0, 1, ..., 59, 58, ..., 1: no scene cut where the loop closes
        from edge_depth.sim.motion import moving_sample

        ahead = [moving_sample(1_000_000, i / 30.0, KINDS[args.motion], RigConfig(),
                               "beams16", frame=i) for i in range(MOVING_FRAMES)]
        samples = ahead + ahead[-2:0:-1]
    calib = Path(tempfile.mkdtemp()) / "calib.toml"
    save_calibration(calib, samples[0].calibration(), LidarExtrinsics(samples[0].T_cam_lidar))
    node = start_node(calib, args.avx2, args.node_flags)
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

    qos = qos_profile_sensor_data  # the inputs as the node expects them by default
    # the camera and the LiDAR as two drivers are, two DDS participants (with one for both,
    # a third of the scans never reached the node: docs/experiments.md)
    contexts, nodes, outputs = [], [], []
    for name, names in (("camera_stand_in", {k: v for k, v in RAW_NAMES.items()
                                             if k != "lidar"}),
                        ("lidar_stand_in", {"lidar": RAW_NAMES["lidar"]})):
        contexts.append(rclpy.context.Context())
        rclpy.init(context=contexts[-1])
        nodes.append(rclpy.create_node(name, context=contexts[-1]))
        outputs.append(Ros2Outputs(nodes[-1], names, qos))
    camera, lidar = outputs
    camera.set_calibration(samples[0].calibration(), LidarExtrinsics(samples[0].T_cam_lidar))
    ros = nodes[0]
    received: list[tuple[int, int]] = []  # (stamp, received) ns, wall clock
    # reliable, as the node publishes (a best-effort reader here received one in ten of the
    # 1 MB images: docs/experiments.md)
    ros.create_subscription(DisparityImage, "/disparity", lambda m: received.append(
        (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, time.time_ns())),
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    executor, thread = spin_in_thread(rclpy, ros)
    wait_for_subscribers(camera.advertise() + lidar.advertise(), 60.0)
    sent = publish(camera, lidar, samples, args.seconds + args.warmup, LidarScan, StereoFrame)
    time.sleep(1.0)
    node.send_signal(signal.SIGINT)
    log, _ = node.communicate(timeout=60)
    executor.shutdown()
    for ros, context in zip(nodes, contexts, strict=True):
        ros.destroy_node()
        rclpy.shutdown(context=context)
    report(received, sent, args, log)
    return 0


def publish(camera, lidar, samples, seconds: float, LidarScan, StereoFrame) -> dict:
    """30 Hz frames, a scan on every third (stamped 5 ms before it); wall-clock stamps."""
    start, i = time.monotonic(), 0
    sent = {"frames": 0, "scans": 0, "start_ns": time.time_ns()}
    while (due := start + i / 30.0) < start + seconds:
        time.sleep(max(due - time.monotonic(), 0.0))
        s, stamp = samples[i % len(samples)], time.time_ns()
        if i % 3 == 0:
            lidar.log_scan(LidarScan(stamp - 5_000_000, s.scan.points))
            sent["scans"] += 1
        camera.log_frame(StereoFrame(stamp, i, s.left, s.right, rectified=True))
        sent["frames"] += 1
        i += 1
    return sent


def report(received, sent: dict, args, log: str) -> None:
    warm = sent["start_ns"] + int(args.warmup * 1e9)
    kept = [(s, r) for s, r in received if s >= warm]
    latency = np.array([(r - s) / 1e6 for s, r in kept])
    rate = len(kept) / args.seconds
    # rate "camera": the scans a key frame ran with (each once) over the scans the node got
    keyed = re.search(r"Camera rate: \d+ key frames \(the engine\) on (\d+) scans", log)
    got = re.search(r" frames in [\d.]+ s, (\d+) scans", log)
    isa = subprocess.run("grep -o -w 'avx512_vnni\\|avx_vnni\\|avx512_bf16' /proc/cpuinfo | "
                         "sort -u | tr '\\n' ' '", shell=True, capture_output=True,
                         text=True).stdout.strip() or "AVX2 only"
    result = dict(seconds=args.seconds, frames_sent=sent["frames"], scans_sent=sent["scans"],
                  depth_received=len(kept), depth_hz=round(rate, 2),
                  latency_ms_median=round(float(np.median(latency)), 1) if kept else None,
                  latency_ms_p95=round(float(np.percentile(latency, 95)), 1) if kept else None,
                  scans_with_key_frame=None if keyed is None or got is None else
                  round(int(keyed.group(1)) / max(int(got.group(1)), 1), 3),
                  kernels="AVX2 (avx2_kernels.sh)" if args.avx2 else "native", host_isa=isa)
    print(json.dumps(result))
    print("node:", *[line for line in log.splitlines() if " frames in " in line
                     or line.startswith("latency") or line.startswith("frames with")
                     or line.startswith("Camera rate")], sep="\n")
    if args.json:
        args.json.write_text(json.dumps(dict(result, node_log=log), indent=1))


if __name__ == "__main__":
    sys.exit(main())
