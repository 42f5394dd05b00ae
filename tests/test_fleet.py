"""`edge-depth fleet`: many recordings on Ray's local mode give what the single-file commands
give, one by one; a damaged recording fails alone; a rerun does nothing."""

from __future__ import annotations

import json

import pytest

from edge_depth.cli import main

pytest.importorskip("ray")

THREADS = ["--threads", "1"]
COUNT = 3  # good recordings, beside one damaged


@pytest.fixture(scope="module", autouse=True)
def ray_session():
    """One local Ray for the module, started as the command starts its own: every `fleet`
    call uses it (a caller's session is the command's), and leaves it running."""
    import ray

    from edge_depth.fleet import _init_ray

    _init_ray(ray, None, 4, 1)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fleet") / "recordings"
    folder.mkdir()
    for i in range(COUNT):
        assert main(["synth", "--mcap", str(folder / f"rec{i}.mcap"), "--frames", "2",
                     "--seed", str(1_000_000 + 7 * i), "--size", "320x200"]) == 0
    good = (folder / "rec0.mcap").read_bytes()
    (folder / "damaged.mcap").write_bytes(good[:8] + b"\x00" * 4096 + good[4104:])
    return folder


def _summary(out):
    return json.loads((out / "summary.json").read_text())


def test_fleet_replay_and_compare_give_the_single_file_commands_results(recordings, tmp_path,
                                                                        capsys, ray_session):
    from edge_depth.compare import compare

    golden = tmp_path / "golden"
    assert main(["fleet", "replay", str(recordings), "--out", str(golden), "--workers", "2",
                 *THREADS]) == 1  # one recording failed
    summary = _summary(golden)
    by_name = {r["name"]: r for r in summary["recordings"]}
    assert sorted(by_name) == ["damaged", *(f"rec{i}" for i in range(COUNT))]
    assert summary["failed"] == ["damaged"] and by_name["damaged"]["reason"]
    assert "damaged" in (golden / "summary.md").read_text()
    assert ray_session.is_initialized()  # the caller's session: used, not shut down
    for i in range(COUNT):
        single = tmp_path / f"single{i}.mcap"
        assert main(["replay", str(recordings / f"rec{i}.mcap"), "--out", str(single),
                     *THREADS]) == 0
        same = compare(single, golden / f"rec{i}.mcap", tolerance_px=0.0, max_share=0.0)
        assert same["frames_compared"] == 2 and same["frames_only_in_base"] == 0
        assert same["beyond_share"] == 0.0 and same["mean_abs_px"] == 0.0
        record = by_name[f"rec{i}"]
        assert record["status"] == "ok" and record["frames"] == 2
        assert record["frames_with_lidar"] == 2 and record["epe"] > 0
    capsys.readouterr()

    stamps = {p.name: p.stat().st_mtime_ns for p in golden.iterdir()}
    assert main(["fleet", "replay", str(recordings), "--out", str(golden), *THREADS]) == 1
    assert f"0 run, {COUNT + 1} skipped (unchanged), 1 failed" in capsys.readouterr().out
    assert {p.name: p.stat().st_mtime_ns for p in golden.iterdir()
            if not p.name.startswith("summary")} == {
        k: v for k, v in stamps.items() if not k.startswith("summary")}

    new = tmp_path / "new"
    assert main(["fleet", "compare", str(recordings), "--base", str(golden), "--out", str(new),
                 *THREADS]) == 1  # the damaged one still fails
    verdicts = {r["name"]: r.get("verdict") for r in _summary(new)["recordings"]}
    for i in range(COUNT):
        single = compare(golden / f"rec{i}.mcap", new / f"rec{i}.mcap")
        assert verdicts[f"rec{i}"] == ("REGRESSION" if single["regressions"] else "OK")
    assert verdicts["damaged"] is None

    scores = tmp_path / "scores"      # evaluate: the same numbers, no output files
    assert main(["fleet", "evaluate", str(recordings), "--out", str(scores), *THREADS]) == 1
    evaluated = {r["name"]: r for r in _summary(scores)["recordings"]}
    for i in range(COUNT):
        assert evaluated[f"rec{i}"]["epe"] == pytest.approx(by_name[f"rec{i}"]["epe"])
    assert not list(scores.glob("*.mcap"))


def test_a_regression_exits_1_and_is_named(recordings, tmp_path, capsys):
    golden, new = tmp_path / "golden", tmp_path / "new"
    one = recordings / "rec1.mcap"
    assert main(["fleet", "replay", str(one), "--out", str(golden), *THREADS]) == 0
    assert main(["fleet", "compare", str(one), "--base", str(golden), "--out", str(new),
                 "--iters", "1", "--refine", "off", "--tolerance-px", "0.01",
                 "--max-share", "0.001", *THREADS]) == 1
    summary = _summary(new)
    assert summary["regressions"] == ["rec1"] and summary["failed"] == []
    assert "1 regressed (rec1)" in capsys.readouterr().out


def test_without_ray_it_says_how_to_install_it(recordings, tmp_path, capsys, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ModuleNotFoundError("No module named 'ray'", name="ray")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    assert main(["fleet", "replay", str(recordings), "--out", str(tmp_path / "o")]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "pip install 'edge-depth[fleet]'" in line


def test_a_recording_read_past_damage_is_kept_as_damaged_and_strict_exits_3(tmp_path, capsys):
    """A cut-off recording and one with a flipped byte in a middle chunk: each row says
    `damaged` and what the input lost, their replays are kept, and only --strict fails."""
    from edge_depth.fleet import DAMAGED_EXIT
    from tests.test_hostile_inputs import _small_recording

    folder, out = tmp_path / "recordings", tmp_path / "out"
    folder.mkdir()
    starts = _small_recording(folder / "whole.mcap")
    raw = (folder / "whole.mcap").read_bytes()
    (folder / "whole.mcap").unlink()
    (folder / "cut.mcap").write_bytes(raw[:starts[6] + 100])
    flipped = bytearray(raw)
    flipped[(starts[4] + starts[5]) // 2] ^= 0xFF
    (folder / "flipped.mcap").write_bytes(bytes(flipped))
    assert main(["fleet", "replay", str(folder), "--out", str(out), *THREADS]) == 0
    summary = _summary(out)
    assert summary["damaged"] == ["cut", "flipped"] and summary["failed"] == []
    by_name = {r["name"]: r for r in summary["recordings"]}
    assert by_name["cut"]["lost"] == [f"cut off at byte {starts[6]} of {starts[6] + 100} "
                                      "(100 bytes unreadable)"]
    assert by_name["flipped"]["lost"][0].startswith(f"damaged data at byte {starts[4]} ")
    assert 0 < by_name["cut"]["frames"] < 6 and 0 < by_name["flipped"]["frames"] < 6
    table = (out / "summary.md").read_text()
    assert f"| cut | damaged | {by_name['cut']['frames']} |" in table
    assert f"input cut off at byte {starts[6]}" in table
    assert f"input damaged data at byte {starts[4]}" in table
    assert "0 failed, 2 damaged (cut, flipped)" in table
    assert (out / "cut.mcap").is_file() and (out / "flipped.mcap").is_file()
    capsys.readouterr()
    assert main(["fleet", "replay", str(folder), "--out", str(out), "--strict",
                 *THREADS]) == DAMAGED_EXIT == 3
    assert "2 skipped (unchanged), 0 failed, 2 damaged" in capsys.readouterr().out


def test_an_out_folder_that_cannot_be_made_is_one_line_naming_it(recordings, tmp_path,
                                                                  capsys):
    (tmp_path / "taken").write_text("a file where the folder would go")
    out = tmp_path / "taken" / "fleet"
    assert main(["fleet", "replay", str(recordings / "rec0.mcap"), "--out", str(out),
                 *THREADS]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "--out" in line and str(out) in line
    assert f"{tmp_path / 'taken'} is a file, not a folder" in line
