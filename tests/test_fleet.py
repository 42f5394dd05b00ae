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
                 "--iters", "1", "--edge-match", "0", "--tolerance-px", "0.01",
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
