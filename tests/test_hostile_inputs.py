"""Inputs that pass every range check and still ruin the output, or break a reader: each
ends in one line naming the property, or is read whole, or is reported in /diagnostics."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from edge_depth.calibration.errors import CalibrationFileError
from edge_depth.calibration.io import dumps_calibration, load_calibration
from edge_depth.calibration.model import LidarExtrinsics, StereoCalibration
from edge_depth.cli import main
from edge_depth.sim.lidar import default_T_cam_lidar
from tests.test_daemon_config import SIM, write


def _calibration_text() -> str:
    K = np.array([[452.0, 0, 322.0], [0, 451.0, 198.0], [0, 0, 1]])
    stereo = StereoCalibration(K, [-0.1, 0.02, 0.0, 0.0, 0.0], K.copy(),
                               [-0.09, 0.015, 0.0, 0.0, 0.0], np.eye(3), [-0.075, 0.0, 0.0],
                               (640, 400))
    return dumps_calibration(stereo, LidarExtrinsics(default_T_cam_lidar()))


def _t_row(text: str, value: str) -> str:
    """The LiDAR translation's x set to `value` (the first row of T_cam_lidar)."""
    head, rows = text.split("T_cam_lidar = ")
    first = rows.index("],")
    row = rows[2:first].split(", ")
    row[3] = value
    return head + "T_cam_lidar = [[" + ", ".join(row) + rows[first:]


@pytest.mark.parametrize("edit, key, words", [
    (lambda t: t.replace("dist = [-0.1,", "dist = [-450.0,"), "stereo.left.dist",
     "does not cover the image"),
    (lambda t: t.replace("dist = [-0.1,", "dist = [-5.0,"), "stereo.left.dist",
     "rectified view reads"),
    (lambda t: t.replace("K = [[452.0, 0.0,", "K = [[452.0, 10000000000.0,"), "stereo.left.K",
     "skew near zero"),
    (lambda t: _t_row(t, "1e308"), "lidar.T_cam_lidar", "within 10 m of the camera"),
])
def test_a_calibration_that_cannot_make_an_image_is_refused_naming_the_property(
        tmp_path, edit, key, words):
    path = tmp_path / "calib.toml"
    path.write_text(edit(_calibration_text()))
    with pytest.raises(CalibrationFileError) as info:
        load_calibration(path)
    message = str(info.value)
    assert f"{path}: {key}:" in message and words in message and "\n" not in message


def test_replay_refuses_such_a_calibration_in_one_line_before_any_frame(recording, tmp_path,
                                                                       capsys):
    calib = tmp_path / "calib.toml"
    calib.write_text(_calibration_text().replace("dist = [-0.1,", "dist = [-450.0,"))
    out = tmp_path / "out.mcap"
    assert main(["replay", str(recording), "--calib", str(calib), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert "does not cover the image" in line and str(calib) in line
    assert "frame" not in captured.out and not out.exists()


def test_real_lenses_still_pass():
    """Barrel and pincushion within what lenses have, a rational model, a small skew."""
    K = np.array([[452.0, 0.5, 322.0], [0, 451.0, 198.0], [0, 0, 1]])
    for dist in ([-0.35, 0.12, 0.001, -0.001, -0.02], [0.2, -0.05, 0, 0, 0],
                 [2.1, 0.8, 0, 0, 0.01, 2.4, 1.2, 0.1]):
        StereoCalibration(K, dist, K.copy(), dist, np.eye(3), [-0.075, 0.0, 0.0], (640, 400))


DEEP = "a = " + "[" * 5000 + "]" * 5000 + "\n"


@pytest.mark.parametrize("command", ["calibration", "config", "topics"])
def test_a_deeply_nested_toml_is_one_line_and_exit_1(recording, tmp_path, capsys, command):
    bad = write(tmp_path, DEEP, "deep.toml")
    argv = {"calibration": ["replay", str(recording), "--calib", str(bad), "--out",
                            str(tmp_path / "o.mcap")],
            "config": ["run", "--config", str(bad), "--max-frames", "1"],
            "topics": ["replay", str(recording), "--topics", str(bad), "--out",
                       str(tmp_path / "o.mcap")]}[command]
    assert main(argv) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert str(bad) in line and "nested too deeply" in line


def test_a_config_far_larger_than_a_settings_file_is_refused(tmp_path, capsys):
    cfg = write(tmp_path, SIM.format(out=tmp_path / "o.mcap") + "#" * (2 << 20) + "\n")
    assert main(["run", "--config", str(cfg), "--max-frames", "1"]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert str(cfg) in line and "larger than 1024 KiB" in line


def test_configs_a_user_wants_told_about_are_warned_or_refused(tmp_path, caplog, monkeypatch):
    from edge_depth.config import load_robot_config
    from edge_depth.errors import ConfigError

    monkeypatch.setattr("os.cpu_count", lambda: 2)
    cfg = load_robot_config(write(tmp_path, f"[engine]\nthreads = 64\n[log]\nout = "
                                            f"'{tmp_path}'\n"))
    assert cfg.log.out == str(tmp_path / "depth.mcap")
    warned = [r.getMessage() for r in caplog.records]
    assert any("engine.threads = 64 on a machine with 2 cores" in m for m in warned)
    assert any(f"log.out = '{tmp_path}' is a directory" in m for m in warned)
    with pytest.raises(ConfigError, match=r"robot.toml: camera.size: expected 64"):
        load_robot_config(write(tmp_path, "[camera]\nsize = [16, 16]\n"))


def test_an_engine_error_from_the_config_names_the_file_and_the_key(tmp_path, capsys):
    cfg = write(tmp_path, SIM.format(out=tmp_path / "o.mcap") + "[engine]\nscale = 3.0\n")
    assert main(["run", "--config", str(cfg), "--max-frames", "1"]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{cfg}: engine.scale:" in line


def _small_recording(path: Path) -> list[int]:
    """Six frames in chunks of ~4 kB; returns the chunks' start offsets."""
    from mcap.reader import make_reader

    from edge_depth.mcap_log import RAW_TOPICS, McapLogger
    from edge_depth.sim import RigConfig, make_sample

    samples = [make_sample(1_000_000 + i, RigConfig(width=96, height=64)) for i in range(6)]
    with McapLogger(path, topics=RAW_TOPICS, chunk_size=4096,
                    calibration_toml=dumps_calibration(samples[0].calibration())) as logger:
        for i, s in enumerate(samples):
            logger.log_frame(s.frame(10**9 + i * 10**8, i))
    with open(path, "rb") as f:
        return [c.chunk_start_offset for c in make_reader(f).get_summary().chunk_indexes]


def _frames(path: Path):
    from edge_depth.capture.replay import McapSource
    from edge_depth.types import StereoFrame

    source = McapSource(path)
    return [e.stamp_ns for e in source if isinstance(e, StereoFrame)], source.stats.errors


@pytest.mark.parametrize("summary", [True, False])
def test_chunks_out_of_order_replay_every_frame(tmp_path, summary):
    path = tmp_path / "rec.mcap"
    starts = _small_recording(path)
    raw = path.read_bytes()
    first, second = raw[starts[0]:starts[1]], raw[starts[1]:starts[2]]
    swapped = raw[:starts[0]] + second + first + raw[starts[2]:]
    if not summary:  # cut before the summary: channels are only declared inside chunks
        swapped = swapped[:starts[-1]]
    path.write_bytes(swapped)
    stamps, errors = _frames(path)
    assert len(stamps) == (6 if summary else 5)  # the last chunk went with the summary
    assert not [k for k in errors if "channel" in k]


def test_a_chunk_stored_twice_is_read_once_and_said_so(tmp_path, caplog):
    path = tmp_path / "rec.mcap"
    starts = _small_recording(path)
    raw = path.read_bytes()
    path.write_bytes(raw[:starts[3]] + raw[starts[0]:starts[1]] + raw[starts[3]:])
    stamps, errors = _frames(path)
    assert len(stamps) == 6 and errors["chunk stored twice (read once)"] == 1
    assert "repeat an earlier chunk byte for byte" in caplog.text
    assert "stamps are zero" not in caplog.text


def test_an_all_invalid_output_raises_the_health_level_and_names_the_cause(
        recording, tmp_path, capsys, monkeypatch):
    """A rectification that reads outside the image (black) and a NaN disparity on every
    frame, as a lens model of k1 = -450 gave before it was refused: /diagnostics reaches
    ERROR and the summary names the calibration."""
    from dataclasses import replace

    from mcap.reader import make_reader

    from edge_depth.calibration.model import Rectifier
    from edge_depth.mcap_log import TOPICS
    from edge_depth.runtime.engine import Engine

    infer = Engine.infer

    def broken(self, *args, **kwargs):
        result = infer(self, *args, **kwargs)
        return replace(result, disparity=np.full_like(result.disparity, np.nan))

    monkeypatch.setattr(Engine, "infer", broken)
    monkeypatch.setattr(Rectifier, "pair",
                        lambda self, frame: (np.zeros_like(frame.left), frame.right))
    out = tmp_path / "out.mcap"
    assert main(["replay", str(recording), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"output health ERROR: 100 % of the depth map invalid .*likely cause: the "
                     r"calibration", printed)
    with open(out, "rb") as f:
        reports = [json.loads(m.data) for _, _, m in
                   make_reader(f).iter_messages(topics=[TOPICS["diagnostics"]])]
    assert reports and reports[-1]["output_health"]["level"] == "ERROR"


def test_a_small_disk_keeps_the_frame_in_hand(tmp_path, monkeypatch, capsys):
    """A 16 MiB disk: frames are written until its reserve (an eighth of it) is reached; the
    frame in hand then goes in whole before the file closes."""
    from collections import namedtuple

    import edge_depth.mcap_log as mcap_log
    from edge_depth.mcap_log import TOPICS
    from tests.test_pipeline_mcap import topic_counts

    usage = namedtuple("usage", "total used free")
    calls = []

    def disk_usage(path):
        calls.append(path)
        free = 8 * 2**20 if len(calls) <= 6 else 1 * 2**20
        return usage(16 * 2**20, 16 * 2**20 - free, free)

    monkeypatch.setattr(mcap_log.shutil, "disk_usage", disk_usage)
    out = tmp_path / "depth.mcap"
    assert main(["run", "--config", str(write(tmp_path, SIM.format(out=out))),
                 "--max-frames", "20"]) == 1
    assert "below 2 MB): wrote the frame in hand" in capsys.readouterr().err
    counts = topic_counts(out)
    assert counts[TOPICS["disparity"]] == counts[TOPICS["left"]] >= 2


def test_a_healthy_replay_stays_ok(recording, tmp_path, capsys):
    from mcap.reader import make_reader

    from edge_depth.mcap_log import TOPICS

    out = tmp_path / "out.mcap"
    assert main(["replay", str(recording), "--out", str(out)]) == 0
    assert "output health" not in capsys.readouterr().out
    with open(out, "rb") as f:
        (report,) = [json.loads(m.data) for _, _, m in
                     make_reader(f).iter_messages(topics=[TOPICS["diagnostics"]])][-1:]
    assert report["output_health"]["level"] == "OK"
    assert report["output_health"]["invalid_pct"] < 1.0
