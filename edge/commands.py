"""The daemon's commands: `edge-depth run`, `record` and `replay` (edge.daemon does the work).

Each loads its configuration and calibration first — a bad file exits 1 naming the file and
the key before any device is opened — then wires sources, the pipeline and the MCAP logger.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from edge_depth.calibration.model import LidarExtrinsics, StereoCalibration
from edge_depth.calibration_watch import EVERY as WATCH_EVERY
from edge_depth.capture.sync import SyncConfig
from edge_depth.config import LogConfig, check_output_path
from edge_depth.daemon import Pipeline, PipelineStats
from edge_depth.errors import ConfigError
from edge_depth.frame_summary import (
    format_latency,
    lidar_summary,
    rate_summary,
    selection_summary,
    summarise,
    watch_summary,
)
from edge_depth.loggers import open_logger
from edge_depth.runner import StopFlag, run
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.types import LidarScan

if TYPE_CHECKING:
    from edge_depth.capture.replay import McapSource

log = logging.getLogger(__name__)
SIM_SCENES = 8  # the sim camera renders this many scenes once and cycles them
SIM_MOTION_FRAMES = 60  # with camera.sim_motion: this many frames of the moving world,
# played forward and back


@dataclasses.dataclass
class ReplayRun:
    """One recording replayed: what the closing summary and a fleet's result record say."""

    stats: PipelineStats
    pipeline: Pipeline
    source: McapSource
    files: list[Path]

    def record(self) -> dict:
        """The numbers of a fleet's result record and summary table."""
        stats = self.stats
        lat = summarise(stats.timings)
        with_lidar = self.pipeline.sync.counters()["frames_with_lidar"]
        metrics = stats.metrics
        return dict(frames=stats.frames, frames_with_lidar=with_lidar if self.pipeline.lidar
                    else 0, ms_per_frame=lat["frame"]["median"] if lat else None,
                    engine_ms=lat["engine"]["median"] if lat else None,
                    epe=metrics.mean("epe") if metrics else None,
                    bad3=metrics.mean("bad3") if metrics else None,
                    skipped=dict(stats.errors), read_errors=dict(self.source.stats.errors),
                    lost=list(self.source.stats.lost), output_health=self.pipeline.health.worst,
                    files=[str(f) for f in self.files])

    def skipped(self) -> str:
        """The skip counts, the reader's (messages, damaged stretches) and the pipeline's
        (frames, scans) apart: "skipped: 4 while reading, 0 in the pipeline"."""
        read, piped = self.source.stats.errors, self.stats.errors
        return (f"skipped: {sum(read.values())} while reading, {sum(piped.values())} in the "
                "pipeline")

    def failure(self) -> str | None:
        """Why the replay failed, in one line: the error that stopped it, or no frame
        processed (with what was skipped, the first reason named); None when it did not."""
        stats = self.stats
        if stats.fatal:
            return stats.fatal
        if stats.frames:
            return None
        reasons = [*self.source.stats.errors, *stats.errors]
        if not reasons:
            return ("no frame was processed (the recording has no frames on the mapped camera "
                    "topics)")
        return f"no frame was processed ({self.skipped()}; the first: {reasons[0]})"


@dataclasses.dataclass
class OpenRecording:
    """A recording opened for replay: its source, topics checked, and the calibration
    resolved (`replay_calibration`) — all before an engine loads."""

    source: McapSource
    stereo: StereoCalibration
    lidar: LidarExtrinsics | None
    calib: Path | None  # --calib, whose file replaces the recording's own


def open_recording(path, out=None, calib=None, topics=None,
                   realtime: bool = False) -> OpenRecording:
    """Open `path` for replay into `out` (None: no output file); ConfigError when `out` is
    the input, ReplayError for a recording that cannot be read or lacks the topics."""
    from edge_depth.capture.replay import McapSource, TopicMap

    if out is not None and Path(out).exists() and Path(path).exists() \
            and os.path.samefile(out, path):
        raise ConfigError("--out", "a file other than the input recording", str(out))
    source = McapSource(path, TopicMap.from_dict(topics or {}), realtime=realtime)
    source.check_topics()
    stereo, lidar = replay_calibration(source, calib)
    return OpenRecording(source, stereo, lidar, calib)


def replay_recording(engine: Engine, recording: OpenRecording, out, profile: str = "foxglove",
                     on_output=None, watch_every: int = WATCH_EVERY) -> ReplayRun:
    """The pipeline over an opened recording with a loaded engine (its iterations and
    deadline from `engine.options`), its output to `out` (None: no output file, as `fleet
    evaluate`); the calibration watched every `watch_every` frames with LiDAR (0: off)."""
    source, realtime = recording.source, recording.source.realtime
    stop = StopFlag()
    stop.install()
    try:
        with contextlib.ExitStack() as stack:
            logger = None if out is None else stack.enter_context(open_logger(out, profile))
            o = engine.options
            pipeline = Pipeline(engine, recording.stereo, recording.lidar, logger,
                                o.iters or None, o.deadline_ms or None,
                                watch_every=watch_every)
            # with --calib given, the recording's own calibration is ignored
            if recording.calib is not None:
                source.topics = dataclasses.replace(source.topics, calibration="")
            stats = run(source, pipeline, stop, threaded=realtime, on_output=on_output,
                        pipelined=realtime and o.pipelined)
    finally:
        stop.restore()
    return ReplayRun(stats, pipeline, source, [] if logger is None else list(logger.files))


def replay_command(path, out, options: EngineOptions | None = None, calib=None, topics=None,
                   realtime: bool = False, profile: str = "foxglove") -> int:
    """`edge-depth replay IN.mcap --out OUT.mcap`: the pipeline over a recording; prints
    EPE / bad-3 per frame and overall where the recording carries ground truth. A replay
    that fails says why first; one that processed no frame leaves no output file."""
    # a missing topic, a bad --calib, an --out that cannot be written: one line before the
    # engine loads
    recording = open_recording(path, out, calib, topics, realtime)
    check_output_path(out, "--out")
    engine = Engine(options=options)
    log.info("engine: %s", engine.describe())

    def on_output(frame, output) -> None:
        m, timings = output.metrics, output.result.timings_ms
        line = f"frame {frame.seq}: " + (
            f"{output.result.iterations} it, {timings['engine']:.0f} ms" if "engine" in timings
            else f"carried from the key frame, {timings.get('propagate', 0.0):.0f} ms")
        if m is not None:
            line += f", EPE {m['epe']:.2f} px, bad-3 {m['bad3']:.1f}%"
        print(line, flush=True)

    done = replay_recording(engine, recording, out, profile, on_output)
    failure = done.failure()
    if failure is not None:
        print(f"error: {failure}", file=sys.stderr, flush=True)
    print_replay_summary(done, str(path), None if calib is None else str(calib))
    if done.stats.frames:
        print(f"wrote {files_text(done.files)}")
    else:  # the output would hold the calibration and scans only
        for file in done.files:
            file.unlink(missing_ok=True)
        print("wrote nothing: no frame was processed"
              + (f" (removed {', '.join(str(p) for p in done.files)})" if done.files else ""))
    return 1 if failure is not None else 0


def print_replay_summary(done: ReplayRun, path: str, calib: str | None) -> None:
    """The replay's closing lines: frames, scans, drops and skips (the reader's and the
    pipeline's, each listed); the LiDAR's, the watch's, the selections' and the health's
    summaries; what the input lost; throughput, latency and EPE / bad-3."""
    stats, pipeline, source = done.stats, done.pipeline, done.source
    print(f"{stats.frames} frames, {stats.scans} scans, {stats.drops} dropped; "
          f"{done.skipped()}")
    if source.stats.errors:
        print(f"skipped while reading: {dict(source.stats.errors)}")
    if stats.errors:
        print(f"skipped in the pipeline: {dict(stats.errors)}")
    print(lidar_summary(pipeline))
    if watched := watch_summary(pipeline, path, calib):
        print(watched)
    if selected := selection_summary(stats.timings):
        print(selected)
    if rated := rate_summary(pipeline.propagator):
        print(rated)
    if unhealthy := pipeline.health.summary():
        print(unhealthy)
    if source.stats.lost:
        print(f"the input is damaged: replayed the {source.stats.messages} messages that could "
              f"be read; lost: {'; '.join(source.stats.lost)}")
    lat = summarise(stats.timings)
    if lat:
        fps = stats.throughput()
        print(f"throughput {'n/a' if fps is None else f'{fps:.1f}'} frames/s; latency median / "
              "p95 ms: " + format_latency(lat))
    if stats.metrics:
        print(f"overall EPE {stats.metrics.mean('epe'):.3f} px, bad-3 "
              f"{stats.metrics.mean('bad3'):.2f}% over {len(stats.metrics)} "
              "frames with ground truth")
    if stats.instability:
        print(f"temporal instability {stats.instability.mean('instability'):.3f} px (mean "
              "|Δ output − Δ ground truth| per pixel between consecutive frames with ground "
              f"truth, {len(stats.instability)} pairs)")


def replay_calibration(source, calib):
    """The replay's calibration, resolved once before the run in this order: `--calib`, the
    recording's /edge/calibration, its CameraInfo pair with T_cam_lidar from /tf_static.
    Logs where it came from; a mapped LiDAR topic with no extrinsics is an error."""
    from edge_depth.calibration.io import load_calibration
    from edge_depth.capture.recording_calibration import recording_calibration
    from edge_depth.capture.replay import ReplayError

    if calib is not None:
        stereo, lidar = load_calibration(calib)
        origin = f"--calib {calib}"
    else:
        found = recording_calibration(source)
        if found is None:
            t = source.topics
            raise ConfigError("--calib", "a calibration file: the recording has neither "
                              f"{t.calibration or '/edge/calibration'} nor a CameraInfo pair "
                              f"on {t.left_info or '(left_info)'} and "
                              f"{t.right_info or '(right_info)'} (map them with --topics)",
                              None, str(source.path))
        stereo, lidar, origin = found
    log.info("calibration: %s", origin)
    topics = source.file_topics()
    lidar_topic = source.topics.lidar
    others = ", ".join(source.unmapped_lidar_topics())
    there = f"; LiDAR-like topics there: {others}" if others else ""
    if lidar_topic and topics is not None and lidar_topic not in topics:
        log.warning("the mapped LiDAR topic %s is not in the recording%s: running stereo "
                    "only (map lidar in --topics)", lidar_topic, there)
    elif not lidar_topic and others:
        log.warning("no LiDAR topic is mapped%s: running stereo only (map lidar in --topics)",
                    there)
    if lidar is None and lidar_topic and topics is not None and lidar_topic in topics:
        raise ReplayError(f"{source.path}: the LiDAR topic {lidar_topic} is mapped but "
                          f"{origin} has no LiDAR extrinsics: give --calib with a [lidar] "
                          "section (edge-depth calibrate lidar), or map lidar = \"\" in "
                          "--topics to run stereo only")
    return stereo, lidar


def open_sources(config, max_frames: int | None = None):
    """The configured camera and LiDAR as one source, plus the calibration (loaded first, so
    a bad calibration file stops the daemon before any device is opened)."""
    from edge_depth.calibration.io import load_calibration
    from edge_depth.capture import MergedSource
    from edge_depth.capture.sim import SimSource
    from edge_depth.sim import RigConfig
    from edge_depth.sim.motion import KINDS

    cam, lid = config.camera, config.lidar
    stereo = lidar = None
    if config.calibration.file:
        stereo, lidar = load_calibration(config.calibration.file)
        log.info("calibration: %s (the config's calibration.file)", config.calibration.file)
    elif cam.source == "oak":
        from edge_depth.calibration.oak import stereo_from_oak

        stereo = stereo_from_oak(None, tuple(cam.size))  # opens the device briefly
        log.info("calibration: the OAK's factory calibration at %dx%d (no LiDAR "
                 "extrinsics)", *cam.size)
    if lidar is None and lid.model not in ("sim", "none"):
        raise ConfigError("lidar.model", "\"none\", or LiDAR extrinsics in the calibration "
                          "(a [lidar] section: edge-depth calibrate lidar; the OAK's factory "
                          "calibration has none)", lid.model, config.path)
    sources = []
    if cam.source == "sim":
        w, h = cam.size
        moving = cam.sim_motion != "none"
        sim = SimSource(max_frames or 10**9, 1_000_000, RigConfig(width=w, height=h),
                        lidar=lid.sim_pattern, period_ms=1000.0 / cam.fps, realtime=True,
                        distinct=SIM_MOTION_FRAMES if moving else SIM_SCENES,
                        motion=KINDS[cam.sim_motion] if moving else None,
                        scan_every=lid.sim_every)
        if stereo is None:
            stereo, lidar = sim.calibration
        if lid.model == "none":
            sim = _FramesOnly(sim)
        sources.append(sim)
    else:
        from edge_depth.capture.oak import OakSource

        sources.append(OakSource(cam.size, cam.fps, cam.device_id or None))
    if lid.model not in ("sim", "none"):
        from edge_depth.capture.serial_lidar import SerialLidarSource

        sources.append(SerialLidarSource(lid.port, lid.model, lid.baudrate or None))
    if lid.model == "none":
        lidar = None
    return MergedSource(sources), stereo, lidar


class _FramesOnly:
    """A source with its LiDAR scans removed."""

    def __init__(self, source) -> None:
        self.source = source

    def close(self) -> None:
        self.source.close()

    def __iter__(self):
        return (e for e in self.source if not isinstance(e, LidarScan))


def logger_options(lg: LogConfig, profile: str | None = None) -> dict:
    """open_logger's profile, rotation and compression from the config's [log] (0 = never
    rotate); `profile` overrides log.profile."""
    options = dict(profile=profile or lg.profile, overwrite=False,  # never a recording
                   rotate_bytes=int(lg.rotate_mb * 1e6) if lg.rotate_mb else None,
                   rotate_s=lg.rotate_s or None, compression=lg.compression)
    if lg.tf_parent_frame:
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", lg.tf_parent_xyz_rpy[3:], degrees=True).as_matrix()
        T[:3, 3] = lg.tf_parent_xyz_rpy[:3]
        options.update(parent_frame=lg.tf_parent_frame, T_parent_camera=T)
    if options["profile"] == "ros2":
        options.update(prefix=lg.ros2_prefix)
    return options


def run_command(config_path, out=None, live: tuple[str, int] | None = None,
                max_frames: int | None = None, profile: str | None = None) -> int:
    """`edge-depth run --config robot.toml`: the on-robot daemon."""
    from edge_depth.config import load_robot_config, sync_mode
    from edge_depth.mcap_log import RAW_TOPICS

    config = load_robot_config(config_path)
    if out is None:
        check_output_path(config.log.out, "log.out", config.path)
    else:
        check_output_path(out, "--out")
    mode = sync_mode(config)
    e = config.engine
    try:
        engine = Engine(options=e)
        source, stereo, lidar = open_sources(config, max_frames)
        engine.plan_for(tuple(stereo.image_size))  # a camera the bundle cannot run: now
    except ConfigError as exc:
        raise exc.naming(config.path, "engine") from None
    lg = config.log
    topics = (RAW_TOPICS if lg.raw else ()) + lg.results
    stop = StopFlag()
    stop.install()
    started = time.monotonic()
    try:
        options = logger_options(lg, profile)
        if live is not None:
            options.update(live=True, live_host=live[0], live_port=live[1])
        with open_logger(out or lg.out, topics=topics, **options) as logger:
            pipeline = Pipeline(engine, stereo, lidar, logger, e.iters or None,
                                e.deadline_ms or None,
                                SyncConfig(mode, config.sync.window_ms,
                                           max_wait_ms=config.sync.max_wait_ms,
                                           deskew=config.sync.deskew),
                                log_raw=lg.raw, watch_every=config.calibration.watch_every)
            print(f"edge-depth run: {config.camera.source} camera, LiDAR {config.lidar.model}"
                  f" (sync {mode}{' by the model' if config.sync.mode == 'auto' else ''}),"
                  f" {engine.describe()} engine, logging to {logger.files[0]}"
                  + (f" (live on ws://{live[0]}:{logger.server.port})" if live else ""),
                  flush=True)
            stats = run(source, pipeline, stop, threaded=True, queue_size=lg.queue,
                        max_frames=max_frames, pipelined=e.pipelined)
    finally:
        stop.restore()
    print_run_summary(stats, pipeline, logger, config, time.monotonic() - started)
    if stats.fatal:
        print(f"error: {stats.fatal}", file=sys.stderr)
        return 1
    if stats.source_failed and not stop.is_set():
        print("a source failed (see errors above): exiting 1 so a supervisor restarts us",
              file=sys.stderr)
        return 1
    return 0


def print_run_summary(stats, pipeline: Pipeline, logger, config, elapsed: float) -> None:
    """The daemon's closing lines: frames, scans and drops; the LiDAR's, the calibration
    watch's, the selections' and the health's summaries; throughput and latency; the files."""
    lat = summarise(stats.timings)
    print(f"{stats.frames} frames in {elapsed:.1f} s, {stats.scans} scans, {stats.drops} "
          f"dropped, errors {dict(stats.errors) or 'none'}")
    print(lidar_summary(pipeline))
    if watched := watch_summary(pipeline, str(logger.files[0]) if config.log.raw else None,
                                config.calibration.file or None):
        print(watched)
    if selected := selection_summary(stats.timings):
        print(selected)
    if rated := rate_summary(pipeline.propagator):
        print(rated)
    if unhealthy := pipeline.health.summary():
        print(unhealthy)
    if lat:
        fps = stats.throughput()
        print(f"throughput {'n/a' if fps is None else f'{fps:.1f}'} frames/s"
              f"{' (pipelined)' if config.engine.pipelined else ''}; latency (prepared to "
              f"logged) median {lat['frame']['median']:.0f} ms, p95 "
              f"{lat['frame']['p95']:.0f} ms")
        print("latency median / p95 ms: " + format_latency(lat))
    print(f"wrote {files_text(logger.files)}")


def record_command(config_path, out, max_frames: int | None = None,
                   profile: str | None = None) -> int:
    """`edge-depth record --config robot.toml --out rec.mcap`: the live sensors, rectified
    images and raw points, with the calibration, for replay and training later."""
    from edge_depth.config import load_robot_config
    from edge_depth.mcap_log import RAW_TOPICS

    config = load_robot_config(config_path)
    check_output_path(out, "--out")
    try:
        source, stereo, lidar = open_sources(config, max_frames)
    except ConfigError as exc:
        raise exc.naming(config.path, "camera") from None
    stop = StopFlag()
    stop.install()
    try:
        with open_logger(out, topics=RAW_TOPICS,
                         **logger_options(config.log, profile)) as logger:
            pipeline = Pipeline(None, stereo, lidar, logger)  # no engine: the recorder
            stats = run(source, pipeline, stop, threaded=True, max_frames=max_frames)
    finally:
        stop.restore()
    print(f"recorded {stats.frames} frames ({stats.drops} dropped) and {stats.scans} scans to "
          f"{files_text(logger.files)}; errors {dict(stats.errors) or 'none'}")
    if stats.fatal:
        print(f"error: {stats.fatal}", file=sys.stderr)
        return 1
    return 0


def files_text(files: list, shown: int = 4) -> str:
    """A run's files for its closing line: all of a few, or how many and the first and last
    (a daemon that rotated for days has thousands)."""
    if len(files) <= shown:
        return ", ".join(str(p) for p in files)
    return f"{len(files)} files, {files[0]} … {files[-1]}"
