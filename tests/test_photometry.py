"""The right camera's grey levels matched to the left's (`[engine] match_photometry`)."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.runtime.photometry import (
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
    out, distance = PhotometricMatch().apply(left, right)
    assert distance <= THRESHOLD and out is right


def test_a_darker_right_camera_is_mapped_back_onto_the_left_grey_levels():
    left = _texture(1)
    right = _darker(np.roll(left, 3, axis=1))
    out, distance = PhotometricMatch().apply(left, right)
    assert distance > 0.15 and out.dtype == np.float32
    before = np.abs(right[:, 3:].astype(np.float32) - left[:, :-3]).mean()
    after = np.abs(out[:, 3:] - left[:, :-3]).mean()
    assert before > 15 and after < 1.5
    # the mapping keeps the right image's order of grey levels
    assert np.all(np.diff(matching_table(left, right)) >= 0)


def test_the_engine_matches_only_when_asked_and_says_how_far_apart_the_pair_was():
    from edge_depth.runtime.engine import Engine

    left = _texture(2, (400, 640))
    right = _darker(np.roll(left, 4, axis=1))
    sparse = np.zeros(left.shape, np.float32)
    plain, matched = Engine(runtime="onnxruntime"), Engine(runtime="onnxruntime",
                                                           match_photometry=True)
    assert plain.infer(left, right, sparse, iters=1).photometry_distance is None
    assert plain._inputs["right"][0, 0].max() == right.max()  # as given
    result = matched.infer(left, right, sparse, iters=1)
    assert result.photometry_distance == pytest.approx(histogram_distance(left, right))
    fed = matched._inputs["right"][0, 0]
    assert np.abs(fed[:, 4:] - left[:, :-4]).mean() < 1.5


def test_the_closing_summary_counts_the_frames_whose_right_image_was_matched():
    from edge_depth.daemon import selection_summary, summarise

    timings = [dict(engine=50.0, photometry_distance=d) for d in (0.03, 0.2, 0.3)]
    assert "photometry_distance" not in summarise(timings)
    assert selection_summary(timings) == (
        "Photometry: the right image matched to the left's grey levels in 2 of 3 frames "
        f"(histogram distance median 0.20, matched above {THRESHOLD})")


def test_float_and_strided_images_are_measured_as_their_grey_levels():
    left = _texture(3)
    right = _darker(left)
    wide = np.zeros((left.shape[0], 2 * left.shape[1]), np.uint8)
    wide[:, ::2] = right  # every other column: a view with a stride of 2
    view = wide[:, ::2]
    assert histogram_distance(left, view) == histogram_distance(left, right)
    out, distance = PhotometricMatch().apply(left.astype(np.float32), view)
    assert distance == histogram_distance(left, right)
    assert np.array_equal(out, PhotometricMatch().apply(left, right)[0])
