"""`edge-depth calibrate ...`: the calibration tool's subcommands."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from calibration.errors import CalibrationError
from edge.errors import EdgeError


def add_parsers(sub) -> None:
    cal = sub.add_parser("calibrate", help="stereo calibration, imports, LiDAR extrinsics")
    csub = cal.add_subparsers(dest="calib_command", required=True, parser_class=type(cal))
    st = csub.add_parser("stereo", help="calibrate a stereo pair from board views")
    st.add_argument("--left", required=True, help="glob of left images, e.g. 'DIR/left*.png'")
    st.add_argument("--right", required=True, help="glob of right images")
    st.add_argument("--board", required=True, help="checkerboard:COLSxROWS (inner corners) or "
                    "charuco:COLSxROWS (squares)")
    st.add_argument("--square-m", type=float, required=True, help="square side, metres")
    st.add_argument("--marker-m", type=float, default=None, help="ChArUco marker side, metres")
    st.add_argument("--fit-k3", action="store_true", help="also fit radial k3")
    st.add_argument("--out", required=True, type=Path, help="calibration file to write (TOML)")

    oak = csub.add_parser("import-oak", help="convert an OAK's factory calibration")
    oak.add_argument("--eeprom-json", type=Path, default=None,
                     help="a CalibrationHandler JSON dump; default: read the connected device")
    oak.add_argument("--size", default="640x400", help="output size WxH (intrinsics scaled)")
    oak.add_argument("--out", required=True, type=Path)

    ros = csub.add_parser("import-ros", help="convert ROS camera_info YAML (left and right)")
    ros.add_argument("--left", required=True, type=Path)
    ros.add_argument("--right", required=True, type=Path)
    ros.add_argument("--out", required=True, type=Path)

    exp = csub.add_parser("export-ros", help="write ROS camera_info YAML for both cameras")
    exp.add_argument("--calib", required=True, type=Path)
    exp.add_argument("--out-dir", required=True, type=Path)

    lid = csub.add_parser("lidar", help="check (and --refine) T_cam_lidar against stereo")
    lid.add_argument("--recording", required=True, type=Path,
                     help="a .mcap recording, or scene folders (a folder of them) with "
                          "lidar.npy")
    lid.add_argument("--calib", type=Path, default=None,
                     help="the calibration with the T_cam_lidar to check (default: the "
                          "recording's own: /edge/calibration, or CameraInfo + /tf_static)")
    lid.add_argument("--topics", type=Path, default=None,
                     help="a ROS 2 bag's topic map (TOML [topics] table, as for replay)")
    lid.add_argument("--out", type=Path, default=None,
                     help="write the calibration (with the refined T_cam_lidar if --refine)")
    lid.add_argument("--refine", action="store_true",
                     help="refine T_cam_lidar: make each LiDAR point land on the same "
                          "surface in the left and right image (photometric)")
    lid.add_argument("--overlay", type=Path, default=None, metavar="PNG",
                     help="draw the LiDAR points over a left image (before | refined)")
    lid.add_argument("--max-frames", type=int, default=20,
                     help="frames taken from the recording (default 20)")


def run(args: argparse.Namespace) -> int:
    try:
        if args.calib_command == "stereo":
            return _stereo(args)
        if args.calib_command == "import-oak":
            return _import_oak(args)
        if args.calib_command == "import-ros":
            from calibration.io import save_calibration
            from calibration.ros import load_camera_info_pair

            stereo = load_camera_info_pair(args.left, args.right)
            save_calibration(args.out, stereo)
            print(f"wrote {args.out}: rectified focal {stereo.focal_px:.2f} px, baseline "
                  f"{stereo.baseline_m * 1000:.2f} mm")
            return 0
        if args.calib_command == "export-ros":
            from calibration.io import load_calibration
            from calibration.ros import save_camera_info_pair

            stereo, _ = load_calibration(args.calib)
            paths = save_camera_info_pair(stereo, args.out_dir)
            print("wrote " + ", ".join(str(p) for p in paths))
            return 0
        if args.calib_command == "lidar":
            from calibration.extrinsics import lidar_command
            from edge.capture.replay import TopicMap
            from edge.cli import load_topic_map

            topics = TopicMap.from_dict(load_topic_map(args.topics)) if args.topics else None
            return lidar_command(args.recording, args.calib, args.out, args.refine,
                                 args.overlay, args.max_frames, topics)
    except (CalibrationError, ValueError, EdgeError) as exc:
        print(f"edge-depth calibrate {args.calib_command}: error: {exc}", file=sys.stderr)
        return 1
    return 2


def _stereo(args: argparse.Namespace) -> int:
    from calibration.io import save_calibration
    from calibration.stereo import Board, calibrate_stereo, load_views

    board = Board.parse(args.board, args.square_m, args.marker_m)
    left, right, names = load_views(args.left, args.right)
    calib, report = calibrate_stereo(left, right, board, names, fit_k3=args.fit_k3)
    for line in report.lines():
        print(line)
    save_calibration(args.out, calib)
    print(f"wrote {args.out}")
    return 0


def _import_oak(args: argparse.Namespace) -> int:
    from calibration.io import save_calibration
    from calibration.oak import stereo_from_oak
    from edge.cli import parse_size

    size = parse_size(args.size)
    stereo = stereo_from_oak(args.eeprom_json, size)
    save_calibration(args.out, stereo)
    print(f"wrote {args.out}: rectified focal {stereo.focal_px:.2f} px, baseline "
          f"{stereo.baseline_m * 1000:.2f} mm")
    return 0
