"""The `edge-depth` command. Each subcommand maps its arguments into configs and calls a module."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from edge_depth.arguments import (
    load_topic_map,
    parse_host_port,
    parse_size,
    positive_int,
    share,
)
from edge_depth.calibration.errors import CalibrationError
from edge_depth.errors import EdgeError
from edge_depth.runtime.options import add_engine_arguments, options_from_args

FLEET_THREADS = 1  # fleet: one engine thread per worker, as many workers as cores


def _view_spread(text: str) -> float:
    """0 (one response for both cameras) to 4 (gain ±48 %): beyond, a view's gain could reach
    zero."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number from 0 to 4, got {text!r}") from None
    if not 0.0 <= value <= 4.0:
        raise argparse.ArgumentTypeError(f"expected a number from 0 to 4, got {text!r}")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors on one line and exits with status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("edge-depth")
    except PackageNotFoundError:
        return "unknown (not installed)"


def configure_logging(verbose: bool = False, quiet: bool = False) -> None:
    """stdlib logging on stderr with timestamps and levels: INFO by default, DEBUG with -v,
    WARNING with -q."""
    import logging

    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    # a handler only where none is installed yet (an embedding program's or pytest's stays)
    logging.basicConfig(stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(level)


# the jobs around the robot: `edge-depth NAME ARGS...` runs tools/NAME.py's main(ARGS);
# the ones that need torch or onnx say so in one line when the `train` extra is missing
TOOL_COMMANDS = {
    "train": ("tools.train", "train a checkpoint (supervised or self-supervised)"),
    "evaluate": ("tools.evaluate", "score methods on scene folders against ground truth"),
    "export": ("tools.export", "export a checkpoint to an ONNX bundle"),
    "quantize": ("tools.quantize", "int8-quantize a bundle, calibrated on frames"),
    "bench": ("tools.bench", "benchmark the stages, the engine and SGBM"),
    "real-pairs": ("tools.real_pairs", "unpack the real evaluation pair (opencv-doc)"),
    "adapt": ("tools.adapt", "fine-tune on the robot's recordings into a checked int8 bundle"),
}
TRAIN_MODULES = ("torch", "onnx", "onnxscript", "tqdm", "matplotlib")
OAK_EXTRA_HINT = "pip install 'edge-depth[oak]'"
TRAIN_EXTRA_HINT = ("pip install 'edge-depth[train]' (for the CPU build of torch first: pip "
                    "install torch --index-url https://download.pytorch.org/whl/cpu)")


def run_tool(name: str, argv: list[str]) -> int:
    import importlib

    module_name = TOOL_COMMANDS[name][0]
    program, sys.argv[0] = sys.argv[0], f"edge-depth {name}"  # the tool's usage lines
    try:
        module = importlib.import_module(f"edge_depth.{module_name}")
        return int(module.main(argv) or 0)
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] not in TRAIN_MODULES:
            raise
        print(f"edge-depth {name}: needs {exc.name}, from the train extra: "
              f"{TRAIN_EXTRA_HINT}", file=sys.stderr)
        return 1
    finally:
        sys.argv[0] = program


PROFILE_HELP = ("the output's MCAP profile: foxglove (protobuf Foxglove schemas) or ros2 (ROS 2 "
                "messages in CDR, for ros2 bag play)")


def add_replay_arguments(parser: argparse.ArgumentParser, **defaults) -> None:
    """The recording and engine options of `replay`, shared by `fleet`: one engine flag per
    `EngineOptions` field (`defaults`: the command's own, e.g. fleet's one thread)."""
    parser.add_argument("--calib", type=Path, default=None,
                        help="calibration TOML (default: the recording's /edge/calibration, "
                             "else its CameraInfo pair + /tf_static)")
    parser.add_argument("--topics", type=Path, default=None,
                        help="TOML with a [topics] table mapping roles (left, right, lidar, "
                             "left_info, right_info, tf_static, gt) to the recording's topics")
    parser.add_argument("--profile", choices=("foxglove", "ros2"), default="foxglove",
                        help=PROFILE_HELP)
    add_engine_arguments(parser, **defaults)


def add_fleet_parser(sub) -> None:
    from edge_depth.fleet import DAMAGED_EXIT

    fleet = sub.add_parser("fleet", help="replay, compare or evaluate many recordings on Ray "
                                         "(pip install 'edge-depth[fleet]')")
    fleet.add_argument("fleet_command", choices=("replay", "compare", "evaluate"),
                       help="replay: DIR/NAME.mcap per recording; compare: that, then compare "
                            "with --base DIR/NAME.mcap (exit 1 on a regression); evaluate: "
                            "EPE / bad-3 against the recordings' ground truth, no output. "
                            "Each recording's status: ok, damaged (read past lost data: "
                            "outputs kept, the loss in the table), failed (exit 1)")
    fleet.add_argument("sources", type=Path, nargs="+",
                       help="recordings, folders of recordings, ROS 2 bag directories")
    fleet.add_argument("--out", type=Path, required=True,
                       help="outputs, result records and summary.md / summary.json")
    fleet.add_argument("--address", default=None,
                       help="a Ray cluster to join: auto or HOST:PORT (default: Ray local)")
    fleet.add_argument("--workers", type=positive_int, default=None,
                       help="engines at once (default: the cluster's CPUs / --threads)")
    fleet.add_argument("--base", type=Path, default=None,
                       help="compare: the folder of golden replays (an earlier fleet replay)")
    fleet.add_argument("--tolerance-px", type=float, default=0.25,
                       help="compare: a pixel differs beyond this")
    fleet.add_argument("--max-share", type=share, default=0.01,
                       help="compare: the share of differing pixels allowed")
    fleet.add_argument("--strict", action="store_true",
                       help=f"exit {DAMAGED_EXIT} when a recording is damaged (read past a "
                            "damaged chunk or a cut-off end) and none failed or regressed; "
                            "without it such a recording's outputs are kept, its row says "
                            "'damaged' and what it lost, and the exit status is 0")
    add_replay_arguments(fleet, threads=FLEET_THREADS)


def _add_synth_parser(sub) -> None:
    """`synth`: the synthetic worlds as scene folders or recordings."""
    from edge_depth.sim.lidar import PATTERNS

    p = sub.add_parser("synth", help="write synthetic scene folders with exact ground truth")
    p.add_argument("--out", type=Path, help="output directory of scene folders")
    p.add_argument("--mcap", type=Path, default=None,
                   help="write one MCAP recording here instead (robot topics, the "
                        "calibration, GT disparity on /sim/gt_disparity)")
    p.add_argument("--count", "--frames", type=positive_int, default=1,
                   help="number of scenes (frames)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first scene")
    p.add_argument("--size", type=parse_size, default=(640, 400), help="WxH (640x400)")
    p.add_argument("--lidar", choices=sorted(PATTERNS), default="beams16")
    p.add_argument("--world", choices=("rig", "things", "street"), default="rig",
                   help="rig: the planar rig as scene folders; things: the 3-D training "
                        "world as OUT/NNNNNNN.npz (LiDAR sampled at training time); "
                        "street: a recording (--mcap) of a road at 1242x375 with a "
                        "64-beam LiDAR, a world no shipped model trained on")
    p.add_argument("--turn-deg", type=float, default=0.0,
                   help="--mcap of the rig: the robot turns back and forth by this many "
                        "degrees (a 2 s period, a new scene every 20 frames; 0: still)")
    p.add_argument("--motion", choices=("still", "forward", "turn", "mover"), default=None,
                   help="--mcap of the rig: one world in motion, ground truth on every frame "
                        "(forward: the robot drives at 0.3 m/s; turn: 0.2 m/s turning 15°/s; "
                        "mover: 0.2 m/s while the nearest object crosses at 0.3 m/s; "
                        "edge.sim.motion)")
    p.add_argument("--fps", type=float, default=10.0,
                   help="--motion: the camera's frame rate (10)")
    p.add_argument("--scan-every", type=positive_int, default=1,
                   help="--motion: a LiDAR scan with every this many frames (1; 3 at 30 fps "
                        "is a 10 Hz LiDAR)")
    p.add_argument("--lidar-late-ms", type=float, default=0.0,
                   help="with --turn-deg: the LiDAR's stamps run this late, an offset the "
                        "recorded calibration does not know of (what the calibration watch "
                        "finds)")
    p.add_argument("--workers", type=positive_int, default=1,
                   help="rendering processes (--world things)")
    p.add_argument("--view-spread", type=_view_spread, default=1.0,
                   help="--world things: how much the two cameras' responses differ "
                        "(gain ±12 %%, gamma ±6 %%, blur ±0.3 px, vignetting ±0.05, times "
                        "this; 1 = the world the shipped model trained on)")
    p.add_argument("--clean-cameras", action="store_true",
                   help="--world things: one response for both views, gamma 1, no "
                        "vignetting, blur or JPEG, read noise 0.5 (the same scenes): "
                        "SGBM's matches about as reliable as on a real pair")
    p.add_argument("--scene-folders", action="store_true",
                   help="--world things: write scene folders for evaluation (16 GT rows "
                        "as the LiDAR) instead of training pairs")


def _add_demo_parser(sub) -> None:
    """`demo`: the embedded default."""
    p = sub.add_parser("demo", help="the embedded default: the synthetic rig, end to end")
    p.add_argument("--out", type=Path, default=Path("out"))
    p.add_argument("--frames", type=positive_int, default=3)
    p.add_argument("--seed", type=int, default=1_000_000,
                   help="first scene (default: the test split's first)")
    p.add_argument("--precision", choices=("auto", "int8", "fp32"), default="auto",
                   help="auto: int8 where this CPU runs it faster, else fp32")
    p.add_argument("--iters", type=positive_int, default=None,
                   help="GRU iterations (default: the bundle's)")
    p.add_argument("--deadline-ms", type=float, default=None)
    p.add_argument("--profile", choices=("foxglove", "ros2"), default="foxglove",
                   help=PROFILE_HELP)


def _add_replay_parser(sub) -> None:
    """`replay`: the pipeline over one recording."""
    p = sub.add_parser("replay", help="run the pipeline over an MCAP recording")
    p.add_argument("input", type=Path, help="recording (ours or a ROS 2 bag)")
    p.add_argument("--out", type=Path, required=True, help="output MCAP")
    add_replay_arguments(p)
    p.add_argument("--realtime", action="store_true",
                   help="pace by the recording's clock (drops frames when behind)")


def _add_daemon_parsers(sub) -> None:
    """`run` and `record`: the live sensors."""
    p = sub.add_parser("run", help="the on-robot depth daemon")
    p.add_argument("--config", type=Path, required=True, help="robot TOML (README)")
    p.add_argument("--out", type=Path, default=None, help="override log.out")
    p.add_argument("--live", nargs="?", const="127.0.0.1:8765", default=None,
                   type=parse_host_port, metavar="[HOST:]PORT",
                   help="also serve a Foxglove WebSocket (default 127.0.0.1:8765; "
                        "0.0.0.0:8765 to reach it from another machine)")
    p.add_argument("--max-frames", type=positive_int, default=None,
                   help="stop after this many frames (dry runs)")
    p.add_argument("--profile", choices=("foxglove", "ros2"), default=None,
                   help="override log.profile (foxglove or ros2)")
    p = sub.add_parser("record", help="record the live sensors to MCAP")
    p.add_argument("--config", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--max-frames", type=positive_int, default=None)
    p.add_argument("--profile", choices=("foxglove", "ros2"), default=None,
                   help="override log.profile (foxglove or ros2)")


def _add_compare_parser(sub) -> None:
    """`compare`: two replay outputs of one recording."""
    p = sub.add_parser("compare", help="compare two replay outputs of one recording "
                                       "(exit 1 when NEW regresses: golden replays in CI)")
    p.add_argument("base", type=Path, help="the reference replay output (MCAP)")
    p.add_argument("new", type=Path, help="the replay output under test (MCAP)")
    p.add_argument("--tolerance-px", type=float, default=0.25,
                   help="a pixel differs when |Δ disparity| exceeds this (default 0.25)")
    p.add_argument("--max-share", type=share, default=0.01,
                   help="the share of differing pixels allowed, e.g. 1%% or 0.01")
    p.add_argument("--json", type=Path, default=None, help="also write the report")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="edge-depth", description=__doc__)
    parser.add_argument("--version", action="version", version=f"edge-depth {_version()}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug messages too")
    parser.add_argument("-q", "--quiet", action="store_true", help="warnings and errors only")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    _add_synth_parser(sub)
    _add_demo_parser(sub)
    _add_replay_parser(sub)
    add_fleet_parser(sub)
    _add_daemon_parsers(sub)
    for name, (_, description) in TOOL_COMMANDS.items():
        tool = sub.add_parser(name, help=description, add_help=False,
                              description=f"{description}; `edge-depth {name} --help` for its "
                                          "options")
        tool.add_argument("tool_args", nargs=argparse.REMAINDER)
    _add_compare_parser(sub)
    from edge_depth.calibrate import add_parsers
    from edge_depth.ros2_command import add_parsers as add_ros2_parsers

    add_parsers(sub)
    add_ros2_parsers(sub)
    return parser


def fleet(args: argparse.Namespace) -> int:
    from edge_depth.fleet import FleetJob, fleet_command

    topics = load_topic_map(args.topics) if args.topics else None
    job = FleetJob(args.fleet_command, args.out,
                   options_from_args(args, threads=FLEET_THREADS),
                   dict(calib=args.calib, topics=topics, profile=args.profile),
                   args.base, args.tolerance_px, args.max_share)
    return fleet_command(job, args.sources, args.address, args.workers, args.strict)


def check_synth(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """The combinations of `synth` flags that mean nothing: a usage error each."""
    from edge_depth.sim.motion import MAX_SECONDS as MAX_MOTION_SECONDS

    if (args.out is None) == (args.mcap is None):
        parser.error("synth: give --out DIR (scene folders) or --mcap FILE (a recording)")
    if args.world == "things" and args.mcap:
        parser.error("synth: --world things writes training pairs to --out DIR, not --mcap")
    if args.world == "street" and not args.mcap:
        parser.error("synth: --world street writes a recording: give --mcap FILE")
    if (args.turn_deg or args.lidar_late_ms) and (args.world != "rig" or not args.mcap):
        parser.error("synth: --turn-deg and --lidar-late-ms make a recording of the rig "
                     "(--mcap FILE)")
    if args.motion and (args.world != "rig" or not args.mcap or args.turn_deg):
        parser.error("synth: --motion makes a recording of the rig (--mcap FILE), without "
                     "--turn-deg")
    if (args.fps != 10.0 or args.scan_every != 1) and not args.motion:
        parser.error("synth: --fps and --scan-every apply to --motion")
    if not 0 < args.fps <= 1000:
        parser.error(f"synth: --fps must be in (0, 1000], got {args.fps:g}")
    if args.motion and args.count / args.fps > MAX_MOTION_SECONDS:
        parser.error(f"synth: --motion for at most {MAX_MOTION_SECONDS:g} s (--count / --fps; "
                     f"got {args.count / args.fps:g} s): beyond it the moving world leaves "
                     "the range it was made for")
    if args.lidar_late_ms and not args.turn_deg:
        parser.error("synth: --lidar-late-ms shows only on a turning robot: give --turn-deg")
    if args.clean_cameras or args.view_spread != 1.0:
        if args.world != "things":
            parser.error("synth: --view-spread and --clean-cameras apply to --world things")
        if args.clean_cameras and args.view_spread != 1.0:
            parser.error("synth: --clean-cameras gives both views one response: "
                         "--view-spread does not apply")


def synth(args: argparse.Namespace) -> int:
    if args.mcap and args.world == "street":
        from edge_depth.sim_recording import write_street_recording

        n = write_street_recording(args.mcap, args.count, args.seed)
        print(f"wrote {args.mcap} ({args.count} street frames, 1242x375, {n} messages)")
        return 0
    if args.mcap and args.turn_deg:
        from edge_depth.sim import RigConfig
        from edge_depth.sim_recording import write_turning_recording

        w, h = args.size
        n = write_turning_recording(args.mcap, args.count, args.seed,
                                    RigConfig(width=w, height=h), args.lidar,
                                    amplitude_deg=args.turn_deg,
                                    lidar_clock_ms=args.lidar_late_ms)
        print(f"wrote {args.mcap} ({args.count} frames of a robot turning ±{args.turn_deg:g}°, "
              f"LiDAR stamps {args.lidar_late_ms:+g} ms late, {n} messages)")
        return 0
    if args.mcap:
        from edge_depth.sim import RigConfig
        from edge_depth.sim.motion import KINDS
        from edge_depth.sim_recording import write_sim_recording

        w, h = args.size
        motion = KINDS[args.motion] if args.motion else None
        n = write_sim_recording(args.mcap, args.count, args.seed, RigConfig(width=w, height=h),
                                args.lidar, 1000.0 / args.fps, motion, args.scan_every)
        moving = f", a world {args.motion} at {args.fps:g} fps, a scan every " \
            f"{args.scan_every} frames" if motion else ""
        print(f"wrote {args.mcap} ({args.count} frames{moving}, {n} messages)")
        return 0
    if args.world == "things" and args.scene_folders:
        from edge_depth.sim.export import things_folders_command

        return things_folders_command(args.out, args.count, args.seed, args.size,
                                      args.view_spread, args.clean_cameras)
    if args.world == "things":
        from edge_depth.sim.export import things_command

        return things_command(args.out, args.count, args.seed, args.size, args.workers,
                              args.view_spread, args.clean_cameras)
    from edge_depth.sim.export import synth_command

    return synth_command(args.out, args.count, args.seed, args.size, args.lidar)


def calibrate(args: argparse.Namespace) -> int:
    from edge_depth.calibrate import run

    return run(args)


def demo(args: argparse.Namespace) -> int:
    from edge_depth.demo import demo_command

    return demo_command(args.out, args.frames, args.seed, args.precision, args.iters,
                        args.deadline_ms, args.profile)


def replay(args: argparse.Namespace) -> int:
    from edge_depth.commands import replay_command

    topics = load_topic_map(args.topics) if args.topics else None
    return replay_command(args.input, args.out, options_from_args(args), args.calib, topics,
                          realtime=args.realtime, profile=args.profile)


def run(args: argparse.Namespace) -> int:
    from edge_depth.commands import run_command

    return run_command(args.config, args.out, args.live, args.max_frames, args.profile)


def record(args: argparse.Namespace) -> int:
    from edge_depth.commands import record_command

    return record_command(args.config, args.out, args.max_frames, args.profile)


def compare(args: argparse.Namespace) -> int:
    from edge_depth.compare import CompareError, compare_command

    try:
        return compare_command(args.base, args.new, args.tolerance_px, args.max_share,
                               args.json)
    except CompareError as exc:  # not a verdict: 2, as for a usage error
        print(f"edge-depth compare: error: {exc}", file=sys.stderr)
        return 2


def ros2(args: argparse.Namespace) -> int:
    from edge_depth.ros2_command import main_ros2

    return main_ros2(args)


# each subcommand's function (the tools are run_tool's)
COMMANDS = {"synth": synth, "calibrate": calibrate, "demo": demo, "replay": replay,
            "fleet": fleet, "run": run, "record": record, "compare": compare, "ros2": ros2,
            "ros2-play": ros2}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    flags = [a for a in argv[:2] if a in ("-v", "--verbose", "-q", "--quiet")]
    if len(argv) > len(flags) and argv[len(flags)] in TOOL_COMMANDS:
        # the tool parses its own arguments (--help included): argparse's REMAINDER would
        # stop at the first option
        configure_logging(bool({"-v", "--verbose"} & set(flags)),
                          bool({"-q", "--quiet"} & set(flags)))
        return run_tool(argv[len(flags)], argv[len(flags) + 1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(args.verbose, args.quiet)
    if args.command == "synth":
        check_synth(args, parser)
    if args.command == "fleet" and (args.fleet_command == "compare") != (args.base is not None):
        parser.error("fleet: --base DIR (the golden replays) goes with compare, and only there")
    try:
        if args.command in TOOL_COMMANDS:
            return run_tool(args.command, args.tool_args)
        return COMMANDS[args.command](args)
    except (EdgeError, CalibrationError, OSError) as exc:
        print(f"edge-depth {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] != "depthai":
            raise
        print(f"edge-depth {args.command}: the OAK camera needs depthai, from the oak extra: "
              f"{OAK_EXTRA_HINT}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C before a command's own handlers were installed
        print(f"edge-depth {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
