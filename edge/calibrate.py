"""`edge-depth calibrate ...`: the calibration tool's subcommands.

The `calibration` package is the layer below (models, file formats, projection, the fits): it
imports nothing of `edge`. What reads recordings or runs SGBM to calibrate lives here.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from edge_depth.calibration.errors import CalibrationError
from edge_depth.calibration.extrinsics import (
    ExtrinsicsFrame,
    disagreement,
    overlay,
    pose_difference,
    refine_extrinsics,
)
from edge_depth.calibration.model import StereoCalibration
from edge_depth.errors import EdgeError

# `calibrate check`'s exit status (2, bad arguments, is argparse's): a verdict that passes,
# ERROR, or none reached (no LiDAR scan, too few samples), never folded into a pass
CHECK_OK, CHECK_ERROR, CHECK_NO_VERDICT = 0, 1, 3
CHECK_EXITS = (f"exit status: {CHECK_OK} OK or WARN; {CHECK_ERROR} ERROR, or the check could "
               "not run (a bad calibration file or recording: the reason on stderr); 2 bad "
               f"arguments; {CHECK_NO_VERDICT} no verdict: no LiDAR scan found, or too few "
               "samples")


def add_parsers(sub) -> None:
    """`edge-depth calibrate`'s subcommands."""
    from edge_depth.calibration_watch import EVERY as WATCH_EVERY

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

    _lidar_parser(csub)
    chk = csub.add_parser("check", help="estimate the LiDAR-camera rotation error of a "
                          f"recording (exit {CHECK_OK} OK or WARN, {CHECK_ERROR} ERROR, "
                          f"{CHECK_NO_VERDICT} no verdict)", epilog=CHECK_EXITS)
    chk.add_argument("recording", type=Path, help="a .mcap recording with images and LiDAR")
    chk.add_argument("--calib", type=Path, default=None,
                     help="the calibration to check (default: the recording's own)")
    chk.add_argument("--topics", type=Path, default=None,
                     help="a ROS 2 bag's topic map (TOML [topics] table, as for replay)")
    chk.add_argument("--every", type=int, default=1,
                     help="one sample's budget in this many frames with LiDAR (default 1: "
                          f"every frame; {WATCH_EVERY} is the daemon's [calibration] "
                          "watch_every, a budget for its frame time that an offline check "
                          "does not have)")
    chk.add_argument("--max-samples", type=int, default=60,
                     help="stop after this many samples (default 60, the watch's window)")


def _lidar_parser(csub) -> None:
    """`calibrate lidar`: check (and refine) T_cam_lidar against the stereo."""
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
    lid.add_argument("--no-deskew", dest="deskew", action="store_false",
                     help="a recording's points as recorded, not moved by the camera's turn "
                          "between their own time and the frame's (the daemon's [sync] "
                          "deskew)")


def run(args: argparse.Namespace) -> int:
    try:
        if args.calib_command == "stereo":
            return _stereo(args)
        if args.calib_command == "import-oak":
            return _import_oak(args)
        if args.calib_command == "import-ros":
            from edge_depth.calibration.io import save_calibration
            from edge_depth.calibration.ros import load_camera_info_pair

            stereo = load_camera_info_pair(args.left, args.right)
            save_calibration(args.out, stereo)
            print(f"wrote {args.out}: rectified focal {stereo.focal_px:.2f} px, baseline "
                  f"{stereo.baseline_m * 1000:.2f} mm")
            return 0
        if args.calib_command == "export-ros":
            from edge_depth.calibration.io import load_calibration
            from edge_depth.calibration.ros import save_camera_info_pair

            stereo, _ = load_calibration(args.calib)
            paths = save_camera_info_pair(stereo, args.out_dir)
            print("wrote " + ", ".join(str(p) for p in paths))
            return 0
        if args.calib_command == "lidar":
            from edge_depth.arguments import load_topic_map
            from edge_depth.capture.replay import TopicMap

            topics = TopicMap.from_dict(load_topic_map(args.topics)) if args.topics else None
            return lidar_command(args.recording, args.calib, args.out, args.refine,
                                 args.overlay, args.max_frames, topics, args.deskew)
        if args.calib_command == "check":
            from edge_depth.arguments import load_topic_map
            from edge_depth.capture.replay import TopicMap

            topics = TopicMap.from_dict(load_topic_map(args.topics)) if args.topics else None
            return check_command(args.recording, args.calib, topics, args.every,
                                 args.max_samples)
    except (CalibrationError, ValueError, EdgeError) as exc:
        print(f"edge-depth calibrate {args.calib_command}: error: {exc}", file=sys.stderr)
        return 1
    return 2


def _stereo(args: argparse.Namespace) -> int:
    from edge_depth.calibration.io import save_calibration
    from edge_depth.calibration.stereo import Board, calibrate_stereo, load_views

    board = Board.parse(args.board, args.square_m, args.marker_m)
    left, right, names = load_views(args.left, args.right)
    calib, report = calibrate_stereo(left, right, board, names, fit_k3=args.fit_k3)
    for line in report.lines():
        print(line)
    save_calibration(args.out, calib)
    print(f"wrote {args.out}")
    return 0


def _import_oak(args: argparse.Namespace) -> int:
    from edge_depth.arguments import parse_size
    from edge_depth.calibration.io import save_calibration
    from edge_depth.calibration.oak import stereo_from_oak

    size = parse_size(args.size)
    stereo = stereo_from_oak(args.eeprom_json, size)
    save_calibration(args.out, stereo)
    print(f"wrote {args.out}: rectified focal {stereo.focal_px:.2f} px, baseline "
          f"{stereo.baseline_m * 1000:.2f} mm")
    return 0


def make_frame(left: np.ndarray, right: np.ndarray, points: np.ndarray) -> ExtrinsicsFrame:
    """SGBM on the rectified pair plus the points."""
    from edge_depth.baselines import sgbm_disparity

    disparity = sgbm_disparity(left, right)
    disparity[disparity <= 0] = np.nan
    return ExtrinsicsFrame(disparity, np.asarray(points, np.float64))


def mcap_frames(path: Path, stereo: StereoCalibration, time_offset_ns: int = 0,
                max_frames: int = 20, topics=None, deskew_with: np.ndarray | None = None
                ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Up to `max_frames` (left, right, points) of a recording, each with the LiDAR revolution
    nearest in time (images rectified with `stereo` unless the recording's already are).
    `deskew_with`: the initial T_cam_lidar, to deskew the points by the camera's turn as the
    daemon does (a turn about the camera's own axis: the extrinsics' error moves it by second
    order only)."""
    from edge_depth.capture.synced import deskewed_note, synced_frames

    frames, seen = [], 0
    counts: dict[str, int] = {}
    for frame, left, right, points, _ in synced_frames(path, stereo, time_offset_ns,
                                                       topics=topics, counters=counts,
                                                       deskew_with=deskew_with):
        if frame.size != tuple(stereo.image_size):
            raise CalibrationError(f"image size {frame.size} differs from the "
                                   f"calibration's {stereo.image_size}", path=str(path))
        seen += 1
        if len(points):
            frames.append((left, right, points))
            if len(frames) >= max_frames:
                break
    print(f"{path}: frames with LiDAR: {len(frames)} of {seen} read" + deskewed_note(counts),
          flush=True)
    if not frames:
        raise CalibrationError("no frame with LiDAR points in the recording", path=str(path))
    return frames


def check_command(recording: Path, calib_path: Path | None, topics=None, every: int = 1,
                  max_samples: int = 60) -> int:
    """`edge-depth calibrate check REC.mcap`: the calibration watch of the daemon
    (`edge.calibration_watch`) over a recording's frames with LiDAR, one sample's budget in
    `every` of them; prints the estimate, its uncertainty and the level, and the command that
    refines it. CHECK_ERROR on ERROR, CHECK_NO_VERDICT when it could not reach one (no LiDAR
    scan, too few samples: said which), else CHECK_OK."""
    from edge_depth.calibration_verdict import ERROR, SETTLING, fixes

    if every < 1 or max_samples < 1:
        raise ValueError(f"--every and --max-samples: at least 1, got {every}, {max_samples}")
    stereo, lidar, origin = _initial_calibration(recording, calib_path, True, topics)
    if lidar is None:
        raise CalibrationError(f"{origin} has no LiDAR extrinsics: nothing to check (a "
                               "[lidar] section in --calib)", key="lidar")
    print(f"calibration: {origin}")
    watch, seen, with_lidar = _watch_recording(recording, stereo, lidar, topics, every,
                                               max_samples)
    if not with_lidar:
        print(f"no verdict: {_no_scan_reason(recording, topics)} ({seen} frames read)")
        return CHECK_NO_VERDICT
    estimate = watch.estimate()
    print(f"{watch.samples} samples from {seen} frames ({with_lidar} with LiDAR)")
    print(f"LiDAR-camera rotation error: {estimate.describe()}")
    if estimate.level == SETTLING:
        print(_too_few_line(estimate.samples, with_lidar, every, max_samples))
        return CHECK_NO_VERDICT
    if todo := fixes(estimate, str(recording), None if calib_path is None else str(calib_path),
                     lidar.time_offset_ns):
        print(todo)
    return CHECK_ERROR if estimate.level == ERROR else CHECK_OK


def _watch_recording(recording: Path, stereo: StereoCalibration, lidar, topics, every: int,
                     max_samples: int):
    """(the watch, frames read, frames with LiDAR points): the daemon's watch fed a
    recording's frames, one sample's budget in `every` frames with LiDAR, until `max_samples`
    samples."""
    from edge_depth.calibration.projection import project_to_disparity
    from edge_depth.calibration_watch import CalibrationWatch, stereo_reference
    from edge_depth.capture.synced import stamped_frames
    from edge_depth.runtime.engine import Engine

    engine = Engine()
    watch = CalibrationWatch(stereo, lidar.T_cam_lidar, every)
    seen = with_lidar = 0
    for frame, left, right, points, stamp, _ in stamped_frames(
            recording, stereo, lidar.time_offset_ns, topics=topics):
        if frame.size != tuple(stereo.image_size):
            raise CalibrationError(f"image size {frame.size} differs from the calibration's "
                                   f"{stereo.image_size}", path=str(recording))
        seen += 1
        watch.frame(frame.stamp_ns, left)  # every frame: the turn between frames
        with_lidar += bool(len(points))
        if not len(points) or not watch.due():
            continue
        sparse, _ = project_to_disparity(points, stereo, lidar.T_cam_lidar)
        engine.infer(left, right, sparse)
        watch.add(stereo_reference(engine), points, (stamp - frame.stamp_ns) / 1e9)
        if watch.samples >= max_samples:
            break
    return watch, seen, with_lidar


def _no_scan_reason(recording: Path, topics) -> str:
    """Why no frame of the recording had LiDAR points, naming the topic looked for (and the
    recording's point-cloud topics when it is not one of them)."""
    from edge_depth.capture.replay import McapSource

    source = McapSource(recording, topics)
    lidar_topic, present = source.topics.lidar, source.file_topics()
    others = ", ".join(source.unmapped_lidar_topics())
    there = f"; LiDAR-like topics there: {others} (map lidar in --topics)" if others else ""
    if not lidar_topic:
        return f"no LiDAR topic is mapped (--topics maps lidar to \"\"){there}"
    if present is not None and lidar_topic in present:
        return (f"no frame paired with a LiDAR scan on {lidar_topic} (none there, or their "
                "stamps with [lidar] time_offset_ns miss every frame's)")
    return f"no LiDAR scan found on {lidar_topic}{there}"


def _too_few_line(samples: int, with_lidar: int, every: int, max_samples: int) -> str:
    """What a check short of MIN_SAMPLES samples says, with what would give it more."""
    from edge_depth.calibration_verdict import MIN_SAMPLES

    if max_samples < MIN_SAMPLES:
        more = f"--max-samples {max_samples} stops it short: at least {MIN_SAMPLES}"
    elif every > 1:
        more = f"one sample in {every} frames with LiDAR: a smaller --every, or a longer recording"
    elif with_lidar < MIN_SAMPLES:
        more = f"{with_lidar} frames with LiDAR: a longer recording"
    else:
        more = ("the frames show too few views of their own (a sample of the view the last "
                "one saw replaces it: a robot standing still gives one), or their points miss "
                "the image: a recording that moves")
    return f"no verdict: too few samples ({samples} of the {MIN_SAMPLES} needed); {more}"


def _write_overlay(path: Path, data, calib: StereoCalibration, before: np.ndarray,
                   after: np.ndarray | None) -> None:
    """Before | after overlays of the frame with the most LiDAR points, labelled."""
    import cv2

    left, _, points = max(data, key=lambda d: len(d[2]))
    panels = [("before", before)] + ([("refined", after)] if after is not None else [])
    images = []
    for label, T in panels:
        image = overlay(left, points, calib, T)
        cv2.putText(image, label, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2)
        images.append(image)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.hstack(images)):
        raise CalibrationError("could not write the overlay image", path=str(path))
    print(f"wrote {path}")


# fewer frames than this refine unreliably on the rig (experiments/extrinsics_study.py: 3 frames end
# up to 0.25 degrees / 6.3 mm off, 6 frames within 0.14 degrees / 2.5 mm)
MIN_REFINE_FRAMES = 6


def _initial_calibration(recording: Path, calib_path: Path | None, is_mcap: bool, topics):
    """(stereo, lidar or None, where it came from): --calib, else the recording's own."""
    from edge_depth.calibration.io import load_calibration
    from edge_depth.capture.recording_calibration import recording_calibration
    from edge_depth.capture.replay import McapSource

    if calib_path is not None:
        return (*load_calibration(calib_path), f"--calib {calib_path}")
    found = recording_calibration(McapSource(recording, topics)) if is_mcap else None
    if found is None:
        raise CalibrationError("--calib is needed: the recording carries no calibration "
                               "(/edge/calibration, or a CameraInfo pair mapped with --topics)",
                               path=str(recording))
    return found


def _lidar_frames(recording: Path, is_mcap: bool, stereo, lidar, max_frames: int, topics,
                  deskew: bool) -> list:
    """(left, right, points) of up to `max_frames` frames: a recording's (its points deskewed
    as the daemon deskews them) or scene folders' (left.png, right.png, lidar.npy)."""
    from edge_depth.sim.folder import list_scene_folders, read_scene_folder

    if is_mcap:
        return mcap_frames(recording, stereo, lidar.time_offset_ns, max_frames, topics,
                           lidar.T_cam_lidar if deskew else None)
    folders = list_scene_folders(recording)
    if not folders:
        raise CalibrationError("no scene folders (left.png, right.png, lidar.npy) and not "
                               "a .mcap recording", path=str(recording))
    data = []
    for folder in folders[:max_frames]:
        scene = read_scene_folder(folder)
        if scene.lidar is None:
            print(f"skipping {folder}: no lidar.npy")
            continue
        if scene.left.shape[::-1] != stereo.image_size:
            raise CalibrationError(f"image size {scene.left.shape[::-1]} differs from the "
                                   f"calibration's {stereo.image_size}", path=str(folder))
        data.append((scene.left, scene.right, scene.lidar))
    return data


def lidar_command(recording: Path, calib_path: Path | None, out: Path | None,
                  refine: bool = False, overlay_path: Path | None = None,
                  max_frames: int = 20, topics=None, deskew: bool = True) -> int:
    """`edge-depth calibrate lidar`: report the disagreement of LiDAR and SGBM disparities,
    optionally refine T_cam_lidar (`refine_extrinsics`) and draw the LiDAR over the image.
    Without `calib_path`, a recording's own calibration is used (ours, or a ROS 2 bag's
    CameraInfo pair and /tf_static; `topics` maps the bag's topics). `deskew`: a recording's
    points moved by the camera's turn as the daemon moves them (`[sync] deskew`)."""
    from edge_depth.calibration.io import save_calibration
    from edge_depth.calibration.model import LidarExtrinsics

    if max_frames < 1:
        raise ValueError(f"--max-frames: expected at least 1, got {max_frames}")
    is_mcap = Path(recording).suffix == ".mcap"
    stereo, lidar, origin = _initial_calibration(recording, calib_path, is_mcap, topics)
    if lidar is None:
        raise CalibrationError(f"{origin} has no LiDAR extrinsics: give an initial "
                               "T_cam_lidar to refine (a [lidar] section in --calib)",
                               key="lidar")
    print(f"calibration: {origin}")
    data = _lidar_frames(Path(recording), is_mcap, stereo, lidar, max_frames, topics, deskew)
    frames = [make_frame(*d) for d in data]
    before = disagreement(frames, stereo, lidar.T_cam_lidar)
    print(f"{len(frames)} frames, {before['points']} LiDAR points on SGBM pixels")
    print(f"before: |LiDAR - SGBM| disparity median {before['median_px']:.3f} px, "
          f"p90 {before['p90_px']:.3f} px")
    T = lidar.T_cam_lidar
    if refine:
        if len(data) < MIN_REFINE_FRAMES:
            print(f"warning: {len(data)} frames; refinement wants {MIN_REFINE_FRAMES} or more "
                  "with depth edges in view (on the rig 3 frames end up to 0.25 deg off)")

        def progress(sigma: float, points: int, cost: float) -> None:
            print(f"  blur {sigma:.0f} px, {points} points seen by both cameras: "
                  f"mean |left - right| {cost:.3f} grey levels", flush=True)

        T, result = refine_extrinsics(data, stereo, T, progress=progress)
        angle, shift = pose_difference(T, lidar.T_cam_lidar)
        after = disagreement(frames, stereo, T)
        print(f"refined: mean |left - right| at the LiDAR points {result['cost_before']:.3f} -> "
              f"{result['cost_after']:.3f} grey levels; moved {angle:.3f} deg, "
              f"{shift * 1000:.1f} mm")
        print(f"after: |LiDAR - SGBM| disparity median {after['median_px']:.3f} px, "
              f"p90 {after['p90_px']:.3f} px")
    if overlay_path is not None:
        _write_overlay(Path(overlay_path), data, stereo, lidar.T_cam_lidar,
                       T if refine else None)
    if out is not None:
        save_calibration(out, stereo, LidarExtrinsics(T, lidar.time_offset_ns))
        print(f"wrote {out}" + ("" if refine else " (extrinsics unchanged)"))
    return 0
