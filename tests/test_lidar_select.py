"""The full-resolution LiDAR selection: its features, the choice, model.json round trip, and
the fitting tool's loss and scoring."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.errors import ConfigError
from edge_depth.runtime.lidar_select import FEATURES, LidarSelect, selection_features

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
    out, replaced = cost_chooser().apply(left, right, disparity, confidence,
                                         lidar_rows(TRUE_DISPARITY))
    assert replaced == 30 * 60  # exactly the wrong block: elsewhere both candidates agree
    np.testing.assert_array_equal(out, TRUE_DISPARITY)
    assert disparity[40, 50] == TRUE_DISPARITY + 6  # the input is not modified


def test_selection_keeps_the_network_where_the_lidar_is_wrong():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    out, replaced = cost_chooser().apply(left, right, disparity, np.ones((H, W), np.float32),
                                         lidar_rows(TRUE_DISPARITY - 5))
    # only in the left border's strip, where the network's value reads the right image
    # outside its border and so costs the most
    assert 0 < replaced <= H * int(TRUE_DISPARITY)
    np.testing.assert_array_equal(out[:, int(TRUE_DISPARITY) + 2:], TRUE_DISPARITY)


def test_without_lidar_the_disparity_comes_back_unchanged():
    left, right = textured_pair()
    disparity = np.full((H, W), 3.0, np.float32)
    sparse = np.full((H, W), np.nan, np.float32)  # non-finite counts as no point
    features, pixels, _ = selection_features(left, right, disparity, disparity, sparse)
    assert features.shape == (0, len(FEATURES)) and not len(pixels)
    out, replaced = cost_chooser().apply(left, right, disparity, disparity, sparse)
    assert replaced == 0 and out is disparity


def test_features_measure_cost_disagreement_and_distance():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY + 4, np.float32)
    features, pixels, lidar = selection_features(left, right, disparity,
                                                 np.full((H, W), 0.25, np.float32),
                                                 lidar_rows(TRUE_DISPARITY))
    np.testing.assert_array_equal(pixels, np.arange(H * W))  # every pixel disagrees
    assert features.shape == (H * W, len(FEATURES))
    np.testing.assert_array_equal(lidar, TRUE_DISPARITY)
    col = {name: features[:, i] for i, name in enumerate(FEATURES)}
    inside = pixels % W >= 24  # away from the left border (the warp reads outside the image)
    assert np.all(col["cost5_net_minus_lidar"][inside] > 5)  # the LiDAR's value matches
    np.testing.assert_allclose(col["log_disagreement"], np.log1p(4.0), rtol=1e-6)
    np.testing.assert_allclose(col["lidar_minus_net"], np.tanh(-4.0 / 8.0), rtol=1e-6)
    np.testing.assert_allclose(col["confidence"], 0.25)
    # the network is 4 px off at the points themselves too
    np.testing.assert_allclose(col["log_point_residual"], np.log1p(4.0), rtol=1e-6)
    assert col["log_distance_to_lidar"].min() == 0.0  # on a LiDAR point
    # the last LiDAR row is 84: rows 85-95 are up to 11 px from a point
    assert np.expm1(col["log_distance_to_lidar"].max()) == pytest.approx(11.0, abs=0.6)


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


def test_fit_learns_a_choice_that_lowers_the_error_it_is_scored_on():
    pytest.importorskip("torch")
    from edge_depth.tools.fit_select import fit, score

    rng = np.random.default_rng(0)
    rows = []
    for _ in range(4):
        n = 4000
        x = rng.normal(size=(n, len(FEATURES))).astype(np.float32)
        lidar_better = x[:, 0] + 0.3 * x[:, 5] > 0
        err_net = np.where(lidar_better, 5.0, 0.2).astype(np.float32)
        err_lidar = np.where(lidar_better, 0.2, 5.0).astype(np.float32)
        rows.append(dict(features=x, label=lidar_better,
                         weight=np.abs(err_net - err_lidar), err_net=err_net,
                         err_lidar_at=err_lidar, where_known=np.ones(n, bool),
                         known_at=np.ones(n, bool)))
    select = fit(rows[1:], hidden=8, steps=200, seed=0)
    before, after = score(rows[:1], None), score(rows[:1], select)
    assert before == pytest.approx((2.6, 50.0), abs=1.5)
    assert after[0] < 0.5 and after[1] < 6.0


def test_a_disagreement_cap_keeps_the_network_where_the_lidar_is_too_far_off():
    left, right = textured_pair()
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    disparity[30:60, 40:100] = TRUE_DISPARITY + 6
    disparity[70:90, 40:100] = TRUE_DISPARITY + 2
    sparse = lidar_rows(TRUE_DISPARITY)
    capped = LidarSelect(**{**cost_chooser().__dict__, "max_disagreement_px": 4.0})
    _, pixels, _ = selection_features(left, right, disparity, disparity, sparse, 4.0)
    assert len(pixels) == 20 * 60  # only the 2-px block
    out, replaced = capped.apply(left, right, disparity, np.zeros((H, W), np.float32), sparse)
    assert replaced == 20 * 60
    assert np.all(out[70:90, 40:100] == TRUE_DISPARITY)
    assert np.all(out[30:60, 40:100] == TRUE_DISPARITY + 6)
    again = LidarSelect.from_meta(capped.to_meta())
    assert again.max_disagreement_px == 4.0
    assert np.isinf(LidarSelect.from_meta(cost_chooser().to_meta()).max_disagreement_px)
    with pytest.raises(ConfigError, match="lidar_select"):
        LidarSelect.from_meta({**capped.to_meta(), "max_disagreement_px": 0.1})
