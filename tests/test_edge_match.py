"""The full-resolution block matching at the network's uncertain edges
(`edge.runtime.edge_match`): where it swaps, what it leaves, how it is switched on (by the
bundle, or the caller)."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from edge_depth.errors import ConfigError
from edge_depth.runtime.edge_match import FAR_PX, EdgeMatch, disparities_for, parse_count

BAR = slice(150, 162)      # a thin foreground bar's columns in the left view
BACKGROUND, FOREGROUND = 10, 30


def thin_bar_pair():
    """A textured wall at 10 px and a 12 px wide bar at 30 px in front of it (320x200, no
    noise), with what a 1/8-resolution network makes of it: the wall's 10 px everywhere but
    a blurred bump where the bar is, unsure (confidence 0.5) within 16 px of the bar."""
    rng = np.random.default_rng(0)
    h, w = 200, 320
    wall = cv2.GaussianBlur(rng.uniform(0, 255, (h, w + 64)).astype(np.float32), (0, 0), 1.2)
    bar = cv2.GaussianBlur(rng.uniform(0, 255, (h, w + 64)).astype(np.float32), (0, 0), 1.2)
    xs = np.arange(w)
    left = wall[:, xs + 32].copy()
    left[:, BAR] = bar[:, xs[BAR] + 32]
    right = wall[:, xs + 32 + BACKGROUND].copy()
    seen = (xs + FOREGROUND >= BAR.start) & (xs + FOREGROUND < BAR.stop)
    right[:, seen] = bar[:, xs[seen] + FOREGROUND + 32]
    to8 = lambda im: cv2.normalize(im, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)  # noqa: E731
    gt = np.full((h, w), BACKGROUND, np.float32)
    gt[:, BAR] = FOREGROUND
    coarse = cv2.resize(gt, (w // 8, h // 8), interpolation=cv2.INTER_AREA)
    network = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR)  # the bar smeared
    confidence = np.ones((h, w), np.float32)
    confidence[:, BAR.start - 16:BAR.stop + 16] = 0.5
    return to8(left), to8(right), gt, network, confidence


def test_it_recovers_a_thin_bar_and_leaves_confident_pixels_alone():
    left, right, gt, network, confidence = thin_bar_pair()
    out, count = EdgeMatch(64).apply(left, right, network, confidence)
    inner = (slice(20, 180), slice(BAR.start + 2, BAR.stop - 2))    # away from the bar's edges
    assert np.mean(np.abs(network[inner] - FOREGROUND) > 1.0) > 0.5  # the network blurs it
    assert np.median(np.abs(out[inner] - FOREGROUND)) < 0.5         # matched back
    assert np.mean(np.abs(out[inner] - FOREGROUND) < 1.0) > 0.8
    sure = confidence >= 0.9
    np.testing.assert_array_equal(out[sure], network[sure])         # never where it is sure
    changed = out != network
    assert count == changed.sum() and 0 < count < 0.2 * out.size


def test_flat_uncertain_areas_are_not_swapped():
    # unsure everywhere, but the network's disparity is flat: no edge of its own, no swap
    left, right, _, _, _ = thin_bar_pair()
    flat = np.full(left.shape, 12.0, np.float32)
    out, count = EdgeMatch(64).apply(left, right, flat, np.zeros_like(flat))
    assert count == 0 and np.array_equal(out, flat)


def test_a_network_value_that_explains_the_pair_is_kept():
    # the exact disparity, unsure everywhere and with edges: the matched values warp the
    # right view no better than it, so (nearly) nothing is swapped and nothing gets worse
    left, right, gt, _, _ = thin_bar_pair()
    out, count = EdgeMatch(64).apply(left, right, gt, np.zeros_like(gt))
    assert count < 0.002 * gt.size    # the gate without the photometric test takes 1.4 %
    assert np.mean(out != gt) < 0.002


def lidar_rows(gt: np.ndarray, every: int = 20) -> np.ndarray:
    """Exact points on every `every`-th row, all columns (0 = no point)."""
    sparse = np.zeros_like(gt)
    sparse[::every] = gt[::every]
    return sparse


def test_the_lidar_point_fills_the_matchers_holes_where_the_image_has_texture():
    left, right, gt, network, confidence = thin_bar_pair()
    nothing = np.zeros_like(gt)              # as if StereoBM had found no checked match
    stage = EdgeMatch(64)
    out, count = stage.apply(left, right, network, confidence, lidar_rows(gt), matched=nothing)
    inner = (slice(20, 180), slice(BAR.start + 2, BAR.stop - 2))
    assert np.mean(np.abs(out[inner] - FOREGROUND) < 1.0) > 0.8    # the points' 30 px
    sure = confidence >= 0.9
    np.testing.assert_array_equal(out[sure], network[sure])
    assert count == (out != network).sum() > 0
    # without points, or with the matched values present, the points are not used
    alone, none = stage.apply(left, right, network, confidence, None, matched=nothing)
    assert none == 0 and np.array_equal(alone, network)
    found = gt + 0.25                       # a match everywhere: no hole for the points
    with_points = stage.apply(left, right, network, confidence, lidar_rows(gt), matched=found)
    without = stage.apply(left, right, network, confidence, None, matched=found)
    np.testing.assert_array_equal(with_points[0], without[0])
    assert with_points[1] == without[1] > 0
    # the same pair at 3 % of its contrast: the warp costs still favour the points, but a
    # photometric test on so little texture is weak evidence, so nothing is taken
    faint = [np.rint(128 + 0.03 * (im.astype(np.float32) - 128)).astype(np.uint8)
             for im in (left, right)]
    _, faint_count = stage.apply(*faint, network, confidence, lidar_rows(gt), matched=nothing)
    assert faint_count == 0


def test_far_from_every_point_sgbms_match_stands_in_on_a_sparse_map():
    left, right, gt, network, confidence = thin_bar_pair()
    nothing = np.zeros_like(gt)          # StereoBM found nothing: only SGBM's match can help
    sparse = np.zeros_like(gt)
    sparse[:30:10, :100] = gt[:30:10, :100]   # points on the wall, far from the bar
    inner = (slice(60, 180), slice(BAR.start + 2, BAR.stop - 2))
    far, taken = EdgeMatch(64, far_px=FAR_PX).apply(left, right, network, confidence, sparse,
                                                    matched=nothing)
    off, off_taken = EdgeMatch(64).apply(left, right, network, confidence, sparse,
                                         matched=nothing)
    assert np.mean(np.abs(far[inner] - FOREGROUND) < 1.0) > 0.8     # SGBM's 30 px
    assert np.mean(np.abs(off[inner] - FOREGROUND) < 1.0) < 0.5     # the network's blur
    assert taken > off_taken
    sure = confidence >= 0.9
    np.testing.assert_array_equal(far[sure], network[sure])          # only inside the gate
    # a map that reaches every gated pixel within 12 px, or leaves under FAR_MIN_SHARE of the
    # frame beyond it, is matched as without the option
    for points in (lidar_rows(gt, every=20), lidar_rows(gt, every=20)[:180]):
        dense = np.zeros_like(gt)
        dense[:len(points)] = points
        beyond = EdgeMatch(64, far_px=FAR_PX).prepare(left, right, network, confidence, dense)
        assert beyond is not None and beyond.far is None
        with_far = EdgeMatch(64, far_px=FAR_PX).apply(left, right, network, confidence, dense,
                                                      matched=nothing)
        without = EdgeMatch(64).apply(left, right, network, confidence, dense, matched=nothing)
        np.testing.assert_array_equal(with_far[0], without[0])
    # a frame without points is far from them everywhere: SGBM's match where it is smooth
    alone, alone_taken = EdgeMatch(64, far_px=FAR_PX).apply(left, right, network, confidence,
                                                            None, matched=nothing)
    assert np.mean(np.abs(alone[inner] - FOREGROUND) < 1.0) > 0.8 and alone_taken > 0
    np.testing.assert_array_equal(alone[sure], network[sure])
    stage = EdgeMatch(64, far_px=FAR_PX)
    prepared = stage.prepare(left, right, network, confidence, None)
    assert prepared is not None and prepared.far_smooth_only
    speckle = gt.copy()
    speckle[::3, ::3] += 12.0          # SGBM right but for a speckle in every 3 x 3 block
    _, rough = stage.finish(prepared, network, nothing, speckle)
    _, trusted = stage.finish(replace(prepared, far_smooth_only=False), network, nothing,
                              speckle)
    assert rough == 0 < trusted        # its speckle keeps it out where there are no points
    with pytest.raises(ConfigError, match="edge_match_far_px"):
        EdgeMatch(64, far_px=-1.0)
    # SGBM as the matcher has SGBM's match there already; the engine's default is FAR_PX
    assert EdgeMatch(64, far_px=FAR_PX, matcher="sgbm").prepare(
        left, right, network, confidence, sparse).far is None
    from edge_depth.runtime.options import EngineOptions

    assert EngineOptions().edge_match_far_px == FAR_PX


@pytest.mark.parametrize("count", [-16, 50])
def test_disparity_count_must_be_a_positive_multiple_of_16(count):
    with pytest.raises(ConfigError, match="edge_match"):
        EdgeMatch(count)


def test_auto_takes_each_frames_count_from_the_networks_own_disparity():
    assert disparities_for(np.array([[3.0, 59.9]], np.float32), 640) == 80   # + 8, to 16
    assert disparities_for(np.array([[40.0]], np.float32), 640) == 48
    assert disparities_for(np.zeros((2, 2), np.float32), 640) == 16         # at least 16
    assert disparities_for(np.array([[np.nan, 20.0]], np.float32), 640) == 32
    assert disparities_for(np.array([[900.0]], np.float32), 640) == 624     # below the width
    assert disparities_for(np.array([[np.inf]], np.float32), 320) == 304
    assert parse_count("auto") == "auto" and parse_count("64") == 64 and parse_count("0") == 0
    for bad in ("50", "-16", "sixty"):
        with pytest.raises(ValueError, match="auto"):
            parse_count(bad)
    stage = EdgeMatch(0)     # no fixed count: each call names its own
    left, right, _, _, _ = thin_bar_pair()
    np.testing.assert_array_equal(stage.matched(left, right, 64),
                                  EdgeMatch(64).matched(left, right))
    with pytest.raises(ValueError, match="per call"):
        stage.matched(left, right)
    with pytest.raises(ValueError, match="per call"):
        stage.beyond_px(np.full((4, 4), 20.0))
    assert stage.beyond_px(np.full((4, 4), 20.0), 16) == 16 and \
        stage.beyond_px(np.full((4, 4), 20.0), 32) == 0


def test_the_engine_refuses_a_count_as_wide_as_its_input():
    from edge_depth.runtime.engine import Engine

    with pytest.raises(ConfigError, match="below the bundle's input width"):
        Engine(refine="off", precision="int8", threads=1, edge_match=640)


def test_engine_runs_it_after_the_selections_as_the_bundle_or_the_caller_says():
    from edge_depth.runtime.engine import Engine

    engine = Engine(refine="off", precision="int8", threads=2)  # the engine before the band

    left, right, gt, _, _ = thin_bar_pair()
    big = lambda im: cv2.resize(im, (640, 400), interpolation=cv2.INTER_NEAREST)  # noqa: E731
    sparse = np.zeros((400, 640), np.float32)
    sparse[::50, ::2] = big(gt)[::50, ::2] * 2.0                     # disparities double too
    plain = Engine(precision="int8", threads=2, edge_match=0,
                   refine="off").infer(big(left), big(right), sparse)
    assert plain.matched_px is None and "edge_match" not in plain.timings_ms
    # the shipped bundle (stage 17) declares "auto" on every other row
    shipped = engine.infer(big(left), big(right), sparse)
    assert engine.edge_match.num_disparities == 0 and engine.edge_match.row_step == 2
    assert engine.describe().endswith("edge matching auto on every 2nd row, weighted median "
                                      "9x9/2 (the bundle's)")
    # ... and its weighted median over the gate
    expected, replaced = EdgeMatch(disparities_for(plain.disparity, 640), row_step=2,
                                   median="9x9/2").apply(
        big(left), big(right), plain.disparity, plain.confidence, sparse)
    np.testing.assert_array_equal(shipped.disparity, expected)
    assert shipped.matched_px == replaced > 0 and shipped.timings_ms["edge_match"] > 0
    # each setting left out is the bundle's: every row asked for here
    matched = Engine(refine="off", precision="int8", threads=2, edge_match=128,
                     edge_match_rows=1).infer(
        big(left), big(right), sparse)
    assert matched.matched_px is not None and matched.matched_px > 0
    assert matched.timings_ms["edge_match"] > 0
    # the same stage applied to the engine's output without it
    expected, count = EdgeMatch(128, median="9x9/2").apply(
        big(left), big(right), plain.disparity, plain.confidence, sparse)
    np.testing.assert_array_equal(matched.disparity, expected)
    assert matched.matched_px == count
    assert plain.match_beyond_px is None and matched.match_beyond_px == 0   # up to ~60 px
    # "auto": the count from the engine's own disparity (~60 px here: 80), after the graphs
    auto = Engine(refine="off", precision="int8", threads=2, edge_match="auto",
                  edge_match_rows=1).infer(
        big(left), big(right), sparse)
    count = disparities_for(plain.disparity, 640)
    assert count == 16 * int(np.ceil((plain.disparity.max() + 8) / 16))
    expected, replaced = EdgeMatch(count, median="9x9/2").apply(
        big(left), big(right), plain.disparity, plain.confidence, sparse)
    np.testing.assert_array_equal(auto.disparity, expected)
    assert auto.matched_px == replaced and auto.match_beyond_px == 0
    # a count below the scene's disparities is counted, not silent
    short = Engine(refine="off", precision="int8", threads=2, edge_match=16,
                   edge_match_rows=1).infer(
        big(left), big(right), sparse)
    assert short.match_beyond_px == EdgeMatch(16).beyond_px(plain.disparity) > 0


def test_auto_started_before_the_last_step_gives_the_late_starts_output(monkeypatch):
    """Where the graphs leave a core idle, "auto" starts StereoBM (and the choice's pair-only
    terms) one step before the last, with the count that step's disparity gives: the output
    is the late start's, and a guess the final disparity disowns matches again."""
    from edge_depth.runtime.engine import Engine

    left, right, gt, _, _ = thin_bar_pair()
    big = lambda im: cv2.resize(im, (640, 400), interpolation=cv2.INTER_NEAREST)  # noqa: E731
    left, right = big(left), big(right)
    sparse = np.zeros((400, 640), np.float32)
    sparse[::50, ::2] = big(gt)[::50, ::2] * 2.0
    late, early = (Engine(refine="off", precision="int8", threads=1, edge_match_rows=1)
                   for _ in range(2))
    late.match_schedule.early, early.match_schedule.early = False, True
    for iters in (1, 4):                     # one step: the guess from the encoder's seed
        for points in (sparse, np.zeros_like(sparse)):
            a, b = (e.infer(left, right, points, iters=iters) for e in (late, early))
            np.testing.assert_array_equal(a.disparity, b.disparity)
            np.testing.assert_array_equal(a.confidence, b.confidence)
            assert a.matched_px == b.matched_px and a.match_beyond_px == b.match_beyond_px
            assert b.timings_ms["edge_match"] > 0
    assert late.match_schedule.starts == {"early": 0, "again": 0}
    assert early.match_schedule.starts["early"] == 4
    again = early.match_schedule.starts["again"]
    monkeypatch.setattr(early.match_schedule, "guess_count", lambda disparity: 16)  # wrong
    a, b = (e.infer(left, right, sparse) for e in (late, early))
    np.testing.assert_array_equal(a.disparity, b.disparity)
    assert a.matched_px == b.matched_px > 0
    assert early.match_schedule.starts == {"early": 5, "again": again + 1}


def test_a_bundle_declares_its_engine_settings_and_a_bad_one_is_one_clear_line():
    from edge_depth.runtime.engine import DEFAULT_BUNDLE, Engine
    from edge_depth.runtime.graphs import load_bundle_meta
    from edge_depth.runtime.options import bundle_preset

    meta = load_bundle_meta(DEFAULT_BUNDLE)
    assert bundle_preset(meta) == {"edge_match": "auto", "edge_match_rows": 2,
                                            "edge_median": "9x9/2"}
    older = {k: v for k, v in meta.items() if k != "engine"}     # stage 16 and before: off
    assert bundle_preset(older) == {"edge_match": 0, "edge_match_rows": 1,
                                             "edge_median": "off"}
    off = Engine(refine="off", precision="int8", threads=1, meta=older)
    assert off.edge_match is None and off.describe().endswith("edge matching off (the bundle's)")
    given = Engine(refine="off", precision="int8", threads=1, meta=older,
                   edge_match=64)   # the caller's
    assert given.edge_match.num_disparities == 64 and given.edge_match.row_step == 1
    assert given.describe().endswith("edge matching 64")
    for engine, text in (({"edge_match": 40}, "engine.edge_match"),
                         ({"edge_match": True}, "engine.edge_match"),
                         ({"edge_match_rows": 3}, "engine.edge_match_rows"),
                         ({"edge_median": "5x5"}, "engine.edge_median"),
                         ("auto", 'model.json\'s "engine" as a table')):
        with pytest.raises(ConfigError, match=text):
            Engine(refine="off", precision="int8", threads=1, meta={**meta, "engine": engine})


def test_config_and_evaluate_take_it(tmp_path):
    from edge_depth.config import load_robot_config
    from edge_depth.runtime.options import EngineOptions
    from edge_depth.tools import evaluate

    default = EngineOptions()                      # the bundle's own setting, for the engine
    assert default.edge_match == default.edge_match_rows == "bundle"
    resolved = default.resolved({"edge_match": "auto", "edge_match_rows": 2,
                                 "edge_median": "9x9/2"})
    assert (resolved.edge_match, resolved.edge_match_rows) == ("auto", 2)
    path = tmp_path / "c.toml"
    path.write_text("[engine]\nedge_match = 64\n")
    assert load_robot_config(path).engine.edge_match == 64
    path.write_text('[engine]\nedge_match = 0\nedge_match_rows = 1\n')   # off, said so
    assert load_robot_config(path).engine.edge_match == 0
    path.write_text('[engine]\nedge_match = "auto"\nedge_match_rows = "bundle"\n')
    engine = load_robot_config(path).engine
    assert engine.edge_match == "auto" and engine.edge_match_rows == "bundle"
    path.write_text("[engine]\nedge_match = 40\n")    # not a multiple of 16: the file named
    with pytest.raises(ConfigError, match=r"c.toml: engine.edge_match: expected"):
        load_robot_config(path)
    path.write_text('[engine]\nedge_match = "sixty"\n')
    with pytest.raises(ConfigError, match='"auto" or "bundle" or int'):
        load_robot_config(path)
    path.write_text('[engine]\nedge_match_rows = "two"\n')
    with pytest.raises(ConfigError, match='"bundle" or int'):
        load_robot_config(path)
    with pytest.raises(SystemExit):
        evaluate.main([str(tmp_path), "--edge-match", "40"])
    with pytest.raises(SystemExit):    # refused before any scene is evaluated
        evaluate.main([str(tmp_path), "--picture", str(tmp_path / "errors.gif")])


def test_the_closing_summary_and_diagnostics_count_what_it_replaced():
    from edge_depth.frame_summary import replaced_shares, selection_summary, summarise

    timings = [dict(engine=50.0, edge_match=9.0, matched_pct=4.0),
               dict(engine=52.0, edge_match=11.0, matched_pct=0.0)]
    assert set(summarise(timings)) == {"engine", "edge_match"}   # the share is no latency
    assert replaced_shares(timings, "matched_pct") == [4.0, 0.0]
    assert selection_summary(timings) == ("Edge matching: replaced a median 2.0 % of "
                                          "each frame's pixels (p95 3.8 %; none in 1 of 2 "
                                          "frames)")
    # beyond the matching's disparity count: said only where a frame had more than 1 %
    timings[0]["match_beyond_pct"], timings[1]["match_beyond_pct"] = 0.4, 0.0
    assert set(summarise(timings)) == {"engine", "edge_match"}
    assert "nearer than" not in selection_summary(timings)
    timings[1]["match_beyond_pct"] = 12.5
    assert selection_summary(timings).splitlines()[1] == (
        "Edge matching: the scene was nearer than its disparity count reaches in 1 "
        "of 2 frames (up to 12.5 % of a frame's pixels; StereoBM cannot match there): raise "
        "[engine] edge_match to a multiple of 16 above the scene's largest disparity, or set "
        "it to \"auto\" (each frame's count from the network's own)")
    # SGBM far from the LiDAR: said where it ran, with the share of the frame it matched
    timings[0]["match_far_pct"], timings[1]["match_far_pct"] = 0.0, 0.0
    assert set(summarise(timings)) == {"engine", "edge_match"}
    assert "far from every point" not in selection_summary(timings)
    timings[0]["match_far_pct"] = 9.5
    assert selection_summary(timings).splitlines()[2].startswith(
        "Edge matching: SGBM matched the unsure pixels far from every LiDAR point (a sparse "
        "map, or none) in 1 of 2 frames, a median 9.5 % of the frame")


def test_a_sparse_map_reports_what_sgbm_matched_far_from_it():
    from edge_depth.runtime.engine import Engine

    engine = Engine(refine="off", precision="int8", threads=2)  # the engine before the band
    left, right, gt, _, _ = thin_bar_pair()
    h, w = engine.size
    left, right, gt = (cv2.resize(a, (w, h), interpolation=cv2.INTER_NEAREST)
                       for a in (left, right, gt))
    sparse = np.zeros_like(gt)
    sparse[:40:10, :120] = gt[:40:10, :120]      # a few rows on one side: a sparse map
    far = engine.infer(left, right, sparse)
    dense = engine.infer(left, right, lidar_rows(gt, every=8))
    assert far.match_far_px is not None and far.match_far_px >= 0.05 * gt.size
    assert dense.match_far_px == 0


def test_replay_takes_it_so_a_recording_can_be_compared_with_and_without(recording, tmp_path,
                                                                          capsys):
    from edge_depth.cli import main
    from edge_depth.compare import compare

    plain, matched = tmp_path / "plain.mcap", tmp_path / "matched.mcap"
    assert main(["replay", str(recording), "--out", str(plain), "--iters", "1", "--refine", "off",
                 "--edge-match", "0"]) == 0
    assert "Edge matching" not in capsys.readouterr().out
    assert main(["replay", str(recording), "--out", str(matched), "--iters", "1", "--refine", "off",
                 "--edge-match", "64"]) == 0
    text = capsys.readouterr().out
    assert "Edge matching: replaced a median" in text and "edge_match" in text
    result = compare(plain, matched)                 # what a user runs: edge-depth compare
    assert result["frames_compared"] == 3 and 0 < result["beyond_share"] < 0.2
    auto = tmp_path / "auto.mcap"                    # the count from each frame's own disparity
    assert main(["replay", str(recording), "--out", str(auto), "--iters", "1", "--refine", "off",
                 "--edge-match", "auto", "--edge-match-rows", "1"]) == 0
    assert "Edge matching: replaced a median" in capsys.readouterr().out
    assert compare(matched, auto)["frames_compared"] == 3
    rows = tmp_path / "rows.mcap"                    # every other row: the flag reaches it
    assert main(["replay", str(recording), "--out", str(rows), "--iters", "1", "--refine", "off",
                 "--edge-match", "auto", "--edge-match-rows", "2"]) == 0
    assert "Edge matching: replaced a median" in capsys.readouterr().out
    assert 0 < compare(auto, rows)["beyond_share"] < 0.2         # not the same frames
    default = tmp_path / "default.mcap"              # no matching flag: the bundle's
    assert main(["replay", str(recording), "--out", str(default), "--iters", "1",
                 "--refine", "off"]) == 0
    assert "Edge matching: replaced a median" in capsys.readouterr().out
    assert compare(rows, default)["beyond_share"] == 0
    sgbm = tmp_path / "sgbm.mcap"                    # the matcher flag reaches the engine
    assert main(["replay", str(recording), "--out", str(sgbm), "--iters", "1", "--refine", "off",
                 "--edge-matcher", "sgbm"]) == 0
    assert "Edge matching: replaced a median" in capsys.readouterr().out
    assert 0 < compare(default, sgbm)["beyond_share"] < 0.2     # only the matcher differs
    with pytest.raises(SystemExit) as stop:                      # one clear line
        main(["replay", str(recording), "--out", str(tmp_path / "x.mcap"), "--edge-match", "50"])
    assert stop.value.code == 2
    assert "edge_match: expected 'auto', 0 (off) or a positive multiple of 16" in \
        capsys.readouterr().err


def test_every_other_row_matches_half_the_rows_and_stands_for_the_next(tmp_path):
    from edge_depth.config import load_robot_config
    from edge_depth.runtime.engine import Engine
    from edge_depth.tools import evaluate

    left, right, gt, network, confidence = thin_bar_pair()
    left, right = left[:199], right[:199]                          # an odd height too
    half = EdgeMatch(64, row_step=2)
    got = half.matched(left, right)
    assert got.shape == left.shape
    bm = cv2.StereoBM_create(numDisparities=64, blockSize=7)
    for set_, value in (("setTextureThreshold", 10), ("setUniquenessRatio", 15),
                        ("setDisp12MaxDiff", 1), ("setSpeckleWindowSize", 50),
                        ("setSpeckleRange", 2), ("setPreFilterCap", 31)):
        getattr(bm, set_)(value)
    raw = bm.compute(left[::2], right[::2])
    expected = np.where(raw > 0, raw / 16.0, 0.0).astype(np.float32)
    np.testing.assert_array_equal(got[::2], expected)               # the matched rows
    np.testing.assert_array_equal(got[1::2], expected[:99])         # each for the row below
    # on the thin bar it recovers the bar as every row does
    out, count = half.apply(left, right, network[:199], confidence[:199])
    inner = (slice(20, 180), slice(BAR.start + 2, BAR.stop - 2))
    assert np.mean(np.abs(out[inner] - FOREGROUND) < 1.0) > 0.8 and count > 0
    for bad in (0, 3):
        with pytest.raises(ConfigError, match="edge_match_rows"):
            EdgeMatch(64, row_step=bad)
        with pytest.raises(ConfigError, match="edge_match_rows"):
            Engine(refine="off", precision="int8", threads=1, edge_match_rows=bad)
    path = tmp_path / "c.toml"
    path.write_text('[engine]\nedge_match = "auto"\nedge_match_rows = 2\n')
    assert load_robot_config(path).engine.edge_match_rows == 2
    path.write_text("[engine]\nedge_match_rows = 4\n")
    with pytest.raises(ConfigError, match="edge_match_rows"):
        load_robot_config(path)
    with pytest.raises(SystemExit):
        evaluate.main([str(tmp_path), "--edge-match", "auto", "--edge-match-rows", "3"])


def test_sgbm_as_the_matcher_fills_what_stereobm_leaves_and_is_switched_on_everywhere(tmp_path):
    from edge_depth.baselines import sgbm_disparity
    from edge_depth.config import load_robot_config
    from edge_depth.runtime.engine import Engine
    from edge_depth.tools import evaluate

    left, right, gt, network, confidence = thin_bar_pair()
    stage = EdgeMatch(64, matcher="sgbm")
    got = stage.matched(left, right)
    b = 5                                            # the baseline's SGBM, speckle per row step
    expected = sgbm_disparity(left, right, cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=64, blockSize=b, P1=8 * b * b, P2=32 * b * b,
        disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100, speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY))
    np.testing.assert_array_equal(got, expected)
    assert np.mean(got > 0) > np.mean(EdgeMatch(64).matched(left, right) > 0)   # fewer holes
    out, count = stage.apply(left, right, network, confidence)
    inner = (slice(20, 180), slice(BAR.start + 2, BAR.stop - 2))
    assert np.mean(np.abs(out[inner] - FOREGROUND) < 1.0) > 0.8 and count > 0
    with pytest.raises(ConfigError, match="edge_matcher"):
        EdgeMatch(64, matcher="census")
    with pytest.raises(ConfigError, match="edge_matcher"):
        Engine(refine="off", precision="int8", threads=1, edge_matcher="census")
    engine = Engine(refine="off", precision="int8", threads=1,
                    edge_matcher="sgbm")   # the bundle's count
    assert engine.edge_match.matcher == "sgbm" and engine.edge_match.row_step == 2
    assert engine.describe().endswith("edge matching auto with SGBM on every 2nd row, "
                                      "weighted median 9x9/2 (the bundle's)")
    path = tmp_path / "c.toml"
    path.write_text('[engine]\nedge_matcher = "sgbm"\n')
    assert load_robot_config(path).engine.edge_matcher == "sgbm"
    path.write_text("[engine]\n")
    assert load_robot_config(path).engine.edge_matcher == "bm"            # the default
    path.write_text('[engine]\nedge_matcher = "census"\n')
    with pytest.raises(ConfigError, match="edge_matcher"):
        load_robot_config(path)
    with pytest.raises(SystemExit):
        evaluate.main([str(tmp_path), "--edge-matcher", "census"])
