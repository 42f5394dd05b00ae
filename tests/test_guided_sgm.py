"""edge.guided_sgm: census SGM recovers known disparities, Poggi et al.'s guidance resolves what
matching alone cannot, and the +LiDAR variant keeps the LiDAR where it measured."""

from __future__ import annotations

import json

import cv2
import numpy as np

from edge_depth.guided_sgm import (
    GuidedSgmConfig,
    census_cost,
    guide_cost,
    guided_sgm,
    guided_sgm_lidar,
)

SIZE = (48, 96)  # (H, W) px


def shifted_pair(texture: np.ndarray, disparity: int, seed: int = 0,
                 noise: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A fronto-parallel plane at `disparity` px: left(x) = right(x − disparity), each view
    with its own sensor noise (grey levels); uint8 (H, W) each, cut from a wider `texture`."""
    rng = np.random.default_rng(seed)
    h, w = SIZE
    left = texture[:h, :w]
    right = texture[:h, disparity:disparity + w]
    def shot(image):  # noqa: E306
        return np.clip(image + rng.normal(0, noise, image.shape), 0, 255).astype(np.uint8)
    return shot(left), shot(right)


def random_texture(seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    h, w = SIZE
    noise = rng.uniform(0, 255, (h, w + 32)).astype(np.float32)
    return cv2.GaussianBlur(noise, (0, 0), 1.0) * 2.0 - 128.0 + 64.0


def stripes(period: int) -> np.ndarray:
    """Vertical sinusoidal stripes: every shift by a multiple of `period` matches equally."""
    h, w = SIZE
    xs = np.arange(w + 32, dtype=np.float32)
    return np.tile(128 + 80 * np.sin(2 * np.pi * xs / period), (h, 1))


def epe_inside(disparity: np.ndarray, truth: float, margin: int) -> float:
    """Mean |error| over the pixels whose match lies inside both images and away from the
    census border; holes (0) count as errors."""
    inner = disparity[4:-4, margin:-5]
    return float(np.mean(np.abs(inner - truth)))


def test_census_sgm_recovers_a_textured_plane():
    left, right = shifted_pair(random_texture(), disparity=7)
    disparity = guided_sgm(left, right, None, GuidedSgmConfig(num_disparities=24))
    assert epe_inside(disparity, 7.0, margin=7 + 5) < 0.1
    assert np.mean(disparity[4:-4, 12:-5] > 0) > 0.97  # the LR check keeps the plane


def test_guidance_zeroes_the_cost_at_the_lidar_value_and_raises_it_elsewhere():
    config = GuidedSgmConfig(num_disparities=16, k=10.0, c=1.0)
    cost = np.full((2, 3, 16), 20, np.int16)
    sparse = np.zeros((2, 3), np.float32)
    sparse[1, 2] = 5.0
    guided = guide_cost(cost, sparse, config)
    assert guided[1, 2, 5] == 0
    assert guided[1, 2, 6] == round(20 * 10 * (1 - np.exp(-0.5)))  # 1 px off: 79
    assert guided[1, 2, 15] == 200  # far from the LiDAR: k × the cost
    assert np.array_equal(guided[0], cost[0])  # pixels without a point are untouched


def test_lidar_guidance_resolves_repetitive_stripes():
    # stripes of period 8: disparities 3, 11 and 19 match equally well; the truth is 11
    left, right = shifted_pair(stripes(8), disparity=11, seed=2)
    config = GuidedSgmConfig(num_disparities=24)
    sparse = np.zeros(SIZE, np.float32)
    sparse[::6, ::2] = 11.0 + np.random.default_rng(3).normal(0, 0.1, sparse[::6, ::2].shape)
    plain = guided_sgm(left, right, None, config)
    guided = guided_sgm(left, right, sparse, config)
    assert epe_inside(plain, 11.0, margin=24) > 5.0  # matching alone picks other periods
    assert epe_inside(guided, 11.0, margin=24) < 1.5  # the rest: the LR check's holes
    assert right_period_share(plain, 11.0, margin=24) < 0.6
    assert right_period_share(guided, 11.0, margin=24) > 0.97


def right_period_share(disparity: np.ndarray, truth: float, margin: int) -> float:
    """Among the pixels the left-right check kept, the share within 1 px of the truth."""
    inner = disparity[4:-4, margin:-5]
    kept = inner[inner > 0]
    return float(np.mean(np.abs(kept - truth) <= 1.0))


def test_lidar_variant_keeps_the_lidar_values_at_its_pixels():
    left, right = shifted_pair(random_texture(4), disparity=9, seed=5)
    sparse = np.zeros(SIZE, np.float32)
    sparse[10, ::2] = 9.25
    sparse[30, 1::3] = 8.5  # a point off the stereo match: it must still be kept
    disparity = guided_sgm_lidar(left, right, sparse, GuidedSgmConfig(num_disparities=24))
    valid = sparse > 0
    assert np.array_equal(disparity[valid], sparse[valid])
    assert np.all(disparity > 0)  # the holes took the nearest LiDAR point


def test_census_cost_is_zero_at_the_true_shift_of_a_noiseless_pair():
    left, right = shifted_pair(random_texture(6), disparity=5, noise=0.0)
    cost = census_cost(left, right, GuidedSgmConfig(num_disparities=12))
    inner = cost[3:-3, 5 + 4:-4]
    assert np.all(inner[..., 5] == 0)
    others = np.delete(inner, 5, axis=2)
    assert np.median(others) > 15  # a wrong shift flips about half the 62 bits


def test_evaluate_scores_both_guided_sgm_methods(tmp_path):
    from edge_depth.sim.folder import write_pfm
    from edge_depth.tools import evaluate

    h, w, shift = 64, 192, 7
    noise = np.random.default_rng(7).uniform(0, 255, (h, w + shift)).astype(np.float32)
    texture = np.clip(cv2.GaussianBlur(noise, (0, 0), 1.0) * 2.0 - 64.0, 0, 255)
    scene = tmp_path / "plane"
    scene.mkdir()
    cv2.imwrite(str(scene / "left.png"), texture[:, :w].astype(np.uint8))
    cv2.imwrite(str(scene / "right.png"), texture[:, shift:shift + w].astype(np.uint8))
    write_pfm(scene / "disp.pfm", np.full((h, w), float(shift), np.float32))
    sparse = np.zeros((h, w), np.float32)
    sparse[::8, ::2] = shift
    write_pfm(scene / "sparse.pfm", sparse)
    out = tmp_path / "eval.json"
    assert evaluate.main([str(scene), "--methods", "guided-sgm,guided-sgm+lidar",
                          "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert set(summary) == {"guided-sgm", "guided-sgm+lidar"}
    assert summary["guided-sgm"]["density"] == 100.0  # the row fill closes the check's holes
    assert summary["guided-sgm"]["bad3"] < 1.0
    assert summary["guided-sgm+lidar"]["epe"] < 0.2
