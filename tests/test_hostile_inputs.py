"""Inputs that pass every range check and still ruin the output, or break a reader: each
ends in one line naming the property, or is read whole, or is reported in /diagnostics."""

from __future__ import annotations

import ast
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


def test_a_disk_low_on_space_stops_before_a_frame_and_closes_with_every_frame_whole(
        tmp_path, monkeypatch, capsys):
    """A 64 MiB disk whose free space drops from 32 to 3 MiB: the frames before are written
    whole (images and result), the next is not begun, the file closes with its summary and
    the message says how many frames it holds."""
    from collections import namedtuple

    import edge_depth.disk_reserve as disk_reserve
    from edge_depth.mcap_log import TOPICS
    from tests.test_pipeline_mcap import topic_counts

    usage = namedtuple("usage", "total used free")
    calls = []

    def disk_usage(path):  # one call a frame
        calls.append(path)
        free = 32 * 2**20 if len(calls) <= 3 else 3 * 2**20
        return usage(64 * 2**20, 64 * 2**20 - free, free)

    monkeypatch.setattr(disk_reserve.shutil, "disk_usage", disk_usage)
    import edge_depth.mcap_log as mcap_log  # the frames' checks only: not the scans' own

    monkeypatch.setattr(mcap_log.McapLogger, "_scan_space_low", lambda self: False)
    out = tmp_path / "depth.mcap"
    assert main(["run", "--config", str(write(tmp_path, SIM.format(out=out))),
                 "--max-frames", "20"]) == 1
    err = capsys.readouterr().err
    assert "is full (3 MB free" in err and f"closed {out} with its summary (3 frames)" in err
    counts = topic_counts(out)
    assert counts[TOPICS["disparity"]] == counts[TOPICS["left"]] == 3


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


def _rewritten(src: Path, dst: Path, change) -> Path:
    """A copy of the recording `src` at `dst`, each message's (log time, data) replaced by
    change(topic, message)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f_in, open(dst, "wb") as f_out:
        writer, schemas, channels = Writer(f_out), {}, {}
        writer.start()
        for schema, channel, message in make_reader(f_in).iter_messages():
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding,
                                                            schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id])
            log_time, data = change(channel.topic, message)
            writer.add_message(channels[channel.id], log_time=log_time, data=data,
                               publish_time=log_time)
        writer.finish()
    return dst


def test_a_damaged_first_chunk_is_named_before_a_calibration_is_asked_for(tmp_path, capsys):
    """The chunk that held the calibration is damaged: the error says where and what, not
    that the recording has none; with --calib the rest replays, the damage counted."""
    from edge_depth.sim import RigConfig, make_sample

    path = tmp_path / "rec.mcap"
    starts = _small_recording(path)
    raw = bytearray(path.read_bytes())
    raw[(starts[0] + starts[1]) // 2] ^= 0xFF
    path.write_bytes(bytes(raw))
    assert main(["replay", str(path), "--out", str(tmp_path / "out.mcap")]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"edge-depth replay: error: {path}: no calibration could be read: "
                           f"damaged data at byte {starts[0]} (chunk: ")
    assert "--calib" in line and "neither" not in line
    calib = tmp_path / "calib.toml"
    calib.write_text(dumps_calibration(make_sample(1_000_000, RigConfig(width=96, height=64))
                                       .calibration()))
    assert main(["replay", str(path), "--out", str(tmp_path / "out.mcap"), "--calib",
                 str(calib)]) == 0
    printed = capsys.readouterr().out
    frames = int(re.search(r"^(\d+) frames, ", printed, re.M)[1])
    assert 0 < frames < 6
    assert f"skipped while reading: {{'damaged data at byte {starts[0]} (chunk: " in printed


def test_an_unreadable_calibration_message_is_named_not_replaced_silently(recording, tmp_path,
                                                                          capsys, caplog):
    """/edge/calibration that does not decode: the CameraInfo pair stands in with a warning
    naming the topic and why, and the missing LiDAR extrinsics are blamed on it."""
    from edge_depth.mcap_log import TOPICS

    path = _rewritten(recording, tmp_path / "rec.mcap", lambda topic, m: (
        m.log_time, b"\xffnot JSON" if topic == TOPICS["calibration_file"] else m.data))
    assert main(["replay", str(path), "--out", str(tmp_path / "out.mcap")]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert ("used because its /edge/calibration message is unreadable (UnicodeDecodeError: "
            in line and "has no LiDAR extrinsics" in line)
    assert ("its /edge/calibration message is unreadable (UnicodeDecodeError: " in caplog.text
            and "using the CameraInfo pair instead" in caplog.text)


def test_a_replay_that_processes_no_frame_says_why_and_claims_no_file(tmp_path, capsys):
    """Every image's stamp out of range: the error names the first skip, the summary's counts
    agree with the list below them, and the output (scans and calibration only) is gone."""
    from edge_depth.mcap_log import TOPICS

    small = tmp_path / "small.mcap"
    _small_recording(small)
    images = (TOPICS["left"], TOPICS["right"])
    path = _rewritten(small, tmp_path / "rec.mcap", lambda topic, m: (
        m.log_time + (2**33 * 10**9 if topic in images else 0), m.data))
    out = tmp_path / "out.mcap"
    assert main(["replay", str(path), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.err.startswith("error: no frame was processed (skipped: 12 while reading, "
                                   "0 in the pipeline; the first: /stereo/left/image_rect: "
                                   "stamp ")
    lines = captured.out.splitlines()
    assert lines[0] == "0 frames, 0 scans, 0 dropped; skipped: 12 while reading, 0 in the pipeline"
    listed = ast.literal_eval(lines[1].removeprefix("skipped while reading: "))
    assert sum(listed.values()) == 12 and all("out of range" in k for k in listed)
    assert "wrote nothing: no frame was processed" in captured.out
    assert f"wrote {out}" not in captured.out and not out.exists()


@pytest.mark.parametrize("command", ["replay", "record"])
def test_an_out_that_cannot_be_written_is_named_before_the_engine_loads(
        recording, tmp_path, capsys, monkeypatch, command):
    import edge_depth.commands

    def no_engine(*args, **kwargs):
        raise AssertionError("the engine loaded before the output was checked")

    monkeypatch.setattr(edge_depth.commands, "Engine", no_engine)
    (tmp_path / "taken").write_text("a file where a folder would go")
    out = tmp_path / "taken" / "out.mcap"
    args = ([str(recording)] if command == "replay"
            else ["--config", str(write(tmp_path, SIM.format(out=tmp_path / "log.mcap")))])
    assert main([command, *args, "--out", str(out)]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (f"edge-depth {command}: error: --out: expected a path in a folder that can "
                    f"be written ({tmp_path / 'taken'} is a file, not a folder), got '{out}'")


def test_chunks_cut_out_of_a_recording_are_counted_as_lost(tmp_path, caplog):
    """Two chunks removed from the middle: the summary still counts their messages, and the
    replay says how many no chunk held."""
    from edge_depth.capture.replay import McapSource
    from edge_depth.types import StereoFrame

    path = tmp_path / "rec.mcap"
    starts = _small_recording(path)
    total = McapSource(path)
    list(total)
    raw = path.read_bytes()
    path.write_bytes(raw[:starts[4]] + raw[starts[6]:])
    source = McapSource(path)
    frames = [e for e in source if isinstance(e, StereoFrame)]
    assert 0 < len(frames) < 6
    missing = total.stats.messages - source.stats.messages
    assert missing > 0
    assert source.stats.lost == [f"{missing} messages the summary counts are in no readable "
                                 "chunk"]
    assert "no readable chunk holds" in caplog.text
