"""The stereo-only edge selection: its sides, features, the choice, model.json round trip,
and the fitting tool scoring a choice exactly as the engine applies it."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.errors import ConfigError
from edge_depth.runtime.cells import cell_shape, grey_side
from edge_depth.runtime.edge_select import (
    CANDIDATES,
    FEATURES,
    EdgeSelect,
    edge_features,
    side_values,
)
from tests.test_lidar_select import TRUE_DISPARITY, H, W, one_pixel_cells, textured_pair

BLOCK = (slice(40, 44), slice(60, 64))  # 2 × 2 cells: each cell's 3 × 3 window sees the plane


def near_chooser(max_confidence: float = np.inf) -> EdgeSelect:
    """Takes the near side where its 5×5 cost is lower than the network's by > 0.1; never
    the far side."""
    f = len(FEATURES)
    w1 = np.zeros((f, 1), np.float32)
    w1[FEATURES.index("cost5_net_minus_near"), 0] = 1.0
    w2 = np.array([[0.0, 100.0, 0.0]], np.float32)
    return EdgeSelect(mean=np.zeros(f, np.float32), std=np.ones(f, np.float32), w1=w1,
                      b1=np.zeros(1, np.float32), w2=w2,
                      b2=np.array([0.0, -10.0, -100.0], np.float32),
                      max_confidence=max_confidence, confidence_scale=0.1,
                      confidence_bias=-1.0)


def network_with_a_hole() -> np.ndarray:
    """The plane's disparity, but 6 px too far in BLOCK (a thin near object read as
    background)."""
    disparity = np.full((H, W), TRUE_DISPARITY, np.float32)
    disparity[BLOCK] = TRUE_DISPARITY - 6
    return disparity


def test_sides_are_the_local_extremes_and_grey_says_which_side_a_cell_is_on():
    net = np.zeros((9, 9), np.float32)
    net[:, 5:] = 10.1  # a step between columns 4 | 5 (kept to a quarter pixel)
    for step, column_4 in ((5, -1), (4, 1)):  # the grey step with the depth's, one left
        grey = np.where(np.arange(9) >= step, 200.0, 50.0).astype(np.float32)[None].repeat(9, 0)
        near, far, near_grey, far_grey = side_values(net, grey, 3)
        np.testing.assert_array_equal(near[:, 4], 10.0)
        np.testing.assert_array_equal(far[:, 5], 0.0)
        np.testing.assert_array_equal(near[:, :4], 0.0)
        np.testing.assert_array_equal(near_grey[:, 4], 200.0)
        side = grey_side(grey, near_grey, far_grey)
        # column 4 lies on the far side in depth; its grey is the far side's, then the near's
        assert np.all(side[:, 4] * column_4 > 0.9)
        if step == 5:
            assert np.all(side[:, 5] > 0.9)  # grey and depth both the near side's
    assert side_values(np.full((3, 3), 16000.0, np.float32), np.zeros((3, 3)), 3)[0][1, 1] \
        == 16000.0  # the packed key is still exact


def test_edge_selection_takes_the_near_side_where_the_images_agree_with_it():
    left, right = textured_pair()
    disparity = network_with_a_hole()
    confidence = np.full((H, W), 0.5, np.float32)
    out, trust, replaced = near_chooser().apply(left, right, disparity, confidence)
    assert replaced == 4 * 4  # exactly the hole: elsewhere the network's value is the near one
    np.testing.assert_array_equal(out, TRUE_DISPARITY)
    assert disparity[BLOCK].max() == TRUE_DISPARITY - 6  # the input is not modified
    # the replaced pixels' confidence: sigmoid(0.1 · margin − 1) with a margin > 0
    assert np.all(trust[BLOCK] > 1 / (1 + np.exp(1.0)))
    assert np.all(trust[:, :50] == 0.5)


def test_edge_selection_keeps_confident_cells_and_a_flat_frame():
    left, right = textured_pair()
    disparity = network_with_a_hole()
    confidence = np.full((H, W), 0.95, np.float32)
    out, _, replaced = near_chooser(0.9).apply(left, right, disparity, confidence)
    assert replaced == 0 and out is disparity
    flat = np.full((H, W), TRUE_DISPARITY, np.float32)
    features, cells, values = edge_features(left, right, flat, np.zeros_like(flat))
    assert features.shape == (0, len(FEATURES)) and not len(cells) and values.shape == (0, 2)


def test_edge_features_measure_the_candidates():
    left, right = textured_pair()
    features, cells, values = edge_features(left, right, network_with_a_hole(),
                                            np.full((H, W), 0.25, np.float32))
    hc, wc = cell_shape((H, W))
    rows, cols = np.divmod(cells, wc)
    # the cells within 1 cell of the hole (cell rows 20-21, columns 30-31)
    assert rows.min() == 19 and rows.max() == 22 and cols.min() == 29 and cols.max() == 32
    assert len(cells) == 4 * 4
    np.testing.assert_array_equal(values[:, 0], TRUE_DISPARITY)
    np.testing.assert_array_equal(values[:, 1], TRUE_DISPARITY - 6)
    col = {name: features[:, i] for i, name in enumerate(FEATURES)}
    inside = (rows >= 20) & (rows <= 21) & (cols >= 30) & (cols <= 31)
    np.testing.assert_allclose(col["near_minus_net"][inside], np.log1p(6.0), rtol=1e-6)
    np.testing.assert_allclose(col["net_minus_far"][~inside], np.log1p(6.0), rtol=1e-6)
    gain = col["cost5_net_minus_near"][inside]  # the near side matches, the network does not
    assert np.all(gain > 1) and gain.mean() > 10
    np.testing.assert_allclose(col["confidence"], 0.25)


def test_model_json_round_trip_and_a_damaged_entry_is_a_config_error():
    select = near_chooser(0.9)
    again = EdgeSelect.from_meta(select.to_meta())
    x = np.random.default_rng(1).normal(size=(50, len(FEATURES))).astype(np.float32)
    np.testing.assert_allclose(again.logits(x), select.logits(x), rtol=1e-6)
    assert again.max_confidence == pytest.approx(0.9) and again.side_cells == 3
    entry = select.to_meta()
    assert entry["candidates"] == list(CANDIDATES)
    for damaged in ({**entry, "features": ["other"]}, {**entry, "w2": [[1.0]]},
                    {k: v for k, v in entry.items() if k != "confidence"},
                    {**entry, "side_cells": 1}, {**entry, "cell_px": 1}):
        with pytest.raises(ConfigError, match="edge_select"):
            EdgeSelect.from_meta(damaged)


def test_the_fitting_tool_scores_a_choice_exactly_as_the_engine_applies_it():
    from edge_depth.tools.fit_edge_select import frame_row
    from edge_depth.tools.fit_select import replaced_cells, score

    left, right = textured_pair()
    gt = np.full((H, W), TRUE_DISPARITY, np.float32)
    gt[:, :20] = 0  # unknown
    disparity = network_with_a_hole() + np.float32(0.3)
    disparity[70:81, 11:61] = TRUE_DISPARITY + 2  # odd edges: cells half inside
    confidence = np.zeros((H, W), np.float32)
    row = frame_row("rig", left, right, disparity, confidence, gt, 3, np.inf)
    out, _, replaced = near_chooser().apply(left, right, disparity, confidence)
    known = gt > 0
    err = np.abs(out - gt)[known]
    epe, bad3 = score([row], near_chooser())
    assert epe == pytest.approx(float(err.mean()), rel=1e-5)
    assert bad3 == pytest.approx(100.0 * float((err > 3).mean()), rel=1e-5)
    assert epe < score([row], None)[0]  # the choice helps here
    margins, pixels, within1 = replaced_cells([row], near_chooser())
    assert pixels.sum() == replaced and np.all(margins > 0)
    assert within1.sum() == replaced  # each replaced pixel is within 1 px of the truth


def test_fit_learns_a_choice_that_lowers_the_error():
    pytest.importorskip("torch")
    from edge_depth.tools.fit_edge_select import fit, score

    rng = np.random.default_rng(0)
    rows = []
    for _ in range(4):
        n = 3000  # cells of one known pixel each
        x = rng.normal(size=(n, len(FEATURES))).astype(np.float32)
        for name in ("near_minus_net", "net_minus_far"):  # both sides 2-6 px away
            x[:, FEATURES.index(name)] = np.log1p(rng.uniform(2, 6, n))
        best = np.where(x[:, 4] > 0.5, 1, np.where(x[:, 6] > 0.5, 2, 0))  # near / far / net
        err = np.full((n, 3), 5.0)
        err[np.arange(n), best] = 0.2
        rows.append(one_pixel_cells(x, err))
    select = fit(rows[1:], hidden=8, steps=300, seed=0, side_cells=3, max_confidence=0.9)
    before, after = score(rows[:1], None), score(rows[:1], select)
    assert before[0] > 1.5 and after[0] < 0.6 and after[1] < 10.0


def test_the_fit_tools_fit_on_the_networks_own_outputs():
    """A refit of a bundle that holds both selections must not see either's choices."""
    import argparse

    from edge_depth.runtime.engine import DEFAULT_BUNDLE
    from edge_depth.tools.fit_select import fitting_engine

    args = argparse.Namespace(bundle=DEFAULT_BUNDLE, frames=300, holdout=0.25, threads=1,
                              runtime="onnxruntime")
    engine = fitting_engine(args)
    assert engine.select is None and engine.edge_select is None and engine.has_confidence
    with pytest.raises(SystemExit, match="--frames"):
        fitting_engine(argparse.Namespace(**{**vars(args), "frames": 4}))
