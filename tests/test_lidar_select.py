"""The LiDAR selection: its 2×2 cells, features, the choice, model.json round trip, and the
fitting tool's loss and scoring."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.errors import ConfigError
from edge_depth.runtime.cells import (
    CELL_PX,
    Perceptron,
    Scratch,
    cell_lidar,
    cell_pixels,
    cell_shape,
    feature_matrix,
    key_disparity,
    tanh32,
    unpack_key,
    warp_error,
    warp_error_at,
)
from edge_depth.runtime.lidar_select import (
    FEATURES,
    SIDE_FEATURES,
    LidarSelect,
    available,
    selection_features,
)

H, W = 96, 160
TRUE_DISPARITY = 12.0


def textured_pair(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A random-texture plane at TRUE_DISPARITY: left(x) = right(x − d)."""
    rng = np.random.default_rng(seed)
    wide = rng.integers(0, 256, (H, W + 32)).astype(np.uint8)
    import cv2

    wide = cv2.GaussianBlur(wide, (3, 3), 0)
    d = int(TRUE_DISPARITY)
    return wide[:, :W].copy(), wide[:, d:d + W].copy()


def lidar_rows(value: float) -> np.ndarray:
    sparse = np.zeros((H, W), np.float32)
    sparse[::12, ::2] = value
    return sparse


def one_pixel_cells(x: np.ndarray, err: np.ndarray) -> dict:
    """A fitting tool's row (`candidate_row`'s keys) of cells of one known pixel each:
    features x (N, F), err (N, 1 + candidates), the network's first."""
    return dict(source="things", features=x, err=err, capped=err, bad3=(err > 3).astype(float),
                known=len(x), err_sum=float(err[:, 0].sum()),
                bad3_sum=int((err[:, 0] > 3).sum()))


def cost_chooser() -> LidarSelect:
    """Takes the LiDAR where its 5×5 matching cost is lower than the network's by > 0.1."""
    f = len(FEATURES)
    w1 = np.zeros((f, 1), np.float32)
    w1[FEATURES.index("cost5_net_minus_lidar"), 0] = 1.0
    return LidarSelect(mean=np.zeros(f, np.float32), std=np.ones(f, np.float32), w1=w1,
                       b1=np.zeros(1, np.float32), w2=np.array([100.0], np.float32), b2=-10.0)


def test_selection_takes_the_lidar_where_the_images_agree_with_it():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    disparity[30:60, 40:100] = TRUE_DISPARITY + 6  # the network is wrong here
    confidence = np.full((H, W), 0.5, np.float32)
    out, _, replaced = cost_chooser().apply(left, right, disparity, confidence,
                                         lidar_rows(TRUE_DISPARITY))
    assert replaced == 30 * 60  # exactly the wrong block: elsewhere both candidates agree
    np.testing.assert_array_equal(out, TRUE_DISPARITY)
    assert disparity[40, 50] == TRUE_DISPARITY + 6  # the input is not modified


def test_selection_keeps_the_network_where_the_lidar_is_wrong():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    out, _, replaced = cost_chooser().apply(left, right, disparity, np.ones((H, W), np.float32),
                                         lidar_rows(TRUE_DISPARITY - 5))
    # only in the left border's strip, where the network's value reads the right image
    # outside its border and so costs the most (one cell further: the 3×3-cell window)
    assert 0 < replaced <= H * (int(TRUE_DISPARITY) + 2)
    np.testing.assert_array_equal(out[:, int(TRUE_DISPARITY) + 2:], TRUE_DISPARITY)


def test_without_lidar_the_disparity_comes_back_unchanged():
    left, right = textured_pair()
    disparity = np.full((H, W), 3.0, np.float32)
    sparse = np.full((H, W), np.nan, np.float32)  # non-finite counts as no point
    features, pixels, _ = selection_features(left, right, disparity, disparity, sparse)
    assert features.shape == (0, len(FEATURES)) and not len(pixels)
    out, _, replaced = cost_chooser().apply(left, right, disparity, disparity, sparse)
    assert replaced == 0 and out is disparity


def test_features_measure_cost_disagreement_and_distance():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY + 4, np.float32)
    features, cells, lidar = selection_features(left, right, disparity,
                                                np.full((H, W), 0.25, np.float32),
                                                lidar_rows(TRUE_DISPARITY))
    hc, wc = cell_shape((H, W))
    np.testing.assert_array_equal(cells, np.arange(hc * wc))  # every cell disagrees
    assert features.shape == (hc * wc, len(FEATURES))
    np.testing.assert_array_equal(lidar, TRUE_DISPARITY)
    col = {name: features[:, i] for i, name in enumerate(FEATURES)}
    inside = cells % wc >= 12  # away from the left border (the warp reads outside the image)
    assert np.all(col["cost5_net_minus_lidar"][inside] > 5)  # the LiDAR's value matches
    np.testing.assert_allclose(col["log_disagreement"], np.log1p(4.0), rtol=1e-6)
    np.testing.assert_allclose(col["lidar_minus_net"], np.tanh(-4.0 / 8.0), rtol=1e-6)
    np.testing.assert_allclose(col["confidence"], 0.25)
    # the network is 4 px off at the points themselves too
    np.testing.assert_allclose(col["log_point_residual"], np.log1p(4.0), rtol=1e-6)
    assert col["log_distance_to_lidar"].min() == 0.0  # on a LiDAR point's cell
    # the last LiDAR row is 84 (cell row 42): cell rows 43-47 are up to 5 cells = 10 px away
    assert np.expm1(col["log_distance_to_lidar"].max()) == pytest.approx(10.0, abs=0.6)


def test_cells_cover_an_odd_sized_image_and_take_the_nearest_surface():
    sparse = np.zeros((5, 7), np.float32)
    sparse[0, 0], sparse[1, 1] = 3.0, 9.0  # one cell, two points: the nearer (larger) wins
    sparse[0, 2] = np.nan  # none
    sparse[4, 6] = 2.0  # the cut corner cell
    sparse[2, 2] = -1.0  # none
    lidar = cell_lidar(sparse)
    assert lidar.shape == cell_shape((5, 7)) == (3, 4)
    assert lidar[0, 0] == 9.0 and lidar[2, 3] == 2.0
    assert np.count_nonzero(lidar) == 2
    pixels, owner = cell_pixels(np.array([0, 11]), (5, 7))  # cell 11: the corner (2, 3)
    np.testing.assert_array_equal(pixels[owner == 0], [0, 1, 7, 8])
    np.testing.assert_array_equal(pixels[owner == 1], [4 * 7 + 6])  # cut to one pixel
    pixels, owner = cell_pixels(np.array([0, 5]), (4, 6))  # no cut cells: the quick path
    np.testing.assert_array_equal(pixels, [0, 1, 6, 7, 16, 17, 22, 23])
    np.testing.assert_array_equal(owner, [0, 0, 0, 0, 1, 1, 1, 1])
    assert CELL_PX == 2


def test_selection_runs_on_an_odd_sized_frame():
    left, right = textured_pair()
    left, right = left[:95, :159], right[:95, :159]
    disparity = np.full((95, 159), TRUE_DISPARITY, np.float32)
    disparity[31:61, 41:101] = TRUE_DISPARITY + 6
    sparse = lidar_rows(TRUE_DISPARITY)[:95, :159]
    out, _, replaced = cost_chooser().apply(left, right, disparity,
                                         np.zeros_like(disparity), sparse)
    assert out.shape == (95, 159)
    # the odd block is covered by whole cells: rows 30-61, columns 40-101
    assert np.all(out[31:61, 41:101] == TRUE_DISPARITY)
    assert 30 * 60 <= replaced <= 32 * 62


def test_model_json_round_trip_and_a_damaged_entry_is_a_config_error():
    select = cost_chooser()
    again = LidarSelect.from_meta(select.to_meta())
    x = np.random.default_rng(1).normal(size=(50, len(FEATURES))).astype(np.float32)
    np.testing.assert_allclose(again.probability(x), select.probability(x), rtol=1e-6)
    entry = select.to_meta()
    with pytest.raises(ConfigError, match="lidar_select"):
        LidarSelect.from_meta({**entry, "features": ["other"]})
    with pytest.raises(ConfigError, match="lidar_select"):
        LidarSelect.from_meta({**entry, "w1": [[1.0]]})
    with pytest.raises(ConfigError, match="lidar_select"):
        LidarSelect.from_meta({k: v for k, v in entry.items() if k != "b2"})
    with pytest.raises(ConfigError, match="lidar_select"):
        LidarSelect.from_meta({**entry, "std": [0.0] * len(FEATURES)})
    # a fit from before the cells (full resolution) must be refitted, not misread
    with pytest.raises(ConfigError, match="refit"):
        LidarSelect.from_meta({k: v for k, v in entry.items() if k != "cell_px"})


def test_fit_learns_a_choice_that_lowers_the_error_it_is_scored_on():
    pytest.importorskip("torch")
    from edge_depth.tools.fit_select import fit, score

    rng = np.random.default_rng(0)
    rows = []
    for _ in range(4):
        n = 4000  # cells of one known pixel each
        x = rng.normal(size=(n, len(FEATURES))).astype(np.float32)
        lidar_better = x[:, 0] + 0.3 * x[:, 5] > 0
        err = np.stack([np.where(lidar_better, 5.0, 0.2), np.where(lidar_better, 0.2, 5.0)], 1)
        rows.append(one_pixel_cells(x, err))
    select = fit(rows[1:], hidden=8, steps=200, seed=0)
    before, after = score(rows[:1], None), score(rows[:1], select)
    assert before == pytest.approx((2.6, 50.0), abs=1.5)
    assert after[0] < 0.5 and after[1] < 6.0


def test_the_fitting_tool_scores_a_choice_exactly_as_the_engine_applies_it():
    from edge_depth.tools.fit_select import frame_row, score

    left, right = textured_pair()
    gt = np.full((H, W), TRUE_DISPARITY, np.float32)
    gt[:, :20] = 0  # unknown
    disparity = gt + np.float32(0.3)
    disparity[30:61, 40:101] = TRUE_DISPARITY + 6  # odd edges: cells half inside
    disparity[70:80, 10:60] = TRUE_DISPARITY - 2
    sparse = lidar_rows(TRUE_DISPARITY + 0.5)
    confidence = np.zeros((H, W), np.float32)
    row = frame_row("rig", left, right, disparity, confidence, sparse, gt)
    out, _, _ = cost_chooser().apply(left, right, disparity, confidence, sparse)
    known = gt > 0
    err = np.abs(out - gt)[known]
    epe, bad3 = score([row], cost_chooser())
    assert epe == pytest.approx(float(err.mean()), rel=1e-5)
    assert bad3 == pytest.approx(100.0 * float((err > 3).mean()), rel=1e-5)
    assert epe < score([row], None)[0]  # the choice helps here


def test_a_disagreement_cap_keeps_the_network_where_the_lidar_is_too_far_off():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    disparity[30:60, 40:100] = TRUE_DISPARITY + 6
    disparity[70:90, 40:100] = TRUE_DISPARITY + 2
    sparse = lidar_rows(TRUE_DISPARITY)
    capped = LidarSelect(**{**cost_chooser().__dict__, "max_disagreement_px": 4.0})
    _, cells, _ = selection_features(left, right, disparity, disparity, sparse, 4.0)
    assert len(cells) * CELL_PX**2 == 20 * 60  # only the 2-px block
    out, _, replaced = capped.apply(left, right, disparity, np.zeros((H, W), np.float32), sparse)
    assert replaced == 20 * 60
    assert np.all(out[70:90, 40:100] == TRUE_DISPARITY)
    assert np.all(out[30:60, 40:100] == TRUE_DISPARITY + 6)
    again = LidarSelect.from_meta(capped.to_meta())
    assert again.max_disagreement_px == 4.0
    assert np.isinf(LidarSelect.from_meta(cost_chooser().to_meta()).max_disagreement_px)
    with pytest.raises(ConfigError, match="lidar_select"):
        LidarSelect.from_meta({**capped.to_meta(), "max_disagreement_px": 0.1})


def test_a_confidence_gate_keeps_the_network_where_it_is_confident():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    disparity[30:60, 40:100] = TRUE_DISPARITY + 6
    confidence = np.full((H, W), 0.5, np.float32)
    confidence[30:60, 40:70] = 0.95  # the left half of the wrong block is (wrongly) sure
    gated = LidarSelect(**{**cost_chooser().__dict__, "max_confidence": 0.9})
    out, _, replaced = gated.apply(left, right, disparity, confidence, lidar_rows(TRUE_DISPARITY))
    assert replaced == 30 * 30
    assert np.all(out[30:60, 70:100] == TRUE_DISPARITY)
    assert np.all(out[30:60, 40:70] == TRUE_DISPARITY + 6)
    assert LidarSelect.from_meta(gated.to_meta()).max_confidence == pytest.approx(0.9)
    assert np.isinf(LidarSelect.from_meta(cost_chooser().to_meta()).max_confidence)


def test_spatial_cues_see_the_networks_edge_and_the_points_zones():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY + 4, np.float32)
    disparity[:, 80:] = TRUE_DISPARITY + 14  # the network's edge: between cell columns 39 | 40
    sparse = lidar_rows(TRUE_DISPARITY)
    sparse[:, 80:][sparse[:, 80:] > 0] = TRUE_DISPARITY + 2  # the points' zones: the same place
    features, cells, _ = selection_features(left, right, disparity,
                                            np.full((H, W), 0.25, np.float32), sparse)
    hc, wc = cell_shape((H, W))
    np.testing.assert_array_equal(cells, np.arange(hc * wc))
    col = {name: features[:, i].reshape(hc, wc) for i, name in enumerate(FEATURES)}
    net3, net7 = np.expm1(col["log_net_range3"]), np.expm1(col["log_net_range7"])
    np.testing.assert_allclose(net3[:, 39:41], 10.0, rtol=1e-5)
    assert np.all(net3[:, :38] == 0) and np.all(net3[:, 42:] == 0)
    np.testing.assert_allclose(net7[:, 37:43], 10.0, rtol=1e-5)  # 3 cells either side
    assert np.all(net7[:, :36] == 0) and np.all(net7[:, 44:] == 0)
    lid3, lid7 = np.expm1(col["log_lidar_range3"]), np.expm1(col["log_lidar_range7"])
    np.testing.assert_allclose(lid3[:, 39:41], 2.0, rtol=1e-5)
    assert np.all(lid3[:, :38] == 0) and np.all(lid7[:, 44:] == 0)
    # points every 12 px = 6 cells down: cell row 2's is row 0, row 4's row 6, row 47's row 42
    rows = col["rows_to_point"][:, 10]
    np.testing.assert_allclose(rows[[0, 2, 4, 47]], np.tanh(np.array([0, 2, -2, 5]) / 4.0),
                               rtol=1e-6)
    assert np.all(col["log_grey_step_to_point"][::6] == 0)  # a point's own cell
    assert col["log_grey_step_to_point"][1::6].mean() > 1  # a textured neighbour's grey differs
    assert col["log_grey_range5"].min() > 0


def test_replaced_pixels_get_the_calibrated_confidence_and_the_rest_keep_the_networks():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    disparity[30:60, 40:100] = TRUE_DISPARITY + 6
    confidence = np.full((H, W), 0.3, np.float32)
    chooser = cost_chooser()
    calibrated = LidarSelect(**{**chooser.__dict__, "confidence_scale": 0.001,
                                "confidence_bias": -1.0})
    features, cells, _ = selection_features(left, right, disparity, confidence,
                                            lidar_rows(TRUE_DISPARITY))
    logits = chooser.logit(features)
    out, trust, replaced = calibrated.apply(left, right, disparity, confidence,
                                            lidar_rows(TRUE_DISPARITY))
    assert replaced == 30 * 60 and np.all(out == TRUE_DISPARITY)
    # each replaced cell: sigmoid(0.001 · its logit − 1); the cells' logits differ
    hc, wc = cell_shape((H, W))
    per_cell = np.zeros(hc * wc, np.float32)
    per_cell[cells] = 1 / (1 + np.exp(-(0.001 * logits - 1.0)))
    expected = np.repeat(np.repeat(per_cell.reshape(hc, wc), 2, 0), 2, 1)[30:60, 40:100]
    np.testing.assert_allclose(trust[30:60, 40:100], expected, rtol=1e-5)
    assert trust[30:60, 40:100].std() > 0.01
    trust[30:60, 40:100] = 0.3
    assert np.all(trust == 0.3)  # the network's elsewhere
    _, unchanged, _ = chooser.apply(left, right, disparity, confidence,
                                    lidar_rows(TRUE_DISPARITY))
    assert unchanged is confidence  # no calibration (bundles before it): the network's
    again = LidarSelect.from_meta(calibrated.to_meta())
    assert (again.confidence_scale, again.confidence_bias) == (0.001, -1.0)
    assert LidarSelect.from_meta(chooser.to_meta()).confidence_scale is None
    with pytest.raises(ConfigError, match="lidar_select"):
        LidarSelect.from_meta({**calibrated.to_meta(), "confidence": {"scale": "x", "bias": 1}})
    # a bundle fitted before the spatial cues: says so and how to go on
    older = {**chooser.to_meta(), "features": list(FEATURES[:10])}
    with pytest.raises(ConfigError, match=r"older feature set \(10 features; this engine "
                       r"computes 17\): refit.*lidar_select = false"):
        LidarSelect.from_meta(older)


def test_the_confidence_fit_recovers_a_known_calibration():
    from edge_depth.tools.fit_select import calibrate, replaced_cells

    rng = np.random.default_rng(3)
    chooser = cost_chooser()  # logit = 100 · relu(cost5 difference) − 10
    rows = []
    for _ in range(3):
        x = np.zeros((20000, len(FEATURES)), np.float32)
        x[:, 0] = rng.uniform(0, 0.3, len(x))
        z = chooser.logit(x)
        pixels = np.full(len(x), 4)
        within1 = rng.binomial(4, 1 / (1 + np.exp(-(0.1 * z - 0.5))))
        rows.append(dict(features=x, pixels=pixels,
                         within1=np.stack([4 - within1, within1], 1).astype(float)))
    calibrated = calibrate(chooser, rows, [], {})
    scale, bias = calibrated.confidence_scale, calibrated.confidence_bias
    assert scale == pytest.approx(0.1, abs=0.01) and bias == pytest.approx(-0.5, abs=0.1)
    z, n, k = replaced_cells(rows, chooser)
    assert np.all(z > 0) and len(z) == sum(int((chooser.logit(r["features"]) > 0).sum())
                                           for r in rows)


def side_chooser(take: int) -> LidarSelect:
    """With the network's sides as candidates: prefers candidate `take` (1 the LiDAR point,
    2 the near side, 3 the far side) wherever it is available, never the others."""
    f = len(FEATURES) + len(SIDE_FEATURES)
    b2 = np.full(3, -5.0, np.float32)
    b2[take - 1] = 5.0
    return LidarSelect(mean=np.zeros(f, np.float32), std=np.ones(f, np.float32),
                       w1=np.zeros((f, 1), np.float32), b1=np.zeros(1, np.float32),
                       w2=np.zeros((1, 3), np.float32), b2=b2, side_cells=3,
                       confidence_scale=1.0, confidence_bias=0.0)


def block_frame() -> tuple[np.ndarray, ...]:
    """A plane at TRUE_DISPARITY the LiDAR agrees with, and a network that put a block 6 px
    nearer on it (cells 15–29 × 20–49)."""
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    disparity[30:60, 40:100] = TRUE_DISPARITY + 6
    return left, right, disparity, np.full((H, W), 0.5, np.float32), lidar_rows(TRUE_DISPARITY)


def test_with_sides_a_cell_can_take_the_networks_near_side_where_the_lidar_agrees():
    left, right, disparity, confidence, sparse = block_frame()
    features, cells, values = selection_features(left, right, disparity, confidence, sparse,
                                                 side_cells=3)
    assert features.shape == (len(cells), len(FEATURES) + len(SIDE_FEATURES))
    assert values.shape == (len(cells), 3)
    hc, wc = cell_shape((H, W))
    ring = np.zeros((hc, wc), bool)
    ring[14:31, 19:51] = True
    ring[15:30, 20:50] = False  # the cells around the block: only their near side differs
    rows = np.isin(cells, np.flatnonzero(ring))
    assert rows.sum() == ring.sum() == 94
    assert np.all(available(features)[rows] == [False, True, False])
    np.testing.assert_array_equal(values[rows, 1], TRUE_DISPARITY + 6)
    out, trust, replaced = side_chooser(2).apply(left, right, disparity, confidence, sparse)
    assert replaced == 94 * CELL_PX * CELL_PX  # the ring grows the block by a cell
    np.testing.assert_array_equal(out[28:62, 38:102], TRUE_DISPARITY + 6)
    np.testing.assert_array_equal(out[:, :38], TRUE_DISPARITY)
    np.testing.assert_allclose(trust[28, 38], 1 / (1 + np.exp(-5.0)), rtol=1e-6)
    # the LiDAR point where it is a candidate: the block's cells
    out, _, replaced = side_chooser(1).apply(left, right, disparity, confidence, sparse)
    assert replaced == 30 * 60
    np.testing.assert_array_equal(out, TRUE_DISPARITY)


def test_a_selection_with_sides_survives_model_json_and_refuses_a_mismatch():
    left, right, disparity, confidence, sparse = block_frame()
    chooser = side_chooser(3)
    meta = chooser.to_meta()
    again = LidarSelect.from_meta(meta)
    assert again.side_cells == 3 and again.b2.shape == (3,)
    np.testing.assert_array_equal(again.apply(left, right, disparity, confidence, sparse)[0],
                                  chooser.apply(left, right, disparity, confidence, sparse)[0])
    with pytest.raises(ConfigError, match="lidar_select"):
        LidarSelect.from_meta({**meta, "w2": [[0.0]]})
    with pytest.raises(ConfigError, match=r"older feature set \(17 features; this engine "
                       r"computes 22\)"):
        LidarSelect.from_meta({**meta, "features": list(FEATURES)})


def test_the_fitting_tool_scores_sides_exactly_as_the_engine_applies_them():
    from edge_depth.tools.fit_select import frame_row, replaced_cells, score

    left, right, disparity, confidence, sparse = block_frame()
    gt = np.full((H, W), TRUE_DISPARITY, np.float32)
    gt[:, :20] = 0  # unknown
    gt[29:61, 39:101] = TRUE_DISPARITY + 6  # the truth's block is a pixel wider: cells half in
    row = frame_row("rig", left, right, disparity, confidence, sparse, gt, side_cells=3)
    for take in (1, 2, 3):
        out, _, replaced = side_chooser(take).apply(left, right, disparity, confidence, sparse)
        err = np.abs(out - gt)[gt > 0]
        epe, bad3 = score([row], side_chooser(take))
        assert epe == pytest.approx(float(err.mean()), rel=1e-5)
        assert bad3 == pytest.approx(100.0 * float((err > 3).mean()), rel=1e-5)
        margins, pixels, _ = replaced_cells([row], side_chooser(take))
        assert pixels.sum() == replaced and np.all(margins == 5.0)


def test_fit_with_sides_learns_which_candidate_to_take():
    pytest.importorskip("torch")
    from edge_depth.tools.fit_select import fit, score

    rng = np.random.default_rng(0)
    names = FEATURES + SIDE_FEATURES
    rows = []
    for _ in range(4):
        n = 4000  # cells of one known pixel each
        x = rng.normal(size=(n, len(names))).astype(np.float32)
        for name in ("log_disagreement", "near_minus_net", "net_minus_far"):  # all available
            x[:, names.index(name)] = np.log1p(rng.uniform(2, 6, n))
        best = np.select([x[:, 0] > 0.5, x[:, 1] > 0.5, x[:, 2] > 0.5], [1, 2, 3], 0)
        err = np.full((n, 4), 5.0)
        err[np.arange(n), best] = 0.2
        rows.append(one_pixel_cells(x, err))
    select = fit(rows[1:], hidden=16, steps=300, seed=0, side_cells=3)
    assert select.side_cells == 3 and select.w2.shape == (16, 3)
    before, after = score(rows[:1], None), score(rows[:1], select)
    assert before[0] > 3.0 and after[0] < 0.8 and after[1] < 12.0


def test_the_vectorised_helpers_match_numpy():
    x = np.linspace(-60, 60, 2001, dtype=np.float32).reshape(3, -1)[:, :-1]
    out = tanh32(x)
    assert out.dtype == np.float32 and out.shape == x.shape
    np.testing.assert_allclose(out, np.tanh(x.astype(np.float64)), atol=3e-7)
    rng = np.random.default_rng(1)
    mean, std = rng.normal(size=5), rng.uniform(0.5, 2, 5)
    w1, b1, w2, b2 = rng.normal(size=(5, 7)), rng.normal(size=7), rng.normal(size=(7, 3)), \
        rng.normal(size=3)
    features = rng.normal(size=(5000, 5)).astype(np.float32)  # beyond the 4096 tiled rows
    expected = np.maximum(((features - mean) / std) @ w1 + b1, 0) @ w2 + b2
    scorer = Perceptron(mean, std, w1, b1, w2, b2)
    np.testing.assert_allclose(scorer(features[:10]), expected[:10], rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(scorer(features), expected, rtol=1e-4, atol=1e-4)
    assert scorer(features[:0]).shape == (0, 3)
    for n in (1, 6):  # the features' interleave, from float64 and strided columns too
        columns = [rng.normal(size=n), rng.normal(size=(n, 2)).astype(np.float32)[:, 1],
                   np.arange(n, dtype=np.float32)]
        matrix = feature_matrix(columns)
        assert matrix.dtype == np.float32 and matrix.shape == (n, 3)
        np.testing.assert_array_equal(matrix, np.stack(columns, 1).astype(np.float32))
    left, right = (rng.uniform(0, 255, (6, 9)).astype(np.float32) for _ in range(2))
    disparity = rng.uniform(-1, 12, (6, 9)).astype(np.float32)  # some read beyond the border
    pixels = np.array([0, 8, 17, 30, 53])
    np.testing.assert_array_equal(warp_error_at(left, right, pixels, disparity.ravel()[pixels]),
                                  warp_error(left, right, disparity).ravel()[pixels])
    assert np.any(warp_error(left, right, disparity) == 255.0)
    left, right = (rng.uniform(0, 255, (200, 320)).astype(np.float32) for _ in range(2))
    disparity = rng.uniform(-1, 40, (200, 320)).astype(np.float32)
    pixels = np.arange(0, 64000, 1)[rng.random(64000) < 0.7]  # more than remap's 32 767
    np.testing.assert_array_equal(warp_error_at(left, right, pixels, disparity.ravel()[pixels]),
                                  warp_error(left, right, disparity).ravel()[pixels])
    scratch = Scratch()  # the same values into one reused buffer, grown when a frame needs
    first = feature_matrix([np.arange(5.0), np.ones(5)], scratch)
    np.testing.assert_array_equal(first, [[i, 1] for i in range(5)])
    again = feature_matrix([np.zeros(7), np.arange(7.0)], scratch)
    assert np.shares_memory(first, again)
    np.testing.assert_array_equal(again, [[0, i] for i in range(7)])
    assert not np.shares_memory(feature_matrix([np.zeros(9000)] * 2, scratch), again)
    keys = np.arange(0, 2**24, 97, dtype=np.float32)
    np.testing.assert_array_equal(key_disparity(keys), unpack_key(keys)[0])
