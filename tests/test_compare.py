"""`edge-depth compare`: golden replays in a robot team's CI."""

from __future__ import annotations

import json

import pytest

from edge_depth.cli import main
from edge_depth.compare import compare, frame_difference


@pytest.fixture(scope="module")
def replays(tmp_path_factory, request):
    """The 3-frame recording replayed at 1 and 4 iterations, and the 4-iteration one again in
    the ros2 profile."""
    recording = request.getfixturevalue("recording")
    tmp = tmp_path_factory.mktemp("replays")
    out = {}
    for name, extra in (("it4", []), ("it1", ["--iters", "1"]),
                        ("it4_ros2", ["--profile", "ros2"])):
        out[name] = tmp / f"{name}.mcap"
        assert main(["replay", str(recording), "--out", str(out[name]),
                     "--runtime", "onnxruntime", *extra]) == 0
    return out


def test_a_replay_against_itself_is_identical_and_passes(replays, tmp_path, capsys):
    report = tmp_path / "same.json"
    assert main(["compare", str(replays["it4"]), str(replays["it4"]), "--json",
                 str(report)]) == 0
    r = json.loads(report.read_text())
    assert r["frames_compared"] == 3 and r["mean_abs_px"] == 0.0 and r["beyond_share"] == 0.0
    assert r["base_accuracy"] == r["new_accuracy"] and r["regressions"] == []
    assert r["base_latency_ms"]["engine"] > 0
    assert "OK: within the limits" in capsys.readouterr().out


def test_fewer_iterations_is_a_regression_against_ground_truth(replays, capsys):
    r = compare(replays["it4"], replays["it1"])
    assert r["new_accuracy"]["epe"] > r["base_accuracy"]["epe"]
    assert any(reason.startswith("EPE") for reason in r["regressions"])
    assert main(["compare", str(replays["it4"]), str(replays["it1"])]) == 1
    assert "REGRESSION: EPE" in capsys.readouterr().out
    # the other way round it is an improvement, and passes unless the pixels moved a lot
    better = compare(replays["it1"], replays["it4"], max_share=1.0)
    assert better["regressions"] == []


def test_the_ros2_profile_output_compares_to_the_foxglove_one(replays):
    r = compare(replays["it4"], replays["it4_ros2"])
    assert r["frames_compared"] == 3
    assert r["mean_abs_px"] < 1e-4 and r["regressions"] == []


def test_a_pixel_valid_in_one_output_only_counts_as_differing():
    import numpy as np

    base = np.full((2, 2), 10.0, np.float32)
    new = base.copy()
    new[0, 0] = np.nan  # invalid in NEW
    new[1, 1] = 10.5    # beyond 0.25 px
    d = frame_difference(base, new, 0.25)
    assert d["beyond"] == 2 and d["pixels"] == 4
    assert d["mean_abs_px"] == pytest.approx(0.5 / 3)


def test_not_a_replay_output_is_one_clear_error(tmp_path, recording, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap")
    assert main(["compare", str(junk), str(junk)]) == 2
    assert "not a readable MCAP" in capsys.readouterr().err
    assert main(["compare", str(recording), str(recording)]) == 2  # raw: no disparity
    assert "is it a replay output" in capsys.readouterr().err
    assert main(["compare", str(tmp_path / "absent.mcap"), str(recording)]) == 2
