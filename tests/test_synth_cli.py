"""`edge-depth synth` writes scene folders that read back exactly, or nothing at all."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from edge_depth.cli import main
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.folder import (
    SceneFolderError,
    list_scene_folders,
    read_pfm,
    read_scene_folder,
    write_pfm,
)


def test_pfm_round_trip_keeps_values_and_inf(tmp_path):
    image = np.arange(12, dtype=np.float32).reshape(3, 4) / 7
    image[1, 2] = np.inf
    write_pfm(tmp_path / "x.pfm", image)
    np.testing.assert_array_equal(read_pfm(tmp_path / "x.pfm"), image)


def test_truncated_pfm_is_a_clear_error(tmp_path):
    write_pfm(tmp_path / "x.pfm", np.ones((8, 8), np.float32))
    data = (tmp_path / "x.pfm").read_bytes()
    (tmp_path / "x.pfm").write_bytes(data[:-10])
    with pytest.raises(SceneFolderError, match="truncated"):
        read_pfm(tmp_path / "x.pfm")
    (tmp_path / "y.pfm").write_bytes(b"garbage")
    with pytest.raises(SceneFolderError, match="header"):
        read_pfm(tmp_path / "y.pfm")


def test_synth_writes_scene_folders_that_match_the_rig(tmp_path, capsys):
    out = tmp_path / "scenes"
    assert main(["synth", "--out", str(out), "--count", "2", "--seed", "5",
                 "--size", "96x64", "--lidar", "beams64"]) == 0
    folders = list_scene_folders(out)
    assert [f.name for f in folders] == ["000005", "000006"]
    scene = read_scene_folder(folders[0])
    rig = RigConfig(width=96, height=64)
    expected = make_sample(5, rig, "beams64")
    np.testing.assert_array_equal(scene.left, expected.left)
    np.testing.assert_array_equal(scene.right, expected.right)
    np.testing.assert_array_equal(scene.disp, expected.disp_left)
    np.testing.assert_array_equal(scene.occ, expected.occ_left)
    np.testing.assert_array_equal(scene.lidar, expected.scan.points)
    sparse, valid = expected.sparse_disparity()
    np.testing.assert_array_equal(scene.sparse, sparse)
    assert valid.sum() > 0 and (scene.sparse > 0).sum() == valid.sum()
    meta = json.loads((folders[0] / "meta.json").read_text())
    assert meta["seed"] == 5 and meta["focal_px"] == rig.focal_px
    assert np.allclose(meta["T_cam_lidar"], expected.T_cam_lidar)


def test_progress_in_a_log_is_a_line_per_tenth_not_one_endless_line(tmp_path, capsys):
    # capsys's stderr is not a terminal, as under nohup or CI
    assert main(["synth", "--out", str(tmp_path / "s"), "--count", "20", "--seed", "5",
                 "--size", "64x64"]) == 0
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert "\r" not in err and lines[-1] == "synth: 20/20 scenes"
    assert lines == [f"synth: {n}/20 scenes" for n in (1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 20)]


@pytest.mark.parametrize("args,reason", [
    (["--size", "640by400"], "WxH"),
    (["--size", "8x8"], "16x16"),
    (["--count", "0"], "positive"),
    (["--count", "-3"], "positive"),
    (["--lidar", "beams7"], "invalid choice"),
    (["--view-spread", "-0.5"], "from 0 to 4"),
    (["--view-spread", "nan"], "from 0 to 4"),
    (["--view-spread", "wide"], "from 0 to 4"),
    (["--view-spread", "0.5"], "apply to --world things"),            # the rig has no such knob
    (["--clean-cameras"], "apply to --world things"),
    (["--world", "things", "--clean-cameras", "--view-spread", "2"], "does not apply"),
])
def test_bad_arguments_exit_non_zero_with_one_line_and_write_nothing(tmp_path, capsys, args,
                                                                       reason):
    out = tmp_path / "scenes"
    with pytest.raises(SystemExit) as exc:
        main(["synth", "--out", str(out), *args])
    assert exc.value.code != 0
    err = capsys.readouterr().err.strip()
    assert reason in err and len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_unwritable_output_is_refused_before_rendering(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    assert main(["synth", "--out", str(locked / "x"), "--count", "1"]) == 1


def test_output_under_a_file_is_refused_with_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert main(["synth", "--out", str(blocker / "scenes"), "--size", "64x64"]) == 1
    err = capsys.readouterr().err.strip()
    assert "cannot create output directory" in err and len(err.splitlines()) == 1
    assert blocker.read_text() == "not a directory"


def test_failure_midway_removes_the_scenes_already_written(tmp_path, monkeypatch):
    import edge_depth.sim.export as export

    calls = {"n": 0}
    real = export.make_sample

    def flaky(*a, **k):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(28, "No space left on device")
        return real(*a, **k)

    monkeypatch.setattr(export, "make_sample", flaky)
    out = tmp_path / "scenes"
    assert main(["synth", "--out", str(out), "--count", "4", "--size", "64x64"]) == 1
    assert list_scene_folders(out) == [] and list(out.iterdir()) == []


def test_synth_things_world_writes_training_pairs_and_continues(tmp_path, capsys):
    from edge_depth.sim.things_store import list_things, read_things

    args = ["synth", "--world", "things", "--out", str(tmp_path), "--count", "2", "--seed",
            "40", "--size", "96x64"]
    assert main(args) == 0
    assert [p.name for p in list_things(tmp_path)] == ["0000040.npz", "0000041.npz"]
    pair = read_things(tmp_path / "0000040.npz")
    assert pair["left"].shape == (64, 96) and pair["disp_left"].max() > 0
    assert main(args) == 0
    assert "wrote 0 things pairs" in capsys.readouterr().out


def test_synth_things_world_refuses_an_mcap_output(tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["synth", "--world", "things", "--mcap", str(tmp_path / "x.mcap")])
    assert exc.value.code == 2


def test_synth_things_scene_folders_carry_gt_rows_as_the_lidar(tmp_path):
    from edge_depth.sim.folder import read_scene_folder

    assert main(["synth", "--world", "things", "--scene-folders", "--out", str(tmp_path),
                 "--count", "1", "--seed", "2000000", "--size", "96x64"]) == 0
    scene = read_scene_folder(tmp_path / "2000000")
    ys, xs = np.nonzero(scene.sparse)
    assert len(np.unique(ys)) == 16 and set(np.unique(xs % 2)) == {0}
    err = scene.sparse[ys, xs] - scene.disp[ys, xs]
    assert abs(float(np.median(err))) < 0.05 and float(np.std(err)) < 0.2
