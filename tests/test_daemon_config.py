"""`edge-depth run` / `record` and the robot configuration file."""

from __future__ import annotations

import re

import numpy as np
import pytest

from edge_depth.capture.replay import McapSource
from edge_depth.cli import main
from edge_depth.config import load_robot_config
from edge_depth.errors import ConfigError
from edge_depth.mcap_log import TOPICS
from edge_depth.types import StereoFrame
from tests.test_pipeline_mcap import topic_counts

SIM = """
[camera]
source = "sim"
fps = 20.0
[lidar]
model = "sim"
[sync]
mode = "nearest"
[log]
out = "{out}"
rotate_mb = 0.0
queue = 8                      # a loaded host drops no frame of the few a test asks for
"""


def write(tmp_path, text, name="robot.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("text, key", [
    ("[camera]\nsource = 'usb'\n", "camera.source"),
    ("[camera]\nfps = 'fast'\n", "camera.fps"),
    ("[camera]\nsize = [640]\n", "camera.size"),
    ("[engine]\nthreads = 0\n", "engine.threads"),
    ("[engine]\nbatch = 4\n", "engine.batch"),
    ("[motors]\n", "motors"),
    ("[camera]\nsource = 'oak'\n[lidar]\nmodel = 'sim'\n", "lidar.model"),
    ("[lidar]\nsim_pattern = 'velodyne'\n", "lidar.sim_pattern"),
    ("[camera]\nsim_motion = 'spin'\n", "camera.sim_motion"),
    ("[lidar]\nsim_every = 0\n", "lidar.sim_every"),
    ("[camera]\nsource = 'sim'\n[lidar]\nmodel = 'sim'\nsim_every = 3\n", "lidar.sim_every"),
    # values that are the right type but cannot be meant (tracebacks or hangs)
    ("[camera]\nfps = 1e-300\n", "camera.fps"),
    ("[camera]\nfps = 1e-3\n", "camera.fps"),
    ("[camera]\nsize = [100000, 400]\n", "camera.size"),
    ("[engine]\nthreads = 1099511627776\n", "engine.threads"),
    ("[engine]\niters = 1000000000\n", "engine.iters"),
    ("[engine]\nscale = nan\n", "engine.scale"),
    ("[sync]\nwindow_ms = inf\n", "sync.window_ms"),
    ("[log]\nrotate_mb = nan\n", "log.rotate_mb"),
    ("[log]\nrotate_mb = inf\n", "log.rotate_mb"),
    ("[log]\nrotate_mb = -1.0\n", "log.rotate_mb"),
    ("[log]\nrotate_mb = 0.000001\n", "log.rotate_mb"),
    ("[log]\nrotate_s = -5.0\n", "log.rotate_s"),
    ("[log]\nout = ''\n", "log.out"),
    ("[log]\nout = '/dev/null'\n", "log.out"),
])
def test_config_errors_name_the_file_and_the_key(tmp_path, text, key):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_robot_config(path)
    assert info.value.key == key and str(path) in str(info.value)


def test_defaults_and_values_load():
    import tomllib

    cfg = load_robot_config.__globals__["RobotConfig"]()
    assert cfg.camera.size == (640, 400) and cfg.engine.precision == "auto"
    text = "[camera]\nsize = [320, 200]\n[log]\nraw = false\n"
    assert tomllib.loads(text)  # valid TOML


def test_a_missing_calibration_key_stops_before_any_device_opens(tmp_path, monkeypatch,
                                                                capsys):
    import edge_depth.capture.oak as oak
    import edge_depth.capture.serial_lidar as serial_lidar

    def refuse(*args, **kwargs):
        raise AssertionError("a device was opened")

    monkeypatch.setattr(oak.OakSource, "__init__", refuse)
    monkeypatch.setattr(serial_lidar.SerialLidarSource, "__init__", refuse)
    calib = write(tmp_path, "[stereo]\nimage_size = [640, 400]\n", "calib.toml")
    cfg = write(tmp_path, f"[camera]\nsource = 'oak'\n[calibration]\nfile = '{calib}'\n")
    assert main(["run", "--config", str(cfg)]) == 1
    err = capsys.readouterr().err
    assert str(calib) in err and "stereo" in err


def test_run_on_the_virtual_robot_logs_results_and_diagnostics(tmp_path, capsys):
    out = tmp_path / "depth.mcap"
    cfg = write(tmp_path, SIM.format(out=out))
    assert main(["run", "--config", str(cfg), "--max-frames", "3"]) == 0
    text = capsys.readouterr().out
    assert "3 frames" in text and "errors none" in text
    # the shipped bundle's LiDAR selection says how much it replaced
    share = re.search(r"LiDAR selection: replaced a median ([0-9.]+) % of each frame's "
                      r"pixels \(p95 ([0-9.]+) %; none in 0 of 3 frames\)", text)
    assert share and 0 < float(share[1]) <= float(share[2]) < 50
    counts = topic_counts(out)
    assert counts[TOPICS["disparity"]] == 3 and counts[TOPICS["depth"]] == 3
    assert counts[TOPICS["left"]] == 3 and counts[TOPICS["lidar"]] >= 3
    assert counts[TOPICS["diagnostics"]] >= 1


def test_the_log_writes_only_the_result_topics_asked_for(tmp_path, capsys, monkeypatch):
    from edge_depth import mcap_log

    built = []  # point clouds made: none when points are not written
    monkeypatch.setattr(mcap_log, "depth_to_points",
                        lambda *a, **k: built.append(1) or (np.zeros((0, 3)), None))
    out = tmp_path / "depth.mcap"
    cfg = write(tmp_path, SIM.format(out=out) + 'raw = false\nresults = ["depth", '
                '"diagnostics"]\n')
    assert load_robot_config(cfg).log.results == ("depth", "diagnostics")
    assert main(["run", "--config", str(cfg), "--max-frames", "2"]) == 0
    counts = topic_counts(out)
    assert counts[TOPICS["depth"]] == 2 and counts[TOPICS["diagnostics"]] >= 1
    assert not {TOPICS[k] for k in ("disparity", "sparse", "confidence", "points", "left")} \
        & set(counts)
    assert built == []
    bad = write(tmp_path, SIM.format(out=out) + 'results = ["depth", "dsiparity"]\n')
    with pytest.raises(ConfigError, match="log.results: expected a list of sparse, disparity"):
        load_robot_config(bad)


def test_a_planar_sim_lidar_makes_a_sparse_map_the_band_refines_around(tmp_path, capsys):
    from edge_depth.sim.lidar import PATTERNS

    assert set(load_robot_config.__globals__["CHOICES"][("lidar", "sim_pattern")]) == \
        set(PATTERNS)
    cfg = write(tmp_path, SIM.format(out=tmp_path / "depth.mcap").replace(
        'model = "sim"', 'model = "sim"\nsim_pattern = "planar"'))
    assert main(["run", "--config", str(cfg), "--max-frames", "3"]) == 0
    text = capsys.readouterr().out
    # one scan line leaves most of the frame far from every point: the network is unsure
    # there, and the band refines it
    refined = re.search(r"Band refinement: replaced a median ([0-9.]+) % of each frame's "
                        r"pixels \(p95 [0-9.]+ %; none in 0 of ([0-9]) frames\)", text)
    assert refined and float(refined[1]) > 0.5 and int(refined[2]) >= 1


def test_record_then_replay(tmp_path, capsys):
    rec = tmp_path / "rec.mcap"
    cfg = write(tmp_path, SIM.format(out=tmp_path / "unused.mcap"))
    assert main(["record", "--config", str(cfg), "--out", str(rec), "--max-frames", "2"]) == 0
    assert "recorded 2 frames" in capsys.readouterr().out
    frames = [e for e in McapSource(rec) if isinstance(e, StereoFrame)]
    assert len(frames) == 2 and frames[0].left.shape == (400, 640)
    assert main(["replay", str(rec), "--out", str(tmp_path / "out.mcap")]) == 0
    assert "2 frames" in capsys.readouterr().out


def test_sync_max_wait_reaches_the_config_and_is_validated(tmp_path):
    from edge_depth.config import load_robot_config

    path = tmp_path / "robot.toml"
    path.write_text("[sync]\nmax_wait_ms = 50.0\n")
    assert load_robot_config(path).sync.max_wait_ms == 50.0
    path.write_text("[sync]\nmax_wait_ms = 'long'\n")
    with pytest.raises(ConfigError, match="max_wait_ms"):
        load_robot_config(path)


def test_sync_mode_auto_follows_the_lidar_model(tmp_path):
    """A spinning 3-D LiDAR (the sim's) pairs by its nearest revolution, a 2-D scanner by
    accumulating its points; an explicit mode wins."""
    from edge_depth.config import sync_mode

    path = tmp_path / "robot.toml"
    for model, mode in (("sim", "nearest"), ("ld06", "accumulate"), ("ld19", "accumulate"),
                        ("rplidar-a1", "accumulate"), ("none", "accumulate")):
        camera = "sim" if model == "sim" else "oak"
        path.write_text(f"[camera]\nsource = '{camera}'\n[lidar]\nmodel = '{model}'\n")
        config = load_robot_config(path)
        assert config.sync.mode == "auto" and sync_mode(config) == mode, model
    path.write_text("[camera]\nsource = 'sim'\n[lidar]\nmodel = 'sim'\n[sync]\n"
                    "mode = 'accumulate'\n")
    assert sync_mode(load_robot_config(path)) == "accumulate"
    path.write_text("[sync]\nmode = 'closest'\n")
    with pytest.raises(ConfigError, match="sync.mode"):
        load_robot_config(path)


def test_version_and_log_level_flags(capsys):
    import logging

    from edge_depth.cli import configure_logging, main

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.startswith("edge-depth ")
    configure_logging(quiet=True)
    assert logging.getLogger().level == logging.WARNING
    configure_logging(verbose=True)
    assert logging.getLogger().level == logging.DEBUG
    configure_logging()
    assert logging.getLogger().level == logging.INFO


def test_relative_paths_in_a_config_are_relative_to_the_file(tmp_path):
    from edge_depth.config import load_robot_config

    folder = tmp_path / "etc"
    folder.mkdir()
    path = folder / "robot.toml"
    path.write_text('[calibration]\nfile = "calib.toml"\n[engine]\nbundle = "/opt/b"\n'
                    '[log]\nout = "logs/depth.mcap"\n')
    config = load_robot_config(path)
    assert config.calibration.file == str(folder / "calib.toml")
    assert config.engine.bundle == "/opt/b"
    assert config.log.out == str(folder / "logs" / "depth.mcap")


def test_ctrl_c_before_the_handlers_is_one_line_and_exit_130(monkeypatch, capsys):
    import edge_depth.sim.export
    from edge_depth.cli import main

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(edge_depth.sim.export, "synth_command", interrupted)
    assert main(["synth", "--out", "unused", "--count", "1"]) == 130
    assert capsys.readouterr().err.strip() == "edge-depth synth: interrupted"


def test_a_camera_size_the_calibration_does_not_have_stops_at_the_first_frame(tmp_path,
                                                                             capsys):
    from edge_depth.calibration.io import save_calibration
    from edge_depth.capture.sim import SimSource

    calib = tmp_path / "calib.toml"
    save_calibration(calib, *SimSource(1).calibration)  # 640x400
    out = tmp_path / "depth.mcap"
    text = SIM.format(out=out).replace("fps = 20.0\n", "fps = 20.0\nsize = [320, 200]\n")
    cfg = write(tmp_path, text + f'[calibration]\nfile = "{calib}"\n')
    assert main(["run", "--config", str(cfg), "--max-frames", "3"]) == 1
    captured = capsys.readouterr()
    assert "0 frames" in captured.out
    assert "the camera's frames are 320x200 but the calibration is for 640x400" in captured.err


def test_no_calibration_file_on_an_oak_uses_its_factory_calibration(tmp_path, monkeypatch,
                                                                   caplog):
    import logging

    import edge_depth.calibration.oak as oak_calibration
    from edge_depth.calibration.model import StereoCalibration
    from edge_depth.commands import open_sources

    asked = []

    def factory(eeprom_json, size):
        asked.append(size)
        return StereoCalibration.ideal(400.0, 0.075, size)

    monkeypatch.setattr(oak_calibration, "stereo_from_oak", factory)
    caplog.set_level(logging.INFO)
    cfg = load_robot_config(write(tmp_path, "[camera]\nsource = 'oak'\nsize = [640, 480]\n"
                                  "[lidar]\nmodel = 'none'\n"))
    source, stereo, lidar = open_sources(cfg)
    assert asked == [(640, 480)] and stereo.image_size == (640, 480) and lidar is None
    assert "the OAK's factory calibration at 640x480" in caplog.text
    # a LiDAR needs extrinsics, which the factory calibration does not have
    cfg = load_robot_config(write(tmp_path, "[camera]\nsource = 'oak'\n[lidar]\n"
                                  "model = 'ld06'\n"))
    with pytest.raises(ConfigError, match="lidar.model.*calibrate lidar"):
        open_sources(cfg)


def test_a_config_that_is_not_utf8_or_points_log_out_at_a_folder(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_bytes(b"[camera]\nsource = 'sim'\n# caf\xe9\n")
    with pytest.raises(ConfigError, match="UTF-8"):
        load_robot_config(path)
    logs = tmp_path / "logs"
    logs.mkdir()
    path.write_text(f"[log]\nout = '{logs}'\n")
    assert load_robot_config(path).log.out == str(logs / "depth.mcap")  # files inside it
    path.write_text("[log]\nrotate_mb = 0.0\nrotate_s = 0.0\n")  # 0 = never rotate
    assert load_robot_config(path).log.rotate_mb == 0.0


@pytest.mark.parametrize("damage", ["empty model.json", "model.json without keys",
                                    "garbage ONNX"])
def test_a_damaged_bundle_is_one_line_naming_it(tmp_path, capsys, damage):
    import shutil

    from edge_depth.runtime.engine import DEFAULT_BUNDLE

    bundle = tmp_path / "bundle"
    shutil.copytree(DEFAULT_BUNDLE, bundle)
    if damage == "empty model.json":
        (bundle / "model.json").write_text("")
    elif damage == "model.json without keys":
        (bundle / "model.json").write_text("{}")
    else:
        (bundle / "step.int8.onnx").write_bytes(b"\x08\x07garbage" * 100)
    out = tmp_path / "depth.mcap"
    cfg = write(tmp_path, SIM.format(out=out) + f'[engine]\nbundle = "{bundle}"\n')
    assert main(["run", "--config", str(cfg), "--max-frames", "1"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bundle" in err and "Traceback" not in err


def test_a_disk_that_fills_closes_the_file_complete_and_exits_1(tmp_path, monkeypatch,
                                                                capsys, caplog):
    from collections import namedtuple

    from mcap.reader import make_reader

    import edge_depth.disk_reserve as disk_reserve

    usage = namedtuple("usage", "total used free")
    calls = []

    def disk_usage(path):  # plenty for the first frames, then 10 MB
        calls.append(path)
        free = 10 * 2**30 if len(calls) <= 4 else 10 * 2**20
        return usage(20 * 2**30, 20 * 2**30 - free, free)

    monkeypatch.setattr(disk_reserve.shutil, "disk_usage", disk_usage)
    out = tmp_path / "depth.mcap"
    cfg = write(tmp_path, SIM.format(out=out))
    assert main(["run", "--config", str(cfg), "--max-frames", "20"]) == 1
    captured = capsys.readouterr()
    assert "is full (10 MB free, below 64 MB)" in captured.err
    assert caplog.text.count("is full") == 1  # said once
    frames = int(captured.out.split(" frames in")[0].split()[-1])
    assert 1 <= frames < 20  # it stopped instead of inferring on
    with open(out, "rb") as f:
        assert make_reader(f).get_summary() is not None  # closed cleanly, summary written
    assert topic_counts(out)[TOPICS["disparity"]] >= 1


def test_a_run_never_overwrites_an_existing_recording(tmp_path, capsys):
    out = tmp_path / "depth.mcap"
    out.write_bytes(b"an earlier run's recording")
    cfg = write(tmp_path, SIM.format(out=out))  # rotate_mb = 0: one file
    assert main(["run", "--config", str(cfg), "--max-frames", "1"]) == 0
    assert out.read_bytes() == b"an earlier run's recording"
    assert (tmp_path / "depth_0001.mcap").stat().st_size > 1000
    assert "depth_0001.mcap" in capsys.readouterr().out


@pytest.mark.parametrize("profile", ["ros2", "foxglove"])
def test_the_transform_tree_hangs_under_the_configured_parent(tmp_path, profile):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory as Protobuf
    from mcap_ros2.decoder import DecoderFactory as Ros2

    out = tmp_path / "depth.mcap"
    cfg = write(tmp_path, SIM.format(out=out) + 'profile = "' + profile + '"\n'
                'tf_parent_frame = "base_link"\n'
                'tf_parent_xyz_rpy = [0.1, 0.0, 0.3, 0.0, 0.0, 90.0]\n')
    assert main(["run", "--config", str(cfg), "--max-frames", "1"]) == 0
    topic = "/tf_static" if profile == "ros2" else "/tf"
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[Ros2(), Protobuf()])
        (msg,) = [m for _, _, _, m in reader.iter_decoded_messages(topics=[topic])]
    edges = {(t.parent_frame_id if profile == "foxglove" else t.header.frame_id,
              t.child_frame_id): t for t in msg.transforms}
    assert set(edges) == {("camera_left", "camera_right"), ("camera_left", "lidar"),
                          ("base_link", "camera_left")}
    base = edges[("base_link", "camera_left")]
    tr = base.translation if profile == "foxglove" else base.transform.translation
    q = base.rotation if profile == "foxglove" else base.transform.rotation
    assert (tr.x, tr.y, tr.z) == pytest.approx((0.1, 0.0, 0.3))
    assert (q.z, q.w) == pytest.approx((np.sqrt(0.5), np.sqrt(0.5)))  # 90 deg about z


def test_the_two_selections_are_summed_up_each_over_its_own_frames():
    from edge_depth.frame_summary import replaced_shares, selection_summary, summarise

    # frames with LiDAR run the LiDAR selection; the band refinement runs on every frame
    timings = [dict(engine=50.0, select=10.0, replaced_pct=2.0, refined_pct=5.0),
               dict(engine=40.0, band_refine=6.0, refined_pct=7.0),
               dict(engine=60.0, select=12.0, replaced_pct=0.0, refined_pct=9.0),
               dict(engine=45.0, band_refine=8.0)]
    lat = summarise(timings)
    assert set(lat) == {"engine", "select", "band_refine"}  # the shares are not latencies
    assert lat["select"]["median"] == 11.0 and lat["band_refine"]["median"] == 7.0
    assert lat["engine"]["median"] == 47.5
    assert replaced_shares(timings) == [2.0, 0.0]
    assert replaced_shares(timings, "refined_pct") == [5.0, 7.0, 9.0]
    assert selection_summary(timings).splitlines() == [
        "LiDAR selection: replaced a median 1.0 % of each frame's pixels (p95 1.9 %; none in 1 "
        "of 2 frames)",
        "Band refinement: replaced a median 7.0 % of each frame's pixels (p95 8.8 %; none in 0 "
        "of 3 frames)"]
    assert selection_summary([dict(engine=1.0)]) is None


@pytest.mark.parametrize("folder", ["taken", "/proc/edge"])
def test_a_log_out_that_cannot_be_written_names_the_file_and_the_key_before_the_engine_loads(
        tmp_path, capsys, monkeypatch, folder):
    """A log folder under a file, or one the system cannot create: one line naming the config
    file, log.out and the folder, exit 1, and no engine loaded."""
    import edge_depth.commands

    def no_engine(*args, **kwargs):
        raise AssertionError("the engine loaded before the output was checked")

    monkeypatch.setattr(edge_depth.commands, "Engine", no_engine)
    (tmp_path / "taken").write_text("a file where the log folder would go")
    out = tmp_path / folder / "depth.mcap"  # an absolute folder replaces tmp_path
    cfg = write(tmp_path, SIM.format(out=out))
    assert main(["run", "--config", str(cfg), "--max-frames", "1"]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    why = (f"{tmp_path / 'taken'} is a file, not a folder" if folder == "taken"
           else "/proc/edge: No such file or directory")
    assert line == (f"edge-depth run: error: {cfg}: log.out: expected a path in a folder that "
                    f"can be written ({why}), got '{out}'")
