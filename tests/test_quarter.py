"""Refinement version 4 (the 1/4 stage), its losses, and the training-only auxiliary offsets
head."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edge_depth.errors import ConfigError
from edge_depth.model.config import ModelConfig
from edge_depth.model.losses import gate_loss, offset_loss
from edge_depth.model.network import SparseStereoNet, convex_upsample
from tests.test_refine import _two_plane_cell_edge


def test_local_correlation_reads_the_right_features_around_the_centre():
    from edge_depth.model.quarter import local_correlation

    torch.manual_seed(4)
    f_left, f_right = torch.randn(1, 4, 3, 12), torch.randn(1, 4, 3, 12)
    centre = torch.randint(0, 6, (1, 1, 3, 12)).float()
    got = local_correlation(f_left, f_right, centre, 2)
    assert got.shape == (1, 5, 3, 12)
    for k in range(-2, 3):
        for y in range(3):
            for x in range(12):
                j = min(max(x - int(centre[0, 0, y, x]) - k, 0), 11)
                expected = float((f_left[0, :, y, x] * f_right[0, :, y, j]).sum()) / 2.0
                assert float(got[0, k + 2, y, x]) == pytest.approx(expected, abs=1e-5)


def test_quarter_stage_starts_as_the_convex_upsampling_and_every_part_learns():
    """Version 4 adds a per-pixel residual found at 1/4 to the 8× convex estimate: with its
    residual weights at zero it is that estimate exactly; the LiDAR reaches it; the trunk,
    the offsets head and the encoder-side head get a gradient; the confidence says 0.5
    until trained; `aux` receives the offset logits for `offset_loss`."""
    from edge_depth.model.quarter import GATE_START, RADIUS, QuarterStage

    torch.manual_seed(0)
    net = SparseStereoNet(ModelConfig(refine=4))
    assert isinstance(net.refine, QuarterStage)
    with pytest.raises(ConfigError):
        SparseStereoNet(ModelConfig(refine=4, downsample=4))
    left, right, gt, _ = _two_plane_cell_edge()
    sparse, valid = torch.zeros_like(left), torch.zeros_like(left)
    sparse[..., ::4, ::2], valid[..., ::4, ::2] = gt[..., ::4, ::2], 1.0
    state = net.encode(left, right, sparse, valid)
    assert state["quarter_left"].shape == (1, 16, 8, 20)
    d, h, hl = state["disparity"], state["hidden"], state["hidden_low"]
    d, h, hl, mask = net.step(state, d, h, hl)
    quarter = net.quarter_features(state)
    with torch.no_grad():
        plain = convex_upsample(d, mask, 8)
        seen, logit = net.upsample(left, right, d, mask, sparse, valid, quarter)
        blind = net.upsample(left, right, d, mask, None, None, quarter)[0]
        assert float((seen - blind).abs().max()) > 0  # the LiDAR reaches the stage
        assert logit.shape == left.shape and float(logit.abs().max()) == 0.0
        torch.nn.init.zeros_(net.refine.residual.weight)
        start_gate = net.refine.gate.bias
        assert float(start_gate.min()) == float(start_gate.max()) == GATE_START
        torch.nn.init.constant_(start_gate, -30.0)  # the gate shut
        start = net.upsample(left, right, d, mask, sparse, valid, quarter)[0]
    torch.testing.assert_close(start, plain)
    torch.nn.init.normal_(net.refine.residual.weight, std=0.01)
    torch.nn.init.constant_(start_gate, GATE_START)
    aux: dict = {}
    out = net(left, right, sparse, valid, 2, aux=aux)[-1]
    assert aux["offsets"].shape == (1, 2 * RADIUS + 1, 8, 20)
    assert aux["gate"].shape == aux["quarter"].shape == aux["convex"].shape == gt.shape
    # the 1/4 estimate is constant over each 4×4 block
    torch.testing.assert_close(aux["quarter"][..., ::4, ::4].repeat_interleave(4, -1)
                               .repeat_interleave(4, -2), aux["quarter"])
    loss = (out - gt).abs().mean() + offset_loss(aux["offsets"], aux["centre"], gt,
                                                 torch.ones_like(gt), 4, 1) \
        + gate_loss(aux["gate"], aux["convex"], aux["quarter"], gt, torch.ones_like(gt))
    loss.backward()
    for name in ("head", "inp", "offsets", "residual", "gate"):
        grad = getattr(net.refine, name).weight.grad
        assert grad is not None and float(grad.abs().sum()) > 0, name


def test_the_auxiliary_offsets_head_trains_the_backbone_and_changes_no_output():
    """aux_offsets: in training the 1/4 matching's logits reach `aux` and its loss reaches
    the backbone; in evaluation it is not run, and the output is the plain model's."""
    torch.manual_seed(0)
    net = SparseStereoNet(ModelConfig(refine=3, aux_offsets=True))
    with pytest.raises(ConfigError, match="aux_offsets"):
        ModelConfig(refine=4, aux_offsets=True)
    left, right, gt, _ = _two_plane_cell_edge()
    sparse, valid = torch.zeros_like(left), torch.zeros_like(left)
    aux: dict = {}
    net.train()
    net(left, right, sparse, valid, 2, aux=aux)
    assert aux["offsets"].shape == (1, 9, 8, 20) and "gate" not in aux
    offset_loss(aux["offsets"], aux["centre"], gt, torch.ones_like(gt), 4, 1).backward()
    stem = next(net.encoders.parameters()).grad
    assert stem is not None and float(stem.abs().sum()) > 0  # it reaches the backbone
    net.eval()
    plain = SparseStereoNet(ModelConfig(refine=3))
    plain.load_state_dict({k: v for k, v in net.state_dict().items()
                           if not k.startswith("aux_offsets.")})
    plain.eval()
    aux = {}
    with torch.no_grad():
        out = net(left, right, sparse, valid, 2, aux=aux)[-1]
        torch.testing.assert_close(out, plain(left, right, sparse, valid, 2)[-1])
    assert "offsets" not in aux


def test_offset_loss_is_the_two_hot_cross_entropy_of_the_gt_offset_in_range():
    logits = torch.zeros(1, 5, 1, 3)  # offsets -2..2
    logits[0, 3, 0, 0] = 2.0          # pixel 0 prefers +1
    centre = torch.tensor([[[[4.0, 4.0, 4.0]]]])
    gt = torch.zeros(1, 1, 4, 12)     # read at rows/columns 1, 5, 9 (scale 4, sample 1)
    gt[0, 0, 1, 1], gt[0, 0, 1, 5], gt[0, 0, 1, 9] = 20.0, 16.0, 40.0  # +1, 0, +6 (out)
    valid = torch.ones_like(gt)
    p0 = np.exp(2.0) / (np.exp(2.0) + 4)
    expected = (-np.log(p0) - np.log(1 / 5)) / 2
    got = float(offset_loss(logits, centre, gt, valid, 4, 1))
    assert got == pytest.approx(expected, rel=1e-5)
    valid[0, 0, 1, 5] = 0.0           # no GT there: only pixel 0 counts
    assert float(offset_loss(logits, centre, gt, valid, 4, 1)) == pytest.approx(-np.log(p0))
    # between two offsets, the target is two-hot: 17 px is +0.25 → 3/4 on 0, 1/4 on +1
    gt[0, 0, 1, 1], valid[0, 0, 1, 5] = 17.0, 0.0
    p_plus1, p_other = p0, 1 / (np.exp(2.0) + 4)
    expected = -(0.75 * np.log(p_other) + 0.25 * np.log(p_plus1))
    assert float(offset_loss(logits, centre, gt, valid, 4, 1)) == pytest.approx(expected)
    gt[0, 0, 1, 1] = 24.0             # +2, the last offset: all on it
    assert float(offset_loss(logits, centre, gt, valid, 4, 1)) == pytest.approx(
        -np.log(p_other))


def test_gate_loss_weights_each_pixel_by_how_much_the_choice_matters():
    gt = torch.tensor([[[[10.0, 10.0, 10.0, 10.0]]]])
    convex = torch.tensor([[[[12.0, 10.0, 20.0, 10.5]]]])
    quarter = torch.tensor([[[[10.5, 11.0, 10.0, 10.5]]]])  # closer, farther, closer, a tie
    logit = torch.tensor([[[[0.0, 1.0, 2.0, 3.0]]]])
    valid = torch.ones_like(gt)
    bce = torch.nn.functional.binary_cross_entropy_with_logits
    # weights: 1.5, 1, 10 capped at 4, 0 — the tie counts for nothing
    expected = (1.5 * bce(logit[..., 0], torch.ones(1, 1, 1))
                + bce(logit[..., 1], torch.zeros(1, 1, 1))
                + 4.0 * bce(logit[..., 2], torch.ones(1, 1, 1))) / 4
    assert float(gate_loss(logit, convex, quarter, gt, valid)) == pytest.approx(float(expected))
    valid[..., 2] = 0.0  # no GT there
    expected = (1.5 * bce(logit[..., 0], torch.ones(1, 1, 1))
                + bce(logit[..., 1], torch.zeros(1, 1, 1))) / 3
    assert float(gate_loss(logit, convex, quarter, gt, valid)) == pytest.approx(float(expected))


def test_quarter_stage_learns_an_edge_inside_a_cell_from_the_offset_supervision():
    """The two-plane edge inside a 1/8 cell, the convex estimate uniform (blurred): trained
    with L1, the offsets' cross-entropy and the gate's target, the stage puts the edge where
    the images put it."""
    from edge_depth.model.quarter import SAMPLE, SCALE, QuarterStage

    torch.manual_seed(0)
    stage = QuarterStage(backbone=1)
    left, right, gt, low = _two_plane_cell_edge()
    full = convex_upsample(low, torch.zeros(1, 9 * 64, 4, 10), 8)
    pairs = torch.cat([left, right])
    opt = torch.optim.Adam(stage.parameters(), lr=3e-3)
    inner = (slice(None), slice(None), slice(4, 28), slice(12, 76))  # away from borders
    for _ in range(150):
        feats = stage.head(torch.nn.functional.avg_pool2d(pairs, SCALE) / 127.5 - 1.0)
        refined, _, extras = stage(*feats.chunk(2, 0), full, image=left)
        error = (refined - gt)[inner]
        ones = torch.ones_like(gt)
        loss = error.abs().mean() \
            + offset_loss(extras["offsets"], extras["centre"], gt, ones, SCALE, SAMPLE) \
            + gate_loss(extras["gate"], full, extras["quarter"], gt, ones)
        opt.zero_grad()
        loss.backward()
        opt.step()
    convex_error = float((full - gt)[inner].abs().mean())
    assert float(error.detach().abs().mean()) < 0.3 * convex_error
