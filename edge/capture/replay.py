"""Replay an MCAP recording as a source: ours (Foxglove protobuf schemas) or a ROS 2 bag.

Events, in file order: `StereoFrame` (left and right paired by stamp), `LidarScan`,
`Calibration` (from our /edge/calibration topic, or built from a pair of CameraInfo /
CameraCalibration messages of rectified cameras) and `GroundTruth` (/sim/gt_disparity).

The file is read front to back without its summary, so a recording cut off by a crash
replays up to its last complete chunk; a warning says how many messages and seconds of
recording that was. Topics are
mapped by role (`TopicMap`); a mapped topic the file lacks is an error listing the file's
topics.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from edge_depth.capture import Source
from edge_depth.capture.decode import (
    camera_info_dict,
    decode_message,
    frame_id,
    message_decoders,
    static_transforms,
    toml_text,
)
from edge_depth.capture.message_events import MessageEvents
from edge_depth.errors import EdgeError
from edge_depth.topics import TOPICS

log = logging.getLogger(__name__)


class ReplayError(EdgeError):
    """The recording cannot be replayed (not MCAP, or a mapped topic is missing)."""


@dataclass(frozen=True)
class TopicMap:
    """Which topic plays which role. Defaults: this project's own topics. `rectified`: the
    mapped images are already rectified (ours are); false for raw camera images, which the
    pipeline then rectifies with the calibration."""

    left: str = TOPICS["left"]
    right: str = TOPICS["right"]
    lidar: str = TOPICS["lidar"]
    left_info: str = TOPICS["left_calibration"]
    right_info: str = TOPICS["right_calibration"]
    calibration: str = TOPICS["calibration_file"]
    gt: str = TOPICS["gt_disparity"]
    tf_static: str = "/tf_static"
    rectified: bool = True

    @classmethod
    def ros2_profile(cls, prefix: str = "/") -> TopicMap:
        """The topics our ros2 profile writes (`edge.ros2_log`)."""
        from edge_depth.topics import ros2_topic

        return cls(**{role: ros2_topic(key, prefix) for role, key in (
            ("left", "left"), ("right", "right"), ("lidar", "lidar"),
            ("left_info", "left_calibration"), ("right_info", "right_calibration"),
            ("calibration", "calibration_file"), ("gt", "gt_disparity"),
            ("tf_static", "tf_static"))})

    @classmethod
    def from_dict(cls, data: dict) -> TopicMap:
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ReplayError(f"topic map: unknown roles {sorted(unknown)}; "
                              f"known: {sorted(cls.__dataclass_fields__)}")
        topics = cls(**data)
        if topics.left == topics.right:
            raise ReplayError(f"topic map: left and right are the same topic {topics.left!r}: "
                              "no frame could pair; map the right camera's own topic")
        return topics


@dataclass
class RecordingCalibration:
    """What a recording's first messages say about its calibration: our TOML, the two
    camera infos (K, D, R, P, size, frame_id), the static transforms (parent, child, 4×4)
    and the LiDAR's frame id."""

    toml: str | None = None
    infos: dict[str, dict] = field(default_factory=dict)
    transforms: list[tuple[str, str, np.ndarray]] = field(default_factory=list)
    lidar_frame: str | None = None
    # what kept the scanned messages from being read: damaged or cut-off data (`lost`), a
    # calibration message that does not decode (`unreadable`: why)
    lost: list[str] = field(default_factory=list)
    unreadable: str | None = None


@dataclass
class ReplayStats:
    messages: int = 0
    frames: int = 0
    scans: int = 0
    bytes_read: int = 0
    truncated: bool = False
    errors: Counter = field(default_factory=Counter)
    # what the input lost, one line each (a damaged chunk, a cut-off end, messages on a
    # channel no intact record declares); empty for an intact recording
    lost: list[str] = field(default_factory=list)


def damage_text(damage) -> str:
    """A damaged stretch of a file (`mcap_tolerant.Damage`) in words: where, why, how much."""
    lost = "?" if damage.messages_lost is None else damage.messages_lost
    return f"damaged data at byte {damage.offset} ({damage.reason}, {lost} messages lost)"


def cut_off_text(path: Path, offset: int) -> str:
    size = path.stat().st_size
    return f"cut off at byte {offset} of {size} ({size - offset} bytes unreadable)"


def bag_files(path: Path) -> list[Path]:
    """The MCAP files to replay: `path` itself, or a ROS 2 bag directory's, in the order its
    metadata.yaml lists them (else by name)."""
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise ReplayError(f"{path}: no such file or bag directory")
    files = sorted(path.glob("*.mcap"))
    metadata = path / "metadata.yaml"
    if metadata.is_file():
        import yaml

        try:
            info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
            listed = [path / name for name in info.get("relative_file_paths", [])]
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            raise ReplayError(f"{metadata}: not a rosbag2 metadata file ({exc})") from None
        files = [f for f in listed if f.suffix == ".mcap" and f.is_file()] or files
    if not files:
        raise ReplayError(f"{path}: a directory without .mcap files")
    return files


# -- the source ------------------------------------------------------------------------------
class McapSource(Source):
    """Iterate events of a recording. `realtime=True` paces them by their log times."""

    def __init__(self, path: str | Path, topics: TopicMap | None = None,
                 realtime: bool = False, pair_window_ns: int = 5_000_000) -> None:
        self.paths = bag_files(Path(path))  # a file, or a ROS 2 bag directory's files
        self.path = self.paths[0]
        self.topics = topics or self._default_topics()
        self.realtime = realtime
        self.pair_window_ns = pair_window_ns
        self.stats = ReplayStats()
        self.seen_topics: set[str] = set()
        super().__init__()
        self._pace_origin: tuple[int, float] | None = None  # (log time, monotonic s)

    def counters(self) -> dict:
        s = self.stats
        return dict(messages=s.messages, frames=s.frames, scans=s.scans,
                    truncated=s.truncated, errors=dict(s.errors))

    def _default_topics(self) -> TopicMap:
        """Ours, in whichever profile the file was written (its header says)."""
        from mcap.reader import make_reader

        try:
            with open(self.path, "rb") as f:
                profile = make_reader(f).get_header().profile
        except Exception:  # noqa: BLE001 - not MCAP: said when it is read
            profile = ""
        return TopicMap.ros2_profile() if profile == "ros2" else TopicMap()

    def file_topics(self) -> set[str] | None:
        """Topics listed in the summary, or None for a file without one."""
        schemas = self.file_schemas()
        return None if schemas is None else set(schemas)

    def file_schemas(self) -> dict[str, str] | None:
        """{topic: schema name} from the summary, or None for a file without one."""
        from mcap.reader import make_reader

        out: dict[str, str] = {}
        for path in self.paths:
            with open(path, "rb") as f:
                try:
                    summary = make_reader(f).get_summary()
                except Exception:  # noqa: BLE001 - no or broken summary: a cut-off file
                    return None
            if summary is None:
                return None
            out.update({c.topic: (summary.schemas[c.schema_id].name
                                  if c.schema_id in summary.schemas else "")
                        for c in summary.channels.values()})
        return out

    def unmapped_lidar_topics(self) -> list[str]:
        """Point-cloud or laser-scan topics in the file that are not the mapped LiDAR."""
        schemas = self.file_schemas() or {}
        kinds = ("PointCloud2", "LaserScan", "foxglove.PointCloud")
        return sorted(topic for topic, name in schemas.items()
                      if name.split("/")[-1] in kinds and topic != self.topics.lidar
                      and topic not in (TOPICS["points"],))  # our own depth cloud

    def scan_calibration(self, max_messages: int = 5000) -> RecordingCalibration:
        """Read the recording's first messages for its calibration: /edge/calibration (ours,
        logged first), the mapped camera infos, /tf_static and the LiDAR's frame id; with
        what kept the calibration from being read: damage before the camera infos were
        complete (`lost`), a calibration message that does not decode (`unreadable`)."""
        from edge_depth.capture.mcap_tolerant import ReadReport, iter_messages

        t, found, report = self.topics, RecordingCalibration(), ReadReport()
        wanted = {t.calibration, t.left_info, t.right_info, t.tf_static, t.lidar} - {""}
        factories = message_decoders()
        decoders: dict = {}
        damage_before: int | None = None  # damage records before the camera infos were whole
        try:
            messages = iter_messages(self.path, report)
            for count, (schema, channel, message) in enumerate(messages):
                if count >= max_messages:
                    break
                if channel.topic not in wanted:
                    continue
                try:
                    msg = decode_message(schema, channel, message, factories, decoders)
                    if channel.topic == t.calibration:
                        found.toml = toml_text(msg)
                        break  # ours is complete: nothing else is needed
                    if self._found(found, channel.topic, msg):
                        break
                except Exception as exc:  # noqa: BLE001 - counted like the replay's own
                    self.stats.errors[f"{channel.topic}: decode {type(exc).__name__}"] += 1
                    if channel.topic == t.calibration and found.unreadable is None:
                        found.unreadable = f"{type(exc).__name__}: {exc}"[:200]
                if len(found.infos) == 2 and damage_before is None:
                    damage_before = len(report.damage)
        except ValueError as exc:  # not MCAP at all
            raise ReplayError(f"{self.path}: not a readable MCAP file ({exc})") from None
        found.lost = [damage_text(d) for d in report.damage[:damage_before]]
        if report.truncated_at is not None and damage_before is None:
            found.lost.append(cut_off_text(self.path, report.truncated_at))
        return found

    def _found(self, found: RecordingCalibration, topic: str, msg) -> bool:
        """Adds a transform, LiDAR frame or camera info to `found`; True once it has all."""
        t = self.topics
        if topic == t.tf_static:
            found.transforms.extend(static_transforms(msg))
        elif topic == t.lidar:
            found.lidar_frame = found.lidar_frame or frame_id(msg)
        elif topic not in [i["topic"] for i in found.infos.values()]:
            side = "left" if topic == t.left_info else "right"
            found.infos[side] = dict(camera_info_dict(msg), topic=topic)
        return len(found.infos) == 2 and bool(found.transforms) and bool(found.lidar_frame)

    def check_topics(self, required: tuple[str, ...] = ("left", "right")) -> None:
        topics = self.file_topics()
        if topics is None:
            return
        missing = [getattr(self.topics, r) for r in required
                   if getattr(self.topics, r) not in topics]
        if missing:
            raise ReplayError(f"{self.path}: no topic {', '.join(missing)} (mapped as "
                              f"{', '.join(required)}); the file has: "
                              f"{', '.join(sorted(topics)) or 'no topics'}")

    def _file_messages(self):
        """(schema, channel, message) past damaged chunks (`edge.capture.mcap_tolerant`):
        each is counted, named and warned about as it is found; a cut-off end is too."""

        for path in self.paths:
            yield from self._one_file(path)

    def _one_file(self, path: Path):
        from edge_depth.capture.mcap_tolerant import ReadReport, iter_messages

        report, seen = ReadReport(), 0
        first_time = last_time = None
        try:
            for item in iter_messages(path, report):
                for d in report.damage[seen:]:
                    self._damaged(d, path)
                seen = len(report.damage)
                first_time = item[2].log_time if first_time is None else first_time
                last_time = item[2].log_time
                yield item
        except ValueError as exc:  # not MCAP at all
            raise ReplayError(f"{path}: not a readable MCAP file ({exc})") from None
        for d in report.damage[seen:]:
            self._damaged(d, path)
        if report.duplicates:
            self.stats.errors["chunk stored twice (read once)"] += len(report.duplicates)
            log.warning("%s: %d chunk(s) repeat an earlier chunk byte for byte (the first at "
                        "byte %d repeats byte %d): each was read once", path,
                        len(report.duplicates), *report.duplicates[0])
        if report.unknown_channel:
            self.stats.errors["message on a channel no intact record declares"] += \
                report.unknown_channel
            self._lost(path, f"{report.unknown_channel} messages on a channel no intact "
                             "record declares")
        if missing := report.unaccounted():  # whole chunks cut out of the file
            self.stats.errors["message the summary counts but no chunk holds"] += missing
            self._lost(path, f"{missing} messages the summary counts are in no readable chunk")
            log.warning("%s: the summary counts %d messages that no readable chunk holds "
                        "(chunks cut out of the file)", path, missing)
        if report.truncated_at is not None:
            self.stats.truncated = True
            self._lost(path, cut_off_text(path, report.truncated_at))
            self.stats.bytes_read = report.truncated_at
            span = 0.0 if first_time is None else (last_time - first_time) / 1e9
            log.warning("%s is cut off at byte %d: replayed the %d messages of its complete "
                        "chunks, %.2f s of recording; the rest of its %.1f MB is unreadable",
                        path, report.truncated_at, self.stats.messages, span,
                        path.stat().st_size / 1e6)

    def _damaged(self, damage, path: Path) -> None:
        self.stats.errors[damage_text(damage)] += 1
        self._lost(path, damage_text(damage))
        log.warning("%s: damaged data at byte %d (%s): skipped, reading on at the next "
                    "intact chunk", path, damage.offset, damage.reason)

    def _lost(self, path: Path, what: str) -> None:
        """One line of `stats.lost`; a bag's file is named where the bag has several."""
        self.stats.lost.append(f"{path.name}: {what}" if len(self.paths) > 1 else what)

    def _pace(self, log_time: int) -> None:
        """realtime: sleep until the message's log time; a jump of over a minute (a clock
        step, or a corrupted time) restarts the pacing instead of sleeping through it."""
        now = time.monotonic()
        if self._pace_origin is None:
            self._pace_origin = (log_time, now)
        lag = (log_time - self._pace_origin[0]) / 1e9 - (now - self._pace_origin[1])
        if abs(lag) > 60:
            self.stats.errors["log time jump over 60 s (pacing restarted)"] += 1
            self._pace_origin = (log_time, now)
        elif lag > 0:
            self._stop.wait(lag)

    def __iter__(self):
        self.check_topics()
        t = self.topics
        wanted = {t.left, t.right, t.lidar, t.left_info, t.right_info, t.calibration, t.gt}
        wanted.discard("")
        events = MessageEvents(t, self.stats, str(self.path), self.pair_window_ns)
        self._pace_origin = None
        factories = message_decoders()
        decoders: dict[int, object] = {}
        for schema, channel, message in self._file_messages():
            if self._stop.is_set():
                return  # closed by the caller: no end-of-file checks
            topic = channel.topic
            self.seen_topics.add(topic)
            self.stats.messages += 1
            if topic not in wanted:
                continue
            try:
                decoded = decode_message(schema, channel, message, factories, decoders)
            except Exception as exc:  # noqa: BLE001 - a message that does not decode
                self.stats.errors[f"{topic}: decode {type(exc).__name__}"] += 1
                continue
            if self.realtime:
                self._pace(message.log_time)
            try:
                yield from events.events(topic, decoded, int(message.log_time))
            except (ValueError, TypeError, AttributeError, IndexError, OverflowError) as exc:
                self.stats.errors[f"{topic}: {exc}"[:120]] += 1
                log.warning("%s: skipped a message on %s: %s", self.path, topic, exc)
        if self._stop.is_set():
            return
        events.finish()  # half pairs the file ended on
        if not self.stats.truncated:
            self.stats.bytes_read = sum(p.stat().st_size for p in self.paths)
        if self.stats.frames == 0 and t.left not in self.seen_topics:
            raise ReplayError(f"{self.path}: no messages on {t.left} (left); the file has: "
                              f"{', '.join(sorted(self.seen_topics)) or 'no messages'}")
