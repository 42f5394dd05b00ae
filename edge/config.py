"""The robot's configuration file (TOML) for `edge-depth run` and `edge-depth record`.

    [camera]                    # source: "oak" | "sim" (the synthetic rig, for dry runs)
    source = "oak"
    size = [640, 400]
    fps = 30.0
    device_id = ""              # "" = the first OAK found
    sim_motion = "none"         # source "sim": "none" (a new scene a frame) | "still" |
                                # "forward" | "turn" | "mover": one world in motion
                                # (edge.sim.motion), SIM_MOTION_FRAMES of it played
                                # forward and back

    [lidar]                     # model: "ld06" | "ld19" | "rplidar-a1" | "rplidar-a2" |
    model = "ld06"              #        "sim" (with camera.source = "sim") | "none"
    port = "/dev/ttyUSB0"       # anything serial_for_url opens
    baudrate = 0                # 0 = the model's default
    sim_pattern = "beams16"     # model "sim": "beams16" | "beams32" | "beams64" | "planar"
                                # (one scan line, as an LD06's)
    sim_every = 1               # model "sim": a scan with every this many camera frames

    [calibration]
    file = "calib.toml"         # stereo + [lidar] T_cam_lidar; "" = the OAK's factory
                                # calibration, which has no LiDAR extrinsics (then a
                                # LiDAR model other than "none" is an error)
    watch_every = 13            # the LiDAR-camera rotation and clock watched (/diagnostics):
                                # one sample's budget in this many frames with LiDAR; 0 = off

    [sync]
    mode = "auto"               # "nearest" (spinning 3-D) | "accumulate" (2-D scanner) |
                                # "auto": by lidar.model (sim: nearest; the others: accumulate)
    window_ms = 100.0
    max_wait_ms = 200.0         # a frame waits this long for the scans that cover it
    deskew = true               # each point moved by the camera's turn (from the frames)
                                # between its own time and the frame's

    [engine]                    # every key of edge.runtime.options.EngineOptions, with its
    iters = 4                   # default and doc (docs/configuration.md's table is made
    deadline_ms = 80.0          # from it)

    [log]
    out = "logs/depth.mcap"
    raw = true                  # also log the rectified images and the raw points
    rotate_mb = 1024.0          # 0 = never
    rotate_s = 0.0              # 0 = never
    compression = "lz4"         # "lz4" | "zstd" | "none"
    queue = 2                   # frames waiting for inference before the oldest is dropped

Every section and key is optional except where the source needs it; unknown keys and wrong
types are errors that name the file and the key.
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from edge_depth.calibration.tomlfile import TomlReadError, read_toml
from edge_depth.calibration_watch import EVERY as WATCH_EVERY
from edge_depth.errors import ConfigError
from edge_depth.runtime.options import REMOVED, SCALE_WORDS, EngineOptions
from edge_depth.topics import RESULT_TOPICS

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CameraConfig:
    source: str = "oak"
    size: tuple[int, int] = (640, 400)
    fps: float = 30.0
    device_id: str = ""
    sim_motion: str = "none"  # edge.sim.motion.KINDS' names, or "none"


@dataclass(frozen=True)
class LidarConfig:
    model: str = "ld06"
    port: str = "/dev/ttyUSB0"
    baudrate: int = 0
    sim_pattern: str = "beams16"  # edge.sim.lidar.PATTERNS' names
    sim_every: int = 1


@dataclass(frozen=True)
class CalibrationConfig:
    file: str = ""
    watch_every: int = WATCH_EVERY


@dataclass(frozen=True)
class SyncSection:
    mode: str = "auto"
    window_ms: float = 100.0
    max_wait_ms: float = 200.0  # how long a frame waits for the scans that cover it
    deskew: bool = True  # the points moved by the camera's turn (edge.camera_turn.deskew)


# sync.mode "auto": the sim LiDAR is a spinning 3-D one with a revolution per frame; the
# serial ones (LD06/LD19, RPLIDAR) are 2-D scanners slower than the camera, whose points
# are gathered over the window. Accumulating a spinning LiDAR's revolutions instead made
# every frame wait for the next one (~20 ms on the sim robot) and project three of them.
SYNC_MODE_BY_LIDAR = {"sim": "nearest"}


def sync_mode(config: RobotConfig) -> str:
    """The sync mode the daemon runs: the config's, or for "auto" the LiDAR model's."""
    if config.sync.mode != "auto":
        return config.sync.mode
    return SYNC_MODE_BY_LIDAR.get(config.lidar.model, "accumulate")


@dataclass(frozen=True)
class LogConfig:
    out: str = "logs/depth.mcap"
    raw: bool = True
    rotate_mb: float = 1024.0
    rotate_s: float = 0.0
    compression: str = "lz4"
    queue: int = 2
    profile: str = "foxglove"  # or "ros2": ROS 2 messages, for ros2 bag play
    ros2_prefix: str = "/"     # the ros2 profile's topic namespace
    tf_parent_frame: str = ""  # the transforms: camera_left under this frame (e.g. base_link)
    tf_parent_xyz_rpy: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # m, m, m, deg x3
    # the result topics written (docs/configuration.md gives each one's cost)
    results: tuple[str, ...] = RESULT_TOPICS


@dataclass(frozen=True)
class RobotConfig:
    camera: CameraConfig = field(default_factory=CameraConfig)
    lidar: LidarConfig = field(default_factory=LidarConfig)
    calibration: CalibrationConfig = field(default_factory=CalibrationConfig)
    sync: SyncSection = field(default_factory=SyncSection)
    engine: EngineOptions = field(default_factory=EngineOptions)
    log: LogConfig = field(default_factory=LogConfig)
    path: str = "<defaults>"


CHOICES = {
    ("camera", "source"): ("oak", "sim"),
    ("lidar", "model"): ("ld06", "ld19", "rplidar-a1", "rplidar-a2", "sim", "none"),
    ("lidar", "sim_pattern"): ("beams16", "beams32", "beams64", "planar"),
    ("camera", "sim_motion"): ("none", "still", "forward", "turn", "mover"),
    ("sync", "mode"): ("auto", "nearest", "accumulate"),
    ("log", "compression"): ("lz4", "zstd", "none"),
    ("log", "profile"): ("foxglove", "ros2"),
}
# accepted ranges, inclusive (NaN and inf are outside every one); OFF_OR: 0 also accepted
RANGES = {
    ("camera", "fps"): (0.5, 1000.0),
    ("camera", "size"): (64, 16384),  # each side; below 64 the network's 1/4-resolution
    #                                   features and StereoBM's window have nothing to match
    ("lidar", "baudrate"): (0, 10_000_000),
    ("lidar", "sim_every"): (1, 1000),
    ("sync", "window_ms"): (1.0, 10_000.0),
    ("sync", "max_wait_ms"): (0.0, 10_000.0),
    ("log", "rotate_mb"): (1.0, 1e7),
    ("log", "rotate_s"): (1.0, 1e8),
    ("log", "queue"): (1, 1000),
    ("calibration", "watch_every"): (1, 100_000),
    ("log", "tf_parent_xyz_rpy"): (-1000.0, 1000.0),  # each: metres, or degrees
}
# the engine's, from its options' own
CHOICES.update({("engine", f.name): f.metadata["choices"] for f in fields(EngineOptions)
                if f.metadata["choices"]})
RANGES.update({("engine", f.name): f.metadata["bounds"] for f in fields(EngineOptions)
               if f.metadata["bounds"]})
OFF_OR = {("log", "rotate_mb"), ("log", "rotate_s"), ("calibration", "watch_every")}


def _check_range(path: str, name: str, key: str, value) -> None:
    if (name, key) not in RANGES or isinstance(value, str):  # STRING_OR_NUMBER's words
        return
    lo, hi = RANGES[(name, key)]
    values = value if isinstance(value, tuple) else (value,)
    if all(lo <= v <= hi for v in values) or ((name, key) in OFF_OR and value == 0):
        return
    off = " (or 0: off)" if (name, key) in OFF_OR else ""
    raise ConfigError(f"{name}.{key}", f"{lo}–{hi}{off}", value, path)


# a number of the given type, or one of these strings
STRING_OR_NUMBER = {"engine.scale": (SCALE_WORDS, 0.0)}


def _convert(path: str, key: str, value, default):
    words, number = STRING_OR_NUMBER.get(key, ((), None))
    if value in words:
        return value
    if number is not None:
        default = number
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif isinstance(default, tuple) and isinstance(default[0], str):  # a subset of names
        ok = isinstance(value, list) and all(isinstance(v, str) for v in value)
        unknown = sorted(set(value) - set(default)) if ok else []
        if unknown:
            raise ConfigError(key, f"a list of {', '.join(default)}", value, path)
        value = tuple(value) if ok else value
    elif isinstance(default, tuple) and isinstance(default[0], float):  # finite numbers
        ok = (isinstance(value, list) and len(value) == len(default)
              and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                      and math.isfinite(v) for v in value))
        value = tuple(float(v) for v in value) if ok else value
    elif isinstance(default, tuple):
        ok = (isinstance(value, list) and len(value) == len(default)
              and all(isinstance(v, int) and v > 0 for v in value))
        value = tuple(value) if ok else value
    else:
        ok = isinstance(value, str)
    if not ok:
        either = "".join(f'"{w}" or ' for w in words)
        raise ConfigError(key, f"{either}{type(default).__name__} like {default!r}", value,
                          path)
    return value


PATH_KEYS = (("calibration", "file"), ("engine", "bundle"), ("log", "out"))


def _resolve_paths(sections: dict, base: Path) -> None:
    """Relative paths in a config file are relative to that file, not to the working
    directory the daemon happens to start in (systemd starts it in /)."""
    from dataclasses import replace

    for name, key in PATH_KEYS:
        value = getattr(sections[name], key)
        if value and not Path(value).expanduser().is_absolute():
            sections[name] = replace(sections[name], **{key: str(base / value)})


def _log_out(log: LogConfig, path: str) -> LogConfig:
    """`log.out` names a file to write (rotated as NAME_0001.mcap, ...): a directory gets
    depth.mcap inside it; empty and device paths are refused."""
    from dataclasses import replace

    out = Path(log.out).expanduser()
    if not log.out.strip():
        raise ConfigError("log.out", "a file path for the recordings", log.out, path)
    if str(out).startswith("/dev/") or (out.exists() and not (out.is_file() or out.is_dir())):
        raise ConfigError("log.out", "a regular file path (not a device: to keep nothing, "
                          "set log.raw = false and point log.out at a scratch folder)",
                          log.out, path)
    if out.is_dir() or log.out.endswith("/"):
        log_ = replace(log, out=str(out / "depth.mcap"))
        _log.warning("%s: log.out = %r is a directory: recordings go to %s (set log.out to a "
                     "file name to choose it)", path, log.out, log_.out)
        return log_
    return log


def check_output_path(path: str | Path, key: str, source: str | None = None,
                      folder: bool = False) -> None:
    """Refuse an output that cannot be written before anything loads, naming `key` (and the
    config file `source` it came from): a file `path` (or, `folder`, the folder itself)
    whose folder cannot be created or written, or a file path that is a folder. The folder
    is created as the writers would, and a file made in it and removed: the one test that
    holds for read-only file systems, permissions and root alike."""
    path = Path(path).expanduser()
    where = path if folder else path.parent
    if not folder and os.path.isdir(path):
        raise ConfigError(key, "a file to write, not a folder", str(path), source)
    try:
        where.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=where):
            pass
    except OSError as exc:
        # the nearest part of the path that is there (os.path: False where it cannot look)
        existing = next((p for p in (where, *where.parents) if os.path.exists(p)), where)
        why = (f"{existing} is a file, not a folder" if not os.path.isdir(existing)
               else f"{where}: {exc.strerror or type(exc).__name__}")
        what = ("a folder that can be created and written" if folder
                else "a path in a folder that can be written")
        raise ConfigError(key, f"{what} ({why})", str(path), source) from None


def _warn_threads(engine: EngineOptions, path: str) -> None:
    cores = os.cpu_count() or 1
    if engine.threads > cores:
        _log.warning("%s: engine.threads = %d on a machine with %d cores: the engine's threads "
                     "will wait for each other (set engine.threads <= %d)", path,
                     engine.threads, cores, cores)


def load_robot_config(path: str | Path) -> RobotConfig:
    path = str(path)
    try:
        data = read_toml(path)
    except FileNotFoundError:
        raise ConfigError("file", "an existing TOML file", path) from None
    except IsADirectoryError:
        raise ConfigError("file", "a TOML file, not a directory", path) from None
    except TomlReadError as exc:
        raise ConfigError("file", "a robot config (TOML)", str(exc), path) from None
    sections = {f.name: f for f in fields(RobotConfig) if f.name != "path"}
    unknown = set(data) - set(sections)
    if unknown:
        raise ConfigError(sorted(unknown)[0], f"one of the sections {sorted(sections)}",
                          "unknown section", path)
    built = {}
    for name, section_field in sections.items():
        cls: Any = section_field.default_factory  # each section's dataclass
        table = data.get(name, {})
        if not isinstance(table, dict):
            raise ConfigError(name, "a table", table, path)
        defaults = cls()
        values = {}
        for key, value in table.items():
            if name == "engine" and key in REMOVED:
                raise ConfigError(f"{name}.{key}", "a current key (this one was removed: "
                                  f"{REMOVED[key]})", key, path)
            if key not in {f.name for f in fields(cls)}:
                raise ConfigError(f"{name}.{key}", f"one of {[f.name for f in fields(cls)]}",
                                  "unknown key", path)
            value = _convert(path, f"{name}.{key}", value, getattr(defaults, key))
            if (name, key) in CHOICES and value not in CHOICES[(name, key)]:
                raise ConfigError(f"{name}.{key}", f"one of {CHOICES[(name, key)]}", value,
                                  path)
            _check_range(path, name, key, value)
            values[key] = value
        try:
            built[name] = cls(**values)
        except ConfigError as exc:  # a section's own checks (EngineOptions')
            raise exc.naming(path, name) from None
    _resolve_paths(built, Path(path).parent)
    built["log"] = _log_out(built["log"], path)
    _warn_threads(built["engine"], path)
    config = RobotConfig(**built, path=path)
    if config.lidar.sim_every > 1 and config.camera.sim_motion == "none":
        raise ConfigError("lidar.sim_every", "1 unless camera.sim_motion is a moving world "
                          "(each frame is a scene of its own: a scan from another frame "
                          "would be another scene's)", config.lidar.sim_every, path)
    if config.lidar.model == "sim" and config.camera.source != "sim":
        raise ConfigError("lidar.model", "'sim' only with camera.source = 'sim'", "sim", path)
    if config.camera.source == "sim" and config.lidar.model not in ("sim", "none"):
        raise ConfigError("lidar.model", "'sim' or 'none' with camera.source = 'sim'",
                          config.lidar.model, path)
    return config
