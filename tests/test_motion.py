"""edge.sim.motion: one world seen from a moving camera, with an object moving on its own;
the ground truth on every frame follows the geometry, and `synth --mcap --motion` records it
with a camera faster than the LiDAR."""

from __future__ import annotations

import json
import re
from collections import Counter
from dataclasses import replace
from unittest import mock as unittest_mock

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from edge_depth.capture.sim import SimSource
from edge_depth.cli import main as cli_main
from edge_depth.metrics import error_map, temporal_instability
from edge_depth.runtime.propagate import Propagator
from edge_depth.sim.motion import (
    KINDS,
    Motion,
    lift,
    mover_index,
    mover_mask,
    moving_sample,
    plane_of,
    positions_then,
    scene_at,
    start_world,
)
from edge_depth.sim.rig import make_sample
from edge_depth.sim.scene import LEFT, RigConfig
from edge_depth.types import DepthResult, GroundTruth, LidarScan, StereoFrame

RIG = RigConfig(width=192, height=120, focal_px=150.0, max_disparity_px=24.0)
SEED = 11


def world():
    return start_world(SEED, RIG)


def test_a_still_world_is_the_same_on_every_frame_and_its_first_is_make_samples():
    first = moving_sample(SEED, 0.0, KINDS["still"], RIG)
    later = moving_sample(SEED, 0.7, KINDS["still"], RIG, frame=21)
    np.testing.assert_array_equal(first.disp_left, later.disp_left)
    plain = make_sample(SEED, replace(RIG, max_disparity_px=RIG.max_disparity_px / 2))
    # the same scene; only an ellipse's outline, carried as a 48-gon, differs at its rim
    assert np.mean(np.abs(first.disp_left - plain.disp_left) > 0.01) < 0.01


def test_a_background_point_seen_driving_forward_has_the_disparity_geometry_gives():
    motion = Motion(speed_mps=0.3, yaw_dps=10.0)
    scene0, scene1 = world(), scene_at(world(), 0.5, motion)
    background0, background1 = scene0.layers[0], scene1.layers[0]
    assert background0.kind == "background"
    # a background pixel lifted into the world, seen by the camera 0.5 s later
    uv = np.array([[40.0, 30.0], [150.0, 90.0]])
    points = lift(plane_of(background0, RIG), uv, RIG)
    yaw = np.radians(10.0 * 0.5)
    R = np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
    seen = (points - np.array([0.0, 0.0, 0.15])) @ R.T
    u = RIG.cx + RIG.focal_px * seen[:, 0] / seen[:, 2]
    v = RIG.cy + RIG.focal_px * seen[:, 1] / seen[:, 2]
    expected = RIG.focal_px * RIG.baseline_m / seen[:, 2]
    got = background1.disparity(LEFT, u, v, RIG.cx, RIG.cy)
    np.testing.assert_allclose(got, expected, rtol=1e-9)
    assert np.all(expected > background0.disparity(LEFT, uv[:, 0], uv[:, 1], RIG.cx,
                                                   RIG.cy))  # nearer now


def test_a_moving_layers_texture_moves_with_its_plane():
    motion = Motion(speed_mps=0.3, yaw_dps=15.0, mover_mps=(0.3, 0.0, 0.0))
    t = 0.5
    scene0, scene1 = world(), scene_at(world(), t, motion)
    yaw = np.radians(15.0 * t)
    R = np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]])
    mover = mover_index(scene0)
    checked = 0
    for k, (layer0, layer1) in enumerate(zip(scene0.layers, scene1.layers, strict=True)):
        # pixels of the layer at t = 0 lifted onto its plane, moved, seen at t: the texture
        # there must be the one they showed at t = 0 (the corners: any point of the plane)
        uv = np.array([[10.0, 12.0], [170.0, 20.0], [30.0, 100.0], [150.0, 95.0]])
        points = lift(plane_of(layer0, RIG), uv, RIG)
        own = np.array(motion.mover_mps) * t if k == mover else np.zeros(3)
        seen = (points + own - np.array([0.0, 0.0, 0.3 * t])) @ R.T
        u = RIG.cx + RIG.focal_px * seen[:, 0] / seen[:, 2]
        v = RIG.cy + RIG.focal_px * seen[:, 1] / seen[:, 2]
        before = layer0.tex_affine @ np.stack([uv[:, 0], uv[:, 1], np.ones(4)])
        after = layer1.tex_homography @ np.stack([u, v, np.ones(4)])
        np.testing.assert_allclose(after[:2] / after[2], before, atol=1e-6)
        checked += 1
    assert checked == len(scene0.layers) > 1


def test_only_the_mover_moves_against_the_world():
    still_objects = Motion(speed_mps=0.2)
    moving_object = Motion(speed_mps=0.2, mover_mps=(0.3, 0.0, 0.0))
    a, b = scene_at(world(), 0.5, still_objects), scene_at(world(), 0.5, moving_object)
    assert len(a.layers) == len(b.layers)
    differ = [k for k, (x, y) in enumerate(zip(a.layers, b.layers, strict=True))
              if not np.allclose(x.plane, y.plane) or
              (x.vertices is not None and not np.allclose(x.vertices, y.vertices))]
    assert len(differ) == 1
    k = differ[0]
    # moved right by 0.15 m: its outline's centre moves right by about f·0.15 / Z px
    shift = b.layers[k].vertices.mean(axis=0)[0] - a.layers[k].vertices.mean(axis=0)[0]
    depth = RIG.focal_px * RIG.baseline_m / a.layers[k].plane[0]
    assert 0.5 * RIG.focal_px * 0.15 / depth < shift < 2.0 * RIG.focal_px * 0.15 / depth


def test_synth_refuses_a_moving_world_longer_than_it_was_made_for(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli_main(["synth", "--mcap", str(tmp_path / "long.mcap"), "--count", "91",
                  "--motion", "turn", "--fps", "30"])
    assert exit_.value.code == 2 and "at most 3 s" in capsys.readouterr().err
    assert not (tmp_path / "long.mcap").exists()


def test_synth_records_a_moving_world_with_truth_on_every_frame(tmp_path, capsys):
    out = tmp_path / "forward.mcap"
    assert cli_main(["synth", "--mcap", str(out), "--count", "7", "--size", "192x120",
                     "--motion", "forward", "--fps", "30", "--scan-every", "3"]) == 0
    assert "a world forward at 30 fps" in capsys.readouterr().out
    topics: Counter = Counter()
    stamps: dict[str, list[int]] = {}
    with out.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            topics[channel.topic] += 1
            stamps.setdefault(channel.topic, []).append(message.log_time)
    assert topics["/stereo/left/image_rect"] == 7 and topics["/sim/gt_disparity"] == 7
    assert topics["/lidar/points"] == 3  # frames 0, 3 and 6
    frame_gap = np.diff(sorted(stamps["/stereo/left/image_rect"]))
    np.testing.assert_allclose(frame_gap, 1e9 / 30, atol=1)


def test_temporal_instability_is_the_change_of_the_error_beyond_the_truths():
    gt = np.full((4, 6), 10.0, np.float32)
    gt[0, 0] = np.nan  # unknown
    first = error_map(gt + 0.5, gt)
    assert np.isnan(first[0, 0]) and np.allclose(first[1:], 0.5)
    moved_gt = gt + 2.0  # the truth changed by 2 px; an output that follows it is stable
    assert temporal_instability(error_map(moved_gt + 0.5, moved_gt), first) == 0.0
    wobbly = moved_gt + 0.5
    wobbly[2] += 1.0  # one row of 6 known pixels in 23 jumps by a pixel
    assert temporal_instability(error_map(wobbly, moved_gt), first) == \
        pytest.approx(6 / 23)
    hole = moved_gt.copy()
    hole[3, 5] = 0.0  # a hole counts as the whole truth, as in disparity_metrics
    assert temporal_instability(error_map(hole, moved_gt), error_map(moved_gt, moved_gt)) == \
        pytest.approx(12.0 / 23)


@pytest.mark.parametrize("kind", ["forward", "turn", "mover"])
def test_where_each_pixels_surface_was_agrees_with_the_earlier_frames_truth(kind):
    motion = KINDS[kind]
    now = moving_sample(SEED, 0.3, motion, RIG, frame=9)
    then = moving_sample(SEED, 0.0, motion, RIG, frame=0)
    at = positions_then(SEED, 0.3, 0.0, motion, now.disp_left, then.disp_left, RIG)
    known = np.isfinite(at[..., 0])
    # known: the earlier frame's truth at the position is the surface's disparity then
    assert known.mean() > 0.9
    moved = at - np.stack(np.meshgrid(np.arange(RIG.width), np.arange(RIG.height)), -1)
    assert np.nanmean(np.abs(moved)) > 0.3  # the image moved
    mover = mover_mask(SEED, 0.3, motion, now.disp_left, RIG)  # ("mover": it moves itself)
    assert mover.mean() > 0.01 and known[mover].mean() > 0.8
    # an error pattern carried with the scene is stable after the motion, not before it
    rng = np.random.default_rng(0)
    before = rng.normal(0.0, 1.0, now.disp_left.shape).astype(np.float32)
    xi, yi = (np.rint(np.nan_to_num(at[..., k])).astype(int) for k in (0, 1))
    carried = np.where(known, before[yi.clip(0, RIG.height - 1), xi.clip(0, RIG.width - 1)],
                       np.nan)
    assert temporal_instability(carried, before, at) == 0.0
    assert temporal_instability(carried, before) > 0.5


def test_replay_of_a_moving_world_reports_its_temporal_instability(tmp_path, capsys):
    recording = tmp_path / "still.mcap"
    assert cli_main(["synth", "--mcap", str(recording), "--count", "4", "--size", "192x120",
                     "--motion", "still"]) == 0
    assert cli_main(["replay", str(recording), "--out", str(tmp_path / "out.mcap")]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines()
                if x.startswith("temporal instability"))
    value = float(line.split()[2])
    assert 0.0 < value < 2.0 and "3 pairs" in line


def test_the_sim_robot_loops_a_moving_world_with_a_scan_every_third_frame():
    source = SimSource(7, SEED, RIG, period_ms=1000 / 30, distinct=3, motion=KINDS["mover"],
                       scan_every=3)
    events = list(source)
    frames = [e for e in events if isinstance(e, StereoFrame)]
    truths = [e for e in events if isinstance(e, GroundTruth)]
    scans = [e for e in events if isinstance(e, LidarScan)]
    assert len(frames) == len(truths) == 7 and len(scans) == 3  # frames 0, 3 and 6
    # three frames of motion rendered once, played forward and back: 0 1 2 1 0 1 2
    np.testing.assert_array_equal(truths[3].disparity, truths[1].disparity)
    np.testing.assert_array_equal(truths[4].disparity, truths[0].disparity)
    assert not np.array_equal(truths[1].disparity, truths[0].disparity)
    np.testing.assert_allclose(np.diff([f.stamp_ns for f in frames]), 1e9 / 30, atol=1)


def test_a_key_frames_depth_is_carried_along_the_images_motion():
    rng = np.random.default_rng(3)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (120, 220)).astype(np.float32), (0, 0), 1.5)
    key_left = np.clip(texture[:, 10:202], 0, 255).astype(np.uint8)
    left = np.clip(texture[:, 14:206], 0, 255).astype(np.uint8)  # the view moved 4 px left
    disparity = np.full((120, 192), 10.0, np.float32)
    disparity[:, 96:] = 20.0  # a depth edge at x = 96 in the key frame
    key = DepthResult(stamp_ns=0, disparity=disparity, depth=np.zeros_like(disparity),
                      valid=np.ones((120, 192), bool), iterations=4)
    carry = Propagator()
    assert carry.wants_engine(0, 5)
    carry.key(0, 5, key_left, key)
    assert not carry.wants_engine(33_000_000, 5)  # the same scan: carried
    assert carry.wants_engine(33_000_000, 6)  # a fresh scan: a key frame
    assert carry.wants_engine(300_000_000, 5)  # too old to carry
    out = carry.carry(33_000_000, left, 150.0, 0.075)
    # the edge now at x = 92: content at x in this frame was at x + 4 in the key frame
    assert np.all(out.disparity[20:100, 40:88] == pytest.approx(10.0, abs=0.2))
    assert np.all(out.disparity[20:100, 96:150] == pytest.approx(20.0, abs=0.2))
    assert out.iterations == 0 and "propagate" in out.timings_ms
    np.testing.assert_allclose(out.depth[50, 50], 150.0 * 0.075 / out.disparity[50, 50])
    # another scene altogether: the flow is lost, the frame must be a key frame
    elsewhere = np.random.default_rng(4).integers(0, 256, (120, 192)).astype(np.uint8)
    assert carry.carry(66_000_000, elsewhere, 150.0, 0.075) is None
    assert carry.lost == 1 and carry.carried == 1


def test_replay_at_the_camera_rate_runs_the_engine_on_key_frames_only(tmp_path, capsys):
    recording = tmp_path / "forward.mcap"
    assert cli_main(["synth", "--mcap", str(recording), "--count", "9", "--size", "192x120",
                     "--motion", "forward", "--fps", "30", "--scan-every", "3"]) == 0
    assert cli_main(["replay", str(recording), "--out", str(tmp_path / "out.mcap"),
                     "--rate", "camera"]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("Camera rate:"))
    found = re.match(r"Camera rate: (\d+) key frames .*?, (\d+) carried", line)
    assert found, line
    keys, carried = int(found[1]), int(found[2])
    # the engine on the frames of the three scans; the frames just before the next scan is
    # due (2, 5 and 8) carried without waiting for it (`ahead`)
    assert (keys, carried) == (3, 6)
    assert sum("carried from the key frame" in x for x in out.splitlines()) == carried
    assert "over 9 frames with ground truth" in out
    with (tmp_path / "out.mcap").open("rb") as f:
        diagnostics = [json.loads(m.data) for _, _, m in
                       make_reader(f).iter_messages(topics=["/diagnostics"])]
    scaled = int(re.search(r"\((\d+) scaled by the camera's motion", line)[1])
    assert 0 < scaled <= carried  # driving forward: the carried disparity is changed
    assert "on 3 scans" in line  # the recording's three, each once
    assert diagnostics[-1]["camera_rate"] == dict(key_frames=keys, carried=carried, lost=0,
                                                  scaled=scaled, scans=3, ahead=3)


RIGID = (250.0, 0.075, 159.5, 119.5)  # f px, B m, cx, cy of a 320×240 camera


def rigid_scene(rng: np.random.Generator, truth: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 320×240 frame of fronto-parallel 8×8 px patches at disparities 6–20 px (drawn from
    `rng`), seen from a camera that moved `truth` (ωx, ωy, ωz rad, Tx, Ty, Tz m) since its key
    frame: (the frame's disparity, the flow frame → key frame (H, W, 2), the key frame's
    disparity carried to the frame)."""
    h, w = 240, 320
    f, b, cx, cy = RIGID
    now = np.repeat(rng.uniform(6.0, 20.0, (h // 8, w // 8)), 8, 0).repeat(8, 1)
    x, y = np.meshgrid(np.arange(w) - cx, np.arange(h) - cy)
    z = f * b / now
    points = np.stack([x * z / f, y * z / f, z], -1)
    key = points @ cv2.Rodrigues(truth[:3])[0].T + truth[3:]  # the points in the key frame's
    flow = np.stack([f * key[..., 0] / key[..., 2] - x, f * key[..., 1] / key[..., 2] - y],
                    -1).astype(np.float32)
    return now, flow, (f * b / key[..., 2]).astype(np.float32)


def test_the_cameras_motion_fitted_to_the_flow_gives_each_carried_pixels_new_disparity():
    """A rigid scene seen from a camera that moved (ω, T) since its key frame: the motion
    fitted to the flow is the motion, and the key frame's disparity carried to the frame and
    scaled is the frame's own; a flow no rigid motion explains leaves it unscaled."""
    from edge_depth.runtime.propagate import depth_change, ego_motion

    rng = np.random.default_rng(3)
    truth = np.array([0.004, -0.012, 0.002, 0.006, -0.003, 0.02])  # ω rad, T m
    now, flow, carried = rigid_scene(rng, truth)
    h, w, f, b, cx, cy = *now.shape, *RIGID
    motion, residual, used = ego_motion(flow, carried, np.ones((h, w), bool), f, b, (cx, cy))
    assert used > 1000 and residual < 0.1
    np.testing.assert_allclose(motion, truth, atol=2e-3)
    scale = depth_change(flow, carried, np.zeros((h, w), np.uint8), f, b, (cx, cy))
    assert scale is not None
    assert np.abs(carried * scale / now - 1).max() < 0.005  # the frame's own disparity
    assert np.abs(carried / now - 1).max() > 0.02  # which the key frame's is not
    chaos = rng.normal(0.0, 5.0, flow.shape).astype(np.float32)
    assert depth_change(chaos, carried, np.zeros((h, w), np.uint8), f, b, (cx, cy)) is None


def test_an_object_moving_on_its_own_does_not_move_the_fitted_camera():
    """A quarter of the frame is an object that moved 6 px right of where the camera's motion
    puts it: the fit leaves it out (its residual is far over the rest's), so the camera's
    motion comes out as without it; Huber's weights alone let it pull the fit."""
    from edge_depth.runtime import propagate

    truth = np.array([0.002, -0.010, 0.001, 0.004, -0.002, 0.015])
    _, flow, carried = rigid_scene(np.random.default_rng(5), truth)
    h, w, f, b, cx, cy = *flow.shape[:2], *RIGID
    flow[: h // 2, : w // 2, 0] += 6.0  # the mover
    args = (flow, carried, np.ones((h, w), bool), f, b, (cx, cy))
    motion, residual, used = propagate.ego_motion(*args)
    assert used > 1000 and residual < 0.1
    np.testing.assert_allclose(motion, truth, atol=2e-3)
    with unittest_mock.patch.object(propagate, "OUTLIER_SIGMAS", np.inf):  # Huber alone
        pulled, _, _ = propagate.ego_motion(*args)
    assert np.abs(pulled - truth).max() > 5 * np.abs(motion - truth).max()


def test_the_motion_kinds_the_config_and_synth_name_are_the_simulators():
    """The robot config and the CLI spell the kinds out (neither imports the simulator to
    build its choices); they must be edge.sim.motion's."""
    from edge_depth.cli import build_parser
    from edge_depth.config import CHOICES

    assert set(CHOICES[("camera", "sim_motion")]) == {"none", *KINDS}
    commands = next(a for a in build_parser()._actions if a.choices and "synth" in a.choices)
    motion = next(a for a in commands.choices["synth"]._actions if a.dest == "motion")
    assert set(motion.choices) == set(KINDS)


def test_live_at_the_camera_rate_the_frame_before_a_scan_is_carried_without_waiting_for_it():
    """Live, paired by "nearest", the frame just before a scan would wait for that scan while
    nothing else can run (what follows needs its key frame). At the camera's rate it is
    carried at once from the key frame before, and the frame nearest the scan is the next
    key frame, whenever the scan arrives (a replay does the same)."""
    import time

    from edge_depth.daemon import Pipeline
    from edge_depth.runner import Runner
    from edge_depth.runtime.engine import Engine
    from edge_depth.runtime.options import EngineOptions

    source = SimSource(4, SEED, RIG, period_ms=1000 / 30, motion=KINDS["forward"],
                       scan_every=3)
    events = list(source)  # scan 0, frames 0, 1, 2, scan 3, frame 3 (and their truths)
    frames = [e for e in events if isinstance(e, StereoFrame)]
    scans = [e for e in events if isinstance(e, LidarScan)]
    pipeline = Pipeline(Engine(options=EngineOptions(rate="camera", precision="int8",
                                                     threads=2)), *source.calibration)
    runner = Runner(source, pipeline, threaded=True)  # its events are fed here instead
    pipeline.on_scan(replace(scans[0], stamp_ns=scans[0].stamp_ns - 100_000_000))
    pipeline.on_scan(scans[0])  # two revolutions: the LiDAR's period is known

    def live(frame):
        waited = runner._wait_for_lidar(frame)
        prepared = pipeline.prepare(frame, None, waited, arrived=time.perf_counter())
        return waited, prepared, pipeline.infer(prepared)

    _, _, key = live(frames[0])
    _, same_scan, _ = live(frames[1])
    assert key.iterations > 0 and same_scan.carried and not same_scan.ahead
    waited, before_scan, _ = live(frames[2])
    assert before_scan.ahead and before_scan.carried
    assert before_scan.points is None  # not paired with the old scan, nor counted unpaired
    sync = pipeline.sync.counters()
    assert (sync["frames_with_lidar"], sync["frames_without_lidar"]) == (2, 0)
    assert waited < 0.25 * pipeline.sync.config.wait_ms  # not held for the next scan
    pipeline.on_scan(scans[1])
    _, after_scan, result = live(frames[3])
    assert not after_scan.carried and result.iterations > 0  # the next key frame
    assert pipeline.propagator.counters() == dict(key_frames=2, carried=2, lost=0, scaled=2,
                                                  scans=2, ahead=1)
    assert pipeline.ahead_frames == 1

    # only the frames before the next scan is due, less half a frame period, go ahead: the
    # scan's own frame waits for it (a camera as fast as the LiDAR: every frame)
    due = scans[1].stamp_ns + 100_000_000
    assert pipeline.goes_ahead(due - 40_000_000) and not pipeline.goes_ahead(due - 10_000_000)
    # behind (the next scan already in when the frame before it is taken) the same frame is
    # carried: the key frames do not depend on when a scan arrives
    pipeline.on_scan(replace(scans[1], stamp_ns=due))
    ahead = pipeline.prepare(replace(frames[3], stamp_ns=due - 40_000_000, seq=5), None)
    assert ahead.ahead and ahead.points is None
    # a new calibration between a frame's preparation and its inference drops the key frame:
    # the frame that went ahead runs the engine, with the scans paired then, instead of
    # failing (so does one whose flow is lost)
    assert pipeline.ahead_frames == 2
    pipeline.set_calibration(pipeline.stereo, pipeline.lidar)
    assert pipeline.infer(ahead).iterations > 0 and not ahead.carried
    assert ahead.points is not None and ahead.points_stamp_ns == due
    assert pipeline.ahead_frames == 1  # counted as paired instead


def test_at_the_camera_rate_no_frame_goes_ahead_without_a_spinning_lidars_scans():
    """Accumulated points (a 2-D scanner) or a key frame without a scan (none yet, a stalled
    LiDAR): every frame waits or is a key frame, as at the LiDAR's rate."""
    from edge_depth.capture.sync import LidarSync, SyncConfig
    from edge_depth.daemon import Pipeline
    from edge_depth.runtime.engine import Engine
    from edge_depth.runtime.options import EngineOptions

    source = SimSource(3, SEED, RIG, period_ms=1000 / 30, motion=KINDS["forward"],
                       scan_every=3)
    frames = [e for e in source if isinstance(e, StereoFrame)]
    pipeline = Pipeline(Engine(options=EngineOptions(rate="camera", precision="int8",
                                                     threads=2)), *source.calibration)
    def two_scans():  # two revolutions: the LiDAR's period is known
        for stamp in (-105_000_000, -5_000_000):
            pipeline.on_scan(LidarScan(frames[0].stamp_ns + stamp,
                                       np.array([[0.0, 0.0, 5.0]], np.float32)))

    two_scans()
    for frame in frames[:2]:
        pipeline.prepare(frame, None)  # the camera's period
    shape = (RIG.height, RIG.width)
    result = DepthResult(0, np.ones(shape, np.float32), np.ones(shape, np.float32),
                         np.ones(shape, bool), 1)
    later = frames[1].stamp_ns + 30_000_000
    pipeline.propagator.key(frames[0].stamp_ns, frames[0].stamp_ns - 5_000_000,
                            frames[0].left, result)
    assert pipeline.goes_ahead(later)
    pipeline.propagator.key(frames[0].stamp_ns, None, frames[0].left, result)  # no scan
    assert not pipeline.goes_ahead(later)
    pipeline.propagator.key(frames[0].stamp_ns, frames[0].stamp_ns - 5_000_000,
                            frames[0].left, result)
    pipeline.sync = LidarSync(SyncConfig(mode="accumulate"))
    two_scans()
    assert pipeline.sync.period_ns() > 0 and not pipeline.goes_ahead(later)


def test_the_cameras_period_holds_while_every_other_frame_is_dropped():
    from edge_depth.daemon import _frame_period

    assert _frame_period([0, 33, 100, 133, 200, 233, 300]) == 33  # half the gaps are drops
    assert _frame_period([0, 33, 66, 66, 99]) == 33 and _frame_period([5]) == 0.0
