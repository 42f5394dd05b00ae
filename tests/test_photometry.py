"""The right camera's grey levels matched to the left's (`[engine] match_photometry`)."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.runtime.photometry import (
    STAGES_THRESHOLD,
    THRESHOLD,
    PhotometricMatch,
    histogram_distance,
    matching_table,
)


def _texture(seed: int = 0, shape=(120, 160)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    smooth = np.cumsum(np.cumsum(rng.normal(size=shape), 0), 1)
    smooth = (smooth - smooth.min()) / np.ptp(smooth)
    return np.rint(20 + 210 * smooth).astype(np.uint8)


def _darker(image: np.ndarray) -> np.ndarray:
    """A right camera 20 % darker, 12 levels of offset, gamma 1.15 (the photo variant)."""
    out = np.clip(image.astype(np.float32) * 0.8 + 12, 0, 255) / 255.0
    return np.rint(255 * out ** 1.15).astype(np.uint8)


def test_the_histogram_distance_is_the_largest_gap_of_the_cumulative_histograms():
    left = np.zeros((10, 10), np.uint8)
    right = left.copy()
    assert histogram_distance(left, right) == 0.0
    right[:3] = 200  # 30 % of the pixels moved from level 0 to 200
    assert histogram_distance(left, right) == pytest.approx(0.3)


def test_a_right_camera_that_agrees_is_left_as_it_is():
    left = _texture()
    right = np.roll(left, 3, axis=1)  # the same scene, seen 3 px over
    out, change = PhotometricMatch().apply(left, right)
    assert change <= THRESHOLD and out is right


def test_a_camera_within_the_trained_range_is_left_as_it_is():
    left = _texture(5)
    right = np.clip(np.roll(left, 3, axis=1) * 1.08, 0, 255).astype(np.uint8)  # 8 % brighter
    out, change = PhotometricMatch().apply(left, right)
    assert 5 < change <= THRESHOLD and out is right


def test_a_darker_right_camera_is_mapped_back_onto_the_left_grey_levels():
    left = _texture(1)
    right = _darker(np.roll(left, 3, axis=1))
    out, change = PhotometricMatch().apply(left, right)
    assert change > THRESHOLD and out.dtype == np.float32
    # the change is what the match moves the right image by, on average
    assert change == pytest.approx(np.abs(out - right).mean(), rel=1e-4)
    before = np.abs(right[:, 3:].astype(np.float32) - left[:, :-3]).mean()
    after = np.abs(out[:, 3:] - left[:, :-3]).mean()
    assert before > 15 and after < 1.5
    # the mapping keeps the right image's order of grey levels
    assert np.all(np.diff(matching_table(left, right)) >= 0)


def test_the_engine_matches_unless_told_not_to_and_says_by_how_much():
    from edge_depth.runtime.engine import Engine

    left = _texture(2, (400, 640))
    right = _darker(np.roll(left, 4, axis=1))
    sparse = np.zeros(left.shape, np.float32)
    plain = Engine(runtime="onnxruntime", match_photometry=False)
    assert plain.infer(left, right, sparse, iters=1).photometry_change is None
    assert plain._inputs["right"][0, 0].max() == right.max()  # as given
    matched = Engine(runtime="onnxruntime")
    result = matched.infer(left, right, sparse, iters=1)
    assert result.photometry_change == pytest.approx(PhotometricMatch().apply(left, right)[1])
    fed = matched._inputs["right"][0, 0]
    assert np.abs(fed[:, 4:] - left[:, :-4]).mean() < 1.5


def test_the_closing_summary_counts_the_frames_whose_right_image_was_matched():
    from edge_depth.frame_summary import selection_summary, summarise

    timings = [dict(engine=50.0, photometry_change=d) for d in (3.0, 25.0, 30.0)]
    assert "photometry_change" not in summarise(timings)
    assert selection_summary(timings) == (
        "Photometry: the right image matched to the left's grey levels in 2 of 3 frames (the "
        f"match would move them by a median 25.0 levels; made above {THRESHOLD:g})")
    assert selection_summary([dict(photometry_change=3.0)]) is None  # none matched


def test_float_and_strided_images_are_measured_as_their_grey_levels():
    left = _texture(3)
    right = _darker(left)
    wide = np.zeros((left.shape[0], 2 * left.shape[1]), np.uint8)
    wide[:, ::2] = right  # every other column: a view with a stride of 2
    view = wide[:, ::2]
    assert histogram_distance(left, view) == histogram_distance(left, right)
    out, change = PhotometricMatch().apply(left.astype(np.float32), view)
    assert change == PhotometricMatch().apply(left, right)[1] > THRESHOLD
    assert np.array_equal(out, PhotometricMatch().apply(left, right)[0])


def test_between_the_two_thresholds_only_the_stages_after_the_network_read_it_matched():
    from edge_depth.runtime.engine import Engine

    left = _texture(5, (400, 640))
    sparse = np.zeros(left.shape, np.float32)
    engine = Engine(runtime="onnxruntime")
    # 12 % brighter: beyond cameras that agree (STAGES_THRESHOLD), within the network's range
    right = np.clip(np.roll(left, 3, axis=1) * 1.12, 0, 255).astype(np.uint8)
    result = engine.infer(left, right, sparse, iters=1)
    assert STAGES_THRESHOLD < result.photometry_change <= THRESHOLD
    assert np.array_equal(engine._inputs["right"][0, 0], right)  # the network's: as given
    stages_right = engine._stage_pair()[1]  # the selections' and the matching's: matched
    np.testing.assert_array_equal(stages_right,
                                  PhotometricMatch().measure(left, right).mapped())
    assert np.abs(right[:, 3:].astype(np.float32) - left[:, :-3]).mean() > 10
    assert np.abs(stages_right[:, 3:] - left[:, :-3]).mean() < 1.5
    # 3 % brighter, as the real pairs' cameras: the stages read the graphs' buffer, as given
    agrees = np.clip(np.roll(left, 3, axis=1) * 1.03, 0, 255).astype(np.uint8)
    assert engine.infer(left, agrees, sparse, iters=1).photometry_change <= STAGES_THRESHOLD
    assert np.shares_memory(engine._stage_pair()[1], engine._inputs["right"])
    np.testing.assert_array_equal(engine._stage_pair()[1], agrees)
