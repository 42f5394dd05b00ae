"""Shared fixtures: small synthetic scenes (rendered once per session), a 3-frame rig
recording and the shipped int8 engine."""

from __future__ import annotations

import os
from pathlib import Path

# Where pytest-xdist runs a worker per core, each worker's torch and OpenBLAS would still start
# a thread per core: on a 2-core host two workers kept four threads busy, and the suite took
# 134 s instead of 109 s. One thread each there (set before numpy or torch is imported).
if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0")) >= (os.cpu_count() or 1):
    os.environ.setdefault("OMP_NUM_THREADS", "1")

import pytest

from edge_depth.sim import RigConfig, make_sample


@pytest.fixture(scope="session")
def small_rig() -> RigConfig:
    return RigConfig(width=320, height=200, focal_px=225.0, max_disparity_px=30.0)


@pytest.fixture(scope="session")
def noiseless_samples(small_rig):
    """Scenes with photometric noise off and a noiseless LiDAR, for exact checks."""
    from edge_depth.sim import PATTERNS

    pattern = PATTERNS["beams64"].noiseless()
    return [make_sample(seed, small_rig.noiseless(), pattern) for seed in range(4)]


RECORDING_SEED = 1_000_000
SMALL_BUNDLE = (160, 96)


@pytest.fixture(scope="session")
def small_bundle(tmp_path_factory):
    """The shipped checkpoint exported at SMALL_BUNDLE (3 iterations): (directory, meta),
    once per session for the export, quantization and engine tests."""
    pytest.importorskip("torch")
    from edge_depth.runtime.engine import DEFAULT_BUNDLE
    from edge_depth.tools.export import export

    out = tmp_path_factory.mktemp("bundle")
    meta = export(DEFAULT_BUNDLE.parent / "sparse_stereo.pt", out, SMALL_BUNDLE, default_iters=3)
    return out, meta


@pytest.fixture(scope="session")
def recording(tmp_path_factory) -> Path:
    from edge_depth.cli import main

    path = tmp_path_factory.mktemp("rec") / "rec.mcap"
    assert main(["synth", "--mcap", str(path), "--frames", "3", "--seed",
                 str(RECORDING_SEED)]) == 0
    return path


@pytest.fixture(scope="session")
def engine():
    from edge_depth.runtime.engine import Engine

    return Engine(precision="int8", threads=2)
