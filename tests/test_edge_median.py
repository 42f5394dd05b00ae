"""The grey-guided weighted median over the network's unsure edges (edge.runtime.edge_median)."""

import numpy as np
import pytest

from edge_depth.errors import ConfigError
from edge_depth.runtime.edge_median import (
    MAX_DISPARITY_PX,
    PATTERNS,
    SUBPIXEL,
    EdgeMedian,
    disparity_steps,
    sorting_network,
)


def apply_network(pairs, values: np.ndarray) -> np.ndarray:
    out = values.copy()
    for a, b in pairs:
        low = np.minimum(out[a], out[b])
        out[b] = np.maximum(out[a], out[b])
        out[a] = low
    return out


@pytest.mark.parametrize("count", [9, 16])
def test_the_sorting_network_sorts_every_zero_one_input(count):
    # the 0-1 principle: a comparator network that sorts every 0/1 input sorts everything
    inputs = (np.arange(2 ** count)[None, :] >> np.arange(count)[:, None]) & 1
    np.testing.assert_array_equal(apply_network(sorting_network(count), inputs),
                                  np.sort(inputs, axis=0))


def test_the_sorting_network_sorts_25_samples():
    values = np.random.default_rng(0).normal(size=(25, 20000)).astype(np.float32)
    values[:, :100] = 1.0                                              # ties
    pairs = sorting_network(25)
    assert len(pairs) < 150                                           # 25 log² 25 / 4 or so
    np.testing.assert_array_equal(apply_network(pairs, values), np.sort(values, axis=0))


def direct_median(median: EdgeMedian, disparity, grey, y, x) -> float:
    """The weighted median at one pixel, written out: each sample's weight from the table,
    the values in order, the first whose running weight reaches half the total."""
    h, w = disparity.shape
    level = np.clip(np.rint(grey), 0, 255).astype(int)
    values, weights = [], []
    for dy, dx in median.offsets:
        yy, xx = min(max(y + dy, 0), h - 1), min(max(x + dx, 0), w - 1)   # edge replicated
        values.append(disparity[yy, xx])
        weights.append(median.weight_table[abs(level[yy, xx] - level[y, x])])
    order = np.argsort(values, kind="stable")
    running = np.cumsum(np.asarray(weights)[order])
    return float(np.asarray(values)[order][np.argmax(running * 2 >= running[-1])])


@pytest.mark.parametrize("pattern", sorted(PATTERNS))
def test_the_median_is_the_written_out_weighted_median_at_each_masked_pixel(pattern):
    rng = np.random.default_rng(1)
    h, w = 48, 64
    disparity = np.rint(rng.uniform(0, 90, (h, w)) * 16).astype(np.float32) / 16  # 1/16 px
    grey = rng.integers(0, 256, (h, w)).astype(np.float32)
    grey[:, w // 2:] = rng.integers(120, 140, (h, w - w // 2))       # a flat half: big weights
    mask = rng.random((h, w)) < 0.4
    median = EdgeMedian(pattern)
    out = median.apply(disparity, grey, mask)
    np.testing.assert_array_equal(out[~mask], disparity[~mask])        # the rest untouched
    ys, xs = np.nonzero(mask)
    expected = [direct_median(median, disparity, grey, y, x) for y, x in zip(ys, xs, strict=True)]
    np.testing.assert_array_equal(out[ys, xs], np.asarray(expected, np.float32))
    assert np.mean(out[ys, xs] != disparity[ys, xs]) > 0.3          # it did change values


def test_passes_over_the_gate_give_the_one_pass_output(monkeypatch):
    import edge_depth.runtime.edge_median as edge_median

    rng = np.random.default_rng(4)
    disparity = rng.uniform(0, 60, (60, 80)).astype(np.float32)
    grey = rng.uniform(0, 255, (60, 80)).astype(np.float32)
    mask = rng.random((60, 80)) < 0.5
    whole = EdgeMedian().apply(disparity, grey, mask)                 # ~2 400 px: one pass
    monkeypatch.setattr(edge_median, "CHUNK_PX", 97)                  # ~25 passes, uneven
    np.testing.assert_array_equal(EdgeMedian().apply(disparity, grey, mask), whole)


def test_an_empty_mask_gives_an_unchanged_copy():
    disparity = np.random.default_rng(2).uniform(0, 60, (120, 160)).astype(np.float32)
    out = EdgeMedian().apply(disparity, np.zeros_like(disparity), np.zeros((120, 160), bool))
    assert out is not disparity
    np.testing.assert_array_equal(out, disparity)


def test_a_non_finite_value_does_not_spread_to_its_neighbours():
    disparity = np.full((40, 40), 20.0, np.float32)
    disparity[20, 20], disparity[10, 10] = np.nan, np.inf
    grey = np.full((40, 40), 100.0, np.float32)
    mask = np.ones((40, 40), bool)
    mask[10, 10] = False                                   # left as it is: inf stays inf
    out = EdgeMedian().apply(disparity, grey, mask)
    assert np.isinf(out[10, 10]) and np.isfinite(np.delete(out.ravel(), 10 * 40 + 10)).all()
    np.testing.assert_array_equal(np.delete(out.ravel(), 10 * 40 + 10), 20.0)


def test_salt_and_a_misplaced_edge_go_back_to_the_image_edge():
    """A depth step whose edge sits 2 px off the image's, with 5 % wrong pixels around it:
    the grey-guided median puts the step back on the image's edge; a plain median cannot
    (every pixel there sees both sides)."""
    rng = np.random.default_rng(3)
    h, w, edge = 60, 80, 40
    grey = np.where(np.arange(w)[None, :] < edge, 60.0, 190.0) * np.ones((h, 1))
    grey += rng.normal(0, 2, (h, w))
    truth = np.where(np.arange(w)[None, :] < edge, 30.0, 12.0) * np.ones((h, 1))
    got = np.where(np.arange(w)[None, :] < edge + 2, 30.0, 12.0) * np.ones((h, 1))
    salt = rng.random((h, w)) < 0.05
    got[salt] = rng.uniform(0, 60, salt.sum())
    band = np.abs(np.arange(w) - edge)[None, :].repeat(h, 0) < 8
    out = EdgeMedian().apply(got.astype(np.float32), grey, band)
    inner = band.copy()
    inner[:4], inner[-4:] = False, False                                 # away from the border
    assert np.mean(np.abs(got - truth)[inner] < 0.5) < 0.85
    assert np.mean(np.abs(out - truth)[inner] < 0.5) > 0.99
    np.testing.assert_array_equal(out[~band], got[~band].astype(np.float32))


def test_a_bad_pattern_or_width_is_one_clear_line(tmp_path):
    from edge_depth.config import load_robot_config
    from edge_depth.runtime.engine import Engine
    from edge_depth.tools import evaluate

    for bad in ("5x5", "9x9"):
        with pytest.raises(ConfigError, match="edge_median.*9x9/2"):
            EdgeMedian(bad)
    with pytest.raises(ConfigError, match="positive"):
        EdgeMedian(sigma_grey=0.0)
    with pytest.raises(ConfigError, match="edge_median"):
        Engine(refine="off", precision="int8", threads=1, edge_median="5x5")
    path = tmp_path / "c.toml"
    path.write_text('[engine]\nedge_median = "5x5"\n')
    with pytest.raises(ConfigError, match="edge_median"):
        load_robot_config(path)
    path.write_text('[engine]\nedge_median = "off"\n')
    assert load_robot_config(path).engine.edge_median == "off"
    path.write_text("[engine]\n")
    assert load_robot_config(path).engine.edge_median == "bundle"    # the bundle's
    with pytest.raises(SystemExit):
        evaluate.main([str(tmp_path), "--edge-median", "5x5"])


def test_the_command_line_and_the_config_offer_exactly_the_patterns():
    import argparse

    from edge_depth.config import CHOICES
    from edge_depth.runtime.edge_median import OFF
    from edge_depth.runtime.options import BUNDLE, add_engine_arguments

    parser = argparse.ArgumentParser()
    add_engine_arguments(parser)
    flag = next(a for a in parser._actions if a.dest == "edge_median")
    assert tuple(flag.choices) == (BUNDLE, OFF, *PATTERNS)
    assert CHOICES[("engine", "edge_median")] == (BUNDLE, OFF, *PATTERNS)


def test_the_engine_takes_it_from_the_bundle_or_the_caller():
    from edge_depth.runtime.engine import Engine

    shipped = Engine(refine="off", precision="int8", threads=1)
    assert shipped.median is not None and shipped.median.pattern == "9x9/2"
    assert shipped.describe().endswith("no refinement, weighted median 9x9/2 (the bundle's)")
    off = Engine(refine="off", precision="int8", threads=1, edge_median="off")
    assert off.median is None and "median" not in off.describe()
    other = Engine(refine="off", precision="int8", threads=1, edge_median="9x9/4")
    assert other.describe().endswith("weighted median 9x9/4")


def test_the_gate_is_the_unsure_pixels_at_a_depth_edge():
    from edge_depth.runtime.edge_median import unsure_edges

    disparity = np.full((20, 30), 10.0, np.float32)
    disparity[:, 15:] = 20.0                                         # an edge at column 15
    confidence = np.full((20, 30), 0.5, np.float32)
    confidence[:10] = 0.95                                           # sure in the top half
    gate = unsure_edges(disparity, confidence)
    assert not gate[:10].any()                                       # sure: never gated
    assert gate[10:, 13:17].all() and not gate[10:, :12].any() and not gate[10:, 18:].any()


@pytest.mark.parametrize("odd", [None, np.nan, np.inf, -np.inf, MAX_DISPARITY_PX, 1e30])
def test_the_disparity_steps_are_the_clipped_rounded_sixteenths_whatever_the_frame_holds(odd):
    # OpenCV's saturating conversion where the frame is finite and in range, numpy's
    # otherwise: both must give the same steps (halves rounded to even, negatives to 0)
    rng = np.random.default_rng(3)
    disparity = (rng.random((40, 64)) * 300 - 20).astype(np.float32)
    disparity[0, :6] = [0.03125, 0.09375, -0.03125, -7.0, 2.5 / 16, 4095.96875]
    if odd is not None:
        disparity[5, 5] = odd
    finite = np.nan_to_num(disparity, nan=0.0, posinf=MAX_DISPARITY_PX, neginf=0.0)
    expected = np.rint(np.clip(finite, 0.0, MAX_DISPARITY_PX) * SUBPIXEL).astype(np.uint16)
    steps = disparity_steps(disparity)
    assert steps.dtype == np.uint16
    np.testing.assert_array_equal(steps, expected)
    assert list(steps[0, :4]) == [0, 2, 0, 0]  # 0.5 and 1.5 steps: to the even neighbour
