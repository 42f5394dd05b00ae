"""`edge-depth ros2` (the live node, edge.ros2_node) and `edge-depth ros2-play` (a recording
published, edge.ros2_play): their arguments and their runs. rclpy is imported only when one
runs, so the rest of the command line works without the `ros2` extra."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from edge_depth.arguments import positive_int
from edge_depth.errors import ConfigError
from edge_depth.runtime.options import add_engine_arguments

QOS = ("sensor_data", "reliable")
NODE_EPILOG = ("ROS parameters (--ros-args -p NAME:=VALUE) override the files: topics.<role> "
               "for the inputs (left, right, left_info, right_info, lidar), outputs.<name> "
               "for the outputs (disparity, depth, depth_info, confidence, points, "
               "diagnostics; \"\" = not published), qos, iters, deadline_ms. Topic names "
               "without a leading / are under the node's namespace (--ros-args -r __ns:=/NS).")


def add_parsers(sub) -> None:
    node = sub.add_parser("ros2", help="the engine as a live ROS 2 node (pip install "
                                       "'edge-depth[ros2]')", epilog=NODE_EPILOG)
    node.add_argument("--calib", type=Path, default=None,
                      help="calibration TOML with the LiDAR extrinsics (default: the "
                           "config's [calibration] file)")
    node.add_argument("--config", type=Path, default=None,
                      help="robot TOML: its [engine], [sync], [calibration] and [log]")
    node.add_argument("--topics", type=Path, default=None,
                      help="TOML with a [topics] table mapping roles (left, right, lidar, "
                           "left_info, right_info) to topics, as for replay")
    node.add_argument("--qos", choices=QOS, default=None,
                      help="the inputs' and outputs' QoS (default: sensor_data: best effort, "
                           "the last 5, as camera and LiDAR drivers publish)")
    node.add_argument("--queue", type=positive_int, default=2,
                      help="frames waiting for the engine; the oldest is dropped (counted)")
    node.add_argument("--out", type=Path, default=None,
                      help="also log to this MCAP file, as the daemon does (default: no log)")
    node.add_argument("--max-frames", type=positive_int, default=None,
                      help="stop after N frames")
    add_engine_arguments(node)
    node.add_argument("--ros-args", nargs=argparse.REMAINDER, default=[],
                      help="ROS arguments (remapping, parameters), to the end of the line")
    play = sub.add_parser("ros2-play", help="publish a recording as ROS 2 topics (ros2 bag "
                                            "play without a ROS installation)")
    play.add_argument("recording", type=Path, help="a .mcap recording or a ROS 2 bag directory")
    play.add_argument("--rate", type=rate, default=1.0,
                      help="times real time (0: as fast as it can)")
    play.add_argument("--qos", choices=QOS, default="sensor_data")
    play.add_argument("--ros-args", nargs=argparse.REMAINDER, default=[])


def rate(text: str) -> float:
    """--rate: a finite number >= 0."""
    value = float(text)
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def qos_profile(name: str):
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

    if name == "sensor_data":
        return qos_profile_sensor_data
    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def start_node(name: str, ros_args: list[str]):
    """rclpy initialised (our own SIGINT / SIGTERM handling: the closing summary) and a node."""
    from edge_depth.ros2_node import import_rclpy

    rclpy = import_rclpy()
    from rclpy.signals import SignalHandlerOptions

    context = rclpy.context.Context()
    rclpy.init(args=["edge-depth", "--ros-args", *ros_args] if ros_args else None,
               context=context, signal_handler_options=SignalHandlerOptions.NO)
    return rclpy, context, rclpy.create_node(name, context=context)


def stop_node(rclpy, context, node, executor, thread) -> None:
    """Everything the node started, ended, in order: the executor (its callbacks finish),
    its thread, the node, rclpy's context."""
    if executor is not None:
        executor.shutdown(timeout_sec=2.0)
    if thread is not None:
        thread.join(timeout=5.0)
    node.destroy_node()
    if context.ok():
        rclpy.shutdown(context=context)


def play(args: argparse.Namespace) -> int:
    from edge_depth.ros2_node import spin_in_thread
    from edge_depth.ros2_play import Pacer, is_cdr, play_cdr, play_ours
    from edge_depth.runner import StopFlag

    cdr = is_cdr(args.recording)
    rclpy, context, node = start_node("edge_depth_play", args.ros_args)
    executor, thread = spin_in_thread(rclpy, node)
    stop = StopFlag()
    stop.install()
    try:
        player = play_cdr if cdr else play_ours
        stats = player(node, args.recording, qos_profile(args.qos),
                       Pacer(args.rate, stop.event), stop.event)
    finally:
        stop.restore()
        stop_node(rclpy, context, node, executor, thread)
    skipped = ", ".join(f"{t} ({n})" for t, n in stats.skipped.items())
    print(f"published {stats.published} messages from {args.recording}"
          + (f"; not published (type not installed): {skipped}" if skipped else ""))
    return 0


def node_parameters(ros, topics, args, options) -> dict:
    """The node's ROS parameters, declared with the files' and flags' values as defaults
    and read back (a launch file's or --ros-args' win); ConfigError naming a bad one."""
    import dataclasses

    from edge_depth.ros2_node import OUTPUTS

    roles = ("left", "right", "left_info", "right_info", "lidar")
    declared = {f"topics.{r}": getattr(topics, r) for r in roles}
    declared.update({f"outputs.{k}": v for k, v in OUTPUTS.items()})
    declared.update({"qos": args.qos or "sensor_data", "iters": int(options.iters),
                     "deadline_ms": float(options.deadline_ms)})
    values = {name: _parameter(ros, name, default) for name, default in declared.items()}
    if values["qos"] not in QOS:
        raise ConfigError("qos (ROS parameter)", f"one of {', '.join(QOS)}", values["qos"])
    iters, deadline_ms = _number(values, "iters", int), _number(values, "deadline_ms", float)
    if not 0 <= iters <= 64 or not deadline_ms >= 0:
        raise ConfigError("iters / deadline_ms (ROS parameters)", "iters 0-64 (0: the "
                          "bundle's), deadline_ms >= 0 (0: none)", f"{iters}, {deadline_ms}")
    return dict(topics=dataclasses.replace(topics, **{r: str(values[f"topics.{r}"])
                                                      for r in roles}),
                outputs={k: str(values[f"outputs.{k}"]) for k in OUTPUTS
                         if values[f"outputs.{k}"]},
                qos=values["qos"], iters=iters or None, deadline_ms=deadline_ms or None)


def _parameter(ros, name: str, default):
    """A parameter declared with dynamic typing (`-p deadline_ms:=50` is an integer where a
    float was declared): its value, or ConfigError naming it."""
    from rcl_interfaces.msg import ParameterDescriptor

    try:
        return ros.declare_parameter(name, default,
                                     ParameterDescriptor(dynamic_typing=True)).value
    except Exception as exc:  # noqa: BLE001 - rclpy's parameter exceptions, one line
        raise ConfigError(f"{name} (ROS parameter)", "a value of its type", str(exc)) from None


def _number(values: dict, name: str, kind):
    value = values[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
        raise ConfigError(f"{name} (ROS parameter)", "a number", value)
    return kind(value)


def node_calibration(calib: Path | None, config):
    """(stereo, lidar) from --calib, else the config's [calibration] file: the node cannot
    receive /tf_static (tf2_msgs is not served as a wheel), so the file carries the LiDAR."""
    from edge_depth.calibration.io import load_calibration

    path = calib or (config.calibration.file if config is not None else "")
    if not path:
        raise ConfigError("--calib", "a calibration file with the LiDAR extrinsics ([lidar]): "
                          "/tf_static cannot be received without tf2_msgs", None)
    stereo, lidar = load_calibration(path)
    if lidar is None:
        raise ConfigError("--calib", f"{path} with a [lidar] section (T_cam_lidar)", None)
    return stereo, lidar


def node(args: argparse.Namespace) -> int:
    """`edge-depth ros2`: the files and flags, then the node and its parameters, then the
    engine (all that can fail, before the run), then the run."""
    from edge_depth.arguments import load_topic_map
    from edge_depth.capture.replay import TopicMap
    from edge_depth.config import check_output_path, load_robot_config
    from edge_depth.ros2_node import input_topics
    from edge_depth.runtime.options import options_from_args

    config = load_robot_config(args.config) if args.config else None
    stereo, lidar = node_calibration(args.calib, config)
    topics = input_topics(TopicMap.from_dict(load_topic_map(args.topics)) if args.topics
                          else None)
    options = options_from_args(args, base=config.engine if config is not None else None)
    if args.out is not None:
        check_output_path(args.out, "--out")
    rclpy, context, ros = start_node("edge_depth", args.ros_args)
    executor = thread = None
    try:
        params = node_parameters(ros, topics, args, options)
        from edge_depth.runtime.engine import Engine

        engine = Engine(options=options)
        engine.plan_for(tuple(stereo.image_size))
        executor, thread, done = run_node(args, config, (stereo, lidar), params, engine,
                                          (rclpy, ros))
    finally:
        stop_node(rclpy, context, ros, executor, thread)
    return node_exit(*done)


def run_node(args, config, calibration, params, engine, ros_handles):
    """The daemon's runner and pipeline between the node's subscriptions and publishers,
    until SIGINT / SIGTERM (or --max-frames): (executor, thread, (stats, pipeline, source,
    outputs, seconds))."""
    import contextlib

    from edge_depth.daemon import Pipeline
    from edge_depth.foxglove_msgs import CAMERA_FRAME
    from edge_depth.ros2_node import Ros2Outputs, Ros2Source, spin_in_thread
    from edge_depth.runner import StopFlag, run

    rclpy, ros = ros_handles
    source = Ros2Source(ros, params["topics"], qos_profile(params["qos"]))
    outputs = Ros2Outputs(ros, params["outputs"], qos_profile("reliable"),
                          frame_id=lambda: source.frame_id or CAMERA_FRAME)
    stop = StopFlag()
    with contextlib.ExitStack() as stack:
        logger, log_raw = node_logger(args.out, config, outputs, stack)
        pipeline = Pipeline(engine, *calibration, logger, params["iters"],
                            params["deadline_ms"], node_sync(config), log_raw=log_raw,
                            watch_every=config.calibration.watch_every if config else 13)
        outputs.advertise()  # subscribers can match before the first output
        executor, thread = spin_in_thread(rclpy, ros, on_error=partial_fatal(pipeline, stop))
        stop.install()
        try:
            print(f"edge-depth ros2: node {ros.get_fully_qualified_name()}, "
                  f"{engine.describe()} engine; in: {', '.join(source.wanted())}; out: "
                  f"{', '.join(ros.resolve_topic_name(t) for t in params['outputs'].values())}",
                  flush=True)
            started = time.monotonic()
            stats = run(source, pipeline, stop, threaded=True, queue_size=args.queue,
                        max_frames=args.max_frames, pipelined=engine.options.pipelined)
            outputs.close()
        finally:
            stop.restore()
    return executor, thread, (stats, pipeline, source, outputs, time.monotonic() - started)


def partial_fatal(pipeline, stop):
    """What the executor thread's death does: the run stops, exits 1, and says why."""
    def fatal(exc: BaseException) -> None:
        pipeline.stats.fatal = f"the ROS 2 executor stopped: {type(exc).__name__}: {exc}"
        stop.set()

    return fatal


def node_logger(out: Path | None, config, outputs, stack):
    """The pipeline's logger: the publishers, and with --out an MCAP log beside them as the
    daemon writes it ([log]: profile, rotation, compression, topics; never overwriting).
    (logger, whether raw topics are logged)."""
    if out is None:
        return outputs, False
    from edge_depth.commands import logger_options
    from edge_depth.config import LogConfig
    from edge_depth.loggers import open_logger
    from edge_depth.mcap_log import RAW_TOPICS
    from edge_depth.ros2_node import LoggerPair

    lg = config.log if config is not None else LogConfig()
    log_file = stack.enter_context(open_logger(
        out, topics=(RAW_TOPICS if lg.raw else ()) + lg.results, **logger_options(lg)))
    return LoggerPair(outputs, log_file), lg.raw


def node_sync(config):
    """The daemon's pairing of scans with frames: the config's [sync], else replay's."""
    if config is None:
        return None
    from edge_depth.capture.sync import SyncConfig
    from edge_depth.config import sync_mode

    return SyncConfig(sync_mode(config), config.sync.window_ms,
                      max_wait_ms=config.sync.max_wait_ms, deskew=config.sync.deskew)


def node_exit(stats, pipeline, source, outputs, seconds: float) -> int:
    """The closing summary and the exit status: 1 on a fatal stop or when nothing was
    processed (never silent: it says which topics never came)."""
    print_node_summary(stats, pipeline, source, outputs, seconds)
    if stats.fatal:
        print(f"error: {stats.fatal}", file=sys.stderr)
        return 1
    if stats.frames == 0:
        waiting = source.counters()["waiting_for"]
        print("error: no frame was processed"
              + (f"; never advertised: {', '.join(waiting)}" if waiting else
                 "; no left and right image paired (see the input errors above)"),
              file=sys.stderr)
        return 1
    return 0


def print_node_summary(stats, pipeline, source, outputs, elapsed: float) -> None:
    """The node's closing lines: frames, drops, what came in and went out, the LiDAR's and
    the calibration watch's lines, the latency."""
    from edge_depth.frame_summary import (
        format_latency,
        lidar_summary,
        rate_summary,
        summarise,
        watch_summary,
    )

    counters = source.counters()
    print(f"{stats.frames} frames in {elapsed:.1f} s, {stats.scans} scans, {stats.drops} "
          f"dropped (queue), {counters['messages']} messages in, {outputs.published} out; "
          f"errors {dict(stats.errors) or 'none'}; input errors {counters['errors'] or 'none'}")
    if counters["waiting_for"]:
        print(f"never advertised: {', '.join(counters['waiting_for'])}")
    print(lidar_summary(pipeline))
    if watched := watch_summary(pipeline, None, None):
        print(watched)
    if rated := rate_summary(pipeline.propagator):
        print(rated)
    if unhealthy := pipeline.health.summary():
        print(unhealthy)
    if lat := summarise(stats.timings):
        print("latency median / p95 ms: " + format_latency(lat))


def check_domain() -> None:
    """ROS_DOMAIN_ID, when set, is a DDS domain (0-232): one line, not a DDS error."""
    value = os.environ.get("ROS_DOMAIN_ID", "")
    if value and not (value.isdigit() and int(value) <= 232):
        raise ConfigError("ROS_DOMAIN_ID", "an integer 0-232 (the environment variable)", value)


def main_ros2(args: argparse.Namespace) -> int:
    from edge_depth.ros2_node import import_rclpy

    import_rclpy()  # a missing extra: one line, before anything loads
    check_domain()
    return node(args) if args.command == "ros2" else play(args)
