"""Scaling and padding a camera of another size onto a bundle (`edge.runtime.fit`)."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.errors import ConfigError
from edge_depth.runtime.fit import FitPlan


def test_fit_scale_is_the_largest_that_fits_and_never_enlarges():
    assert FitPlan.make((1280, 800), (640, 400)).scale == 0.5
    assert FitPlan.make((640, 480), (640, 400)).scale == pytest.approx(400 / 480)
    assert FitPlan.make((320, 200), (640, 400)).scale == 1.0
    assert FitPlan.make((640, 400), (640, 400)).identity
    with pytest.raises(ConfigError, match="engine.scale"):
        FitPlan.make((640, 400), (640, 400), 1.5)


def test_sparse_points_keep_their_value_scaled_and_padding_has_none():
    plan = FitPlan.make((1280, 800), (640, 400))
    sparse = np.zeros((800, 1280), np.float32)
    sparse[101, 301] = 40.0
    sparse[799, 1279] = 8.0
    image = np.zeros((800, 1280), np.uint8)
    left, right, small = plan.prepare(image, image, sparse)
    assert left.shape == (400, 640) and small.shape == (400, 640)
    assert small[50, 150] == 20.0 and small[399, 639] == 4.0   # half the pixels, half the px
    assert np.count_nonzero(small) == 2


def test_a_small_camera_is_padded_and_the_output_cropped_back():
    plan = FitPlan.make((320, 200), (640, 400))
    image = np.arange(200 * 320, dtype=np.float32).reshape(200, 320) % 251
    left, _, sparse = plan.prepare(image.astype(np.uint8), image.astype(np.uint8),
                                   np.zeros((200, 320), np.float32))
    assert left.shape == (400, 640)
    np.testing.assert_array_equal(left[:200, :320], image.astype(np.uint8))
    np.testing.assert_array_equal(left[:200, 320:], np.repeat(left[:200, 319:320], 320, 1))
    out = np.zeros((400, 640), np.float32)
    out[:200, :320] = 7.0
    np.testing.assert_array_equal(plan.restore(out, disparity=True), np.full((200, 320), 7.0))


def test_restored_disparity_is_in_camera_pixels():
    plan = FitPlan.make((1280, 800), (640, 400))
    out = np.full((400, 640), 10.0, np.float32)
    restored = plan.restore(out, disparity=True)
    assert restored.shape == (800, 1280) and float(restored.mean()) == pytest.approx(20.0)
    assert float(plan.restore(out, disparity=False).mean()) == pytest.approx(10.0)
