"""Shared fixtures: small synthetic scenes (rendered once per session)."""

from __future__ import annotations

import pytest

from edge.sim import RigConfig, make_sample


@pytest.fixture(scope="session")
def small_rig() -> RigConfig:
    return RigConfig(width=320, height=200, focal_px=225.0, max_disparity_px=30.0)


@pytest.fixture(scope="session")
def noiseless_samples(small_rig):
    """Scenes with photometric noise off and a noiseless LiDAR, for exact checks."""
    from edge.sim import PATTERNS

    pattern = PATTERNS["beams64"].noiseless()
    return [make_sample(seed, small_rig.noiseless(), pattern) for seed in range(4)]
