"""The network's parts against the paper's equations, on hand-built inputs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from edge_depth.model.config import ModelConfig
from edge_depth.model.corr import (
    correlation_pyramid,
    correlation_volume,
    flatten_pyramid,
    lookup,
    lookup_flat,
)
from edge_depth.model.cspn import cspn, neighbours, normalise_affinity
from edge_depth.model.losses import (
    depth_edges,
    occlusion_from_range_map,
    sequence_loss,
    split_sparse,
    ssim,
    view_loss,
    warp_horizontal,
)
from edge_depth.model.network import SparseStereoNet, convex_upsample, downsample_sparse


def test_correlation_equals_an_explicit_einsum():
    g = torch.Generator().manual_seed(0)
    f_l, f_r = torch.randn(2, 8, 3, 5, generator=g), torch.randn(2, 8, 3, 5, generator=g)
    expected = torch.einsum("bchj,bchk->bhjk", f_l, f_r) / 8**0.5
    torch.testing.assert_close(correlation_volume(f_l, f_r), expected)


def test_pyramid_pools_by_two_and_lookup_interpolates_linearly():
    corr = torch.arange(8, dtype=torch.float32).view(1, 1, 1, 8).repeat(1, 1, 8, 1)
    pyramid = correlation_pyramid(corr, 2)
    torch.testing.assert_close(pyramid[1][0, 0, 0], torch.tensor([0.5, 2.5, 4.5, 6.5]))
    # left pixel x = 5 with disparity 1.5: level 0 samples positions 3.5 + (-1, 0, 1)
    disparity = torch.full((1, 1, 1, 8), 1.5)
    feats = lookup(pyramid, disparity, radius=1)  # (1, 2 * 3, 1, 8)
    torch.testing.assert_close(feats[0, :3, 0, 5], torch.tensor([2.5, 3.5, 4.5]))
    # level 1 samples at 3.5 / 2 + (-1, 0, 1) = 0.75, 1.75, 2.75 on [0.5, 2.5, 4.5, 6.5]
    torch.testing.assert_close(feats[0, 3:, 0, 5], torch.tensor([2.0, 4.0, 6.0]))
    # outside the row the correlation is zero
    far = lookup(pyramid, torch.full((1, 1, 1, 8), 20.0), radius=1)
    assert float(far.abs().max()) == 0.0


def test_single_gather_lookup_equals_the_per_level_lookup():
    g = torch.Generator().manual_seed(3)
    pyramid = correlation_pyramid(torch.randn(2, 3, 21, 21, generator=g), 4)
    # disparities inside, at the edges of and far outside the row, negative included
    disparity = torch.empty(2, 1, 3, 21).uniform_(-30, 30, generator=g)
    disparity[0, 0, 0, :5] = torch.tensor([0.0, 1.0, 20.0, 21.0, -1.0])
    expected = lookup(pyramid, disparity, radius=3)
    got = lookup_flat(flatten_pyramid(pyramid), disparity, radius=3, levels=4)
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=1e-5)


def test_cspn_follows_the_equations_on_a_hand_built_case():
    affinity = torch.zeros(1, 8, 3, 3)
    affinity[0, 1] = 2.0   # up neighbour
    affinity[0, 6] = -2.0  # down neighbour
    weights, centre = normalise_affinity(affinity)
    torch.testing.assert_close(weights.abs().sum(1), torch.ones(1, 3, 3), atol=1e-5, rtol=0)
    torch.testing.assert_close(centre, 1 - weights.sum(1, keepdim=True))
    d0 = torch.tensor([[1.0, 2, 3], [4, 5, 6], [7, 8, 9]]).view(1, 1, 3, 3)
    d1 = cspn(d0, weights, centre, steps=1)
    # centre pixel: Â_c·d0 + 0.5·up - 0.5·down = 1·5 + 0.5·2 - 0.5·8
    assert float(d1[0, 0, 1, 1]) == pytest.approx(5 + 1 - 4, abs=1e-4)
    # a constant field stays constant, whatever the affinity
    rand = torch.randn(1, 8, 4, 5, generator=torch.Generator().manual_seed(1))
    w, c = normalise_affinity(rand)
    const = torch.full((1, 1, 4, 5), 3.25)
    torch.testing.assert_close(cspn(const, w, c, steps=5), const)
    # re-injection is exact at valid pixels
    valid = torch.zeros(1, 1, 4, 5)
    valid[0, 0, 1, 2] = valid[0, 0, 3, 0] = 1
    sparse = valid * 7.0
    out = cspn(torch.randn(1, 1, 4, 5), w, c, steps=3, sparse=sparse, valid=valid)
    assert float(out[0, 0, 1, 2]) == 7.0 and float(out[0, 0, 3, 0]) == 7.0


def test_neighbours_order_and_replicated_border():
    d = torch.arange(9, dtype=torch.float32).view(1, 1, 3, 3)
    n = neighbours(d)[0, :, 1, 1]
    torch.testing.assert_close(n, torch.tensor([0.0, 1, 2, 3, 5, 6, 7, 8]))
    assert float(neighbours(d)[0, 0, 0, 0]) == 0.0  # corner replicates itself


def test_convex_upsampling_of_a_constant_is_the_scaled_constant():
    d = torch.full((1, 1, 3, 4), 2.0)
    mask = torch.randn(1, 9 * 64, 3, 4)
    up = convex_upsample(d, mask, 8)
    assert up.shape == (1, 1, 24, 32)
    torch.testing.assert_close(up, torch.full_like(up, 16.0))


def test_upsampling_mask_as_matmul_equals_the_convolutions():
    from edge_depth.model.update import UpdateBlock

    torch.manual_seed(4)
    block = UpdateBlock(hidden_dim=16, context_dim=8, corr_channels=9, factor=4)
    hidden = torch.randn(2, 16, 5, 7)
    logits = block.upsampling_mask(hidden)
    assert logits.shape == (2, 9 * 16, 5, 7)
    torch.testing.assert_close(logits, 0.25 * block.mask(hidden), atol=1e-5, rtol=1e-5)


def test_the_gru_with_the_contexts_terms_computed_once_is_the_same_step():
    from edge_depth.model.update import UpdateBlock

    torch.manual_seed(5)
    block = UpdateBlock(hidden_dim=16, context_dim=8, corr_channels=9, factor=4)
    hidden, context = torch.randn(2, 16, 5, 7), torch.randn(2, 8, 5, 7)
    corr, disparity = torch.randn(2, 9, 5, 7), torch.rand(2, 1, 5, 7) * 10
    expected = block(hidden, hidden[:, :0], context, corr, disparity)
    terms = block.context_terms(context)
    assert [t.shape[1] for t in terms] == [32, 16]  # the gates' channels, biases included
    got = block(hidden, hidden[:, :0], None, corr, disparity, terms)
    for a, b in zip(got, expected, strict=True):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
    # and it is not the same without the context: the terms carry it
    other = block(hidden, hidden[:, :0], None, corr, disparity,
                  block.context_terms(torch.zeros_like(context)))
    assert (other[0] - expected[0]).abs().max() > 1e-3
    with pytest.raises(ValueError, match="gru_levels 1"):
        UpdateBlock(16, 8, 9, 4, gru_levels=2).context_terms(context)


def test_sparse_downsampling_averages_valid_points_in_low_res_pixels():
    sparse = torch.zeros(1, 1, 8, 16)
    valid = torch.zeros(1, 1, 8, 16)
    sparse[0, 0, 1, 1], sparse[0, 0, 5, 6] = 16.0, 32.0
    valid[0, 0, 1, 1] = valid[0, 0, 5, 6] = 1
    low, low_valid = downsample_sparse(sparse, valid, 8)
    torch.testing.assert_close(low, torch.tensor([[[[3.0, 0.0]]]]))  # (16 + 32) / 2 / 8
    torch.testing.assert_close(low_valid, torch.tensor([[[[1.0, 0.0]]]]))


@pytest.mark.parametrize("downsample, half_res_block", [(4, True), (8, True), (8, False)])
def test_shapes_at_both_downsample_factors(downsample, half_res_block):
    config = ModelConfig(downsample=downsample, gru_levels=2, half_res_block=half_res_block)
    net = SparseStereoNet(config).eval()
    blocks = [m for m in net.encoders.backbone.modules() if type(m).__name__ == "ResidualBlock"]
    assert len(blocks) == (3 if half_res_block else 2)
    img = torch.rand(2, 1, 64, 96) * 255
    valid = (torch.rand(2, 1, 64, 96) < 0.05).float()
    outs = net(img, img, valid * 10, valid, iters=3)
    assert len(outs) == 3 and all(o.shape == (2, 1, 64, 96) for o in outs)
    assert all(torch.isfinite(o).all() for o in outs)


def _affinity_gradient(split: str) -> tuple[torch.Tensor, torch.Tensor]:
    torch.manual_seed(0)
    net = SparseStereoNet(ModelConfig(gru_iters=1, cspn_steps=2))
    img = torch.rand(1, 1, 64, 64) * 255
    valid = torch.zeros(1, 1, 64, 64)
    valid[0, 0, ::8, ::8] = 1  # one point per low-res cell
    gen = torch.Generator().manual_seed(3)
    inp, sup = split_sparse(valid, split, gen)
    state = net.encode(img, img, valid * 12.0 * inp, inp)
    weights = state["weights"]
    weights.retain_grad()
    d, *_ = net.step(state, state["disparity"], state["hidden"], state["hidden_low"])
    low_sup = torch.nn.functional.max_pool2d(sup, 8)
    loss = ((d - 1.5) * low_sup).abs().sum()
    loss.backward()
    return weights.grad, downsample_sparse(valid * inp, inp, 8)[1]


def test_sparse_loss_reaches_the_affinity_only_where_points_are_held_out():
    grad_half2, _ = _affinity_gradient("half2")
    assert float(grad_half2.abs().sum()) > 0
    grad_all, injected = _affinity_gradient("all")
    # with every point injected, CSPN re-injects them: no gradient at the injected pixels
    at_injected = grad_all.abs().sum(1, keepdim=True) * injected
    assert float(at_injected.sum()) == 0.0


def test_warp_ssim_and_range_map_occlusion():
    g = torch.Generator().manual_seed(0)
    right = torch.rand(1, 1, 8, 32, generator=g)
    disp = torch.full((1, 1, 8, 32), 3.0)
    left = warp_horizontal(right, disp)  # left(x) = right(x - 3)
    torch.testing.assert_close(left[..., 5:], right[..., 2:-3])
    assert float(ssim(right, right).min()) > 0.999
    # every right pixel maps to x + 3 in the left: the first 3 left columns receive nothing
    occ = occlusion_from_range_map(disp, sign=1.0)
    assert occ[..., :3].all() and not occ[..., 3:].any()


def test_losses_are_zero_for_a_perfect_prediction():
    g = torch.Generator().manual_seed(0)
    texture = torch.rand(1, 1, 16, 48, generator=g) * 255
    disp = torch.full((1, 1, 16, 40), 4.0)
    left, right = texture[..., 4:44], texture[..., 8:48]  # left(x) = right(x - 4)
    sparse = torch.zeros_like(disp)
    valid = torch.zeros_like(disp)
    valid[..., ::4, ::5] = 1
    sparse = valid * 4.0
    terms = view_loss(left, right, disp, disp, sparse, valid, -1.0)
    assert float(terms["sparse"]) == 0 and float(terms["lr"]) == 0
    assert float(terms["smooth"]) == 0 and float(terms["appearance"]) < 0.01
    wrong = view_loss(left, right, disp + 1.5, disp + 1.5, sparse, valid, -1.0)
    assert float(wrong["appearance"]) > 10 * float(terms["appearance"]) + 1e-3
    assert float(wrong["sparse"]) == pytest.approx(1.5)


def test_sequence_loss_weights_later_iterations_more():
    gt = torch.zeros(1, 1, 2, 2)
    valid = torch.ones_like(gt)
    preds = [torch.ones_like(gt), torch.zeros_like(gt)]
    assert float(sequence_loss(preds, gt, valid, 0.9)) == pytest.approx(0.9)
    assert float(sequence_loss(preds[::-1], gt, valid, 0.9)) == pytest.approx(1.0)


def test_depth_edges_mark_jumps_not_slopes_and_weight_the_loss():
    x = torch.arange(40.0).expand(1, 1, 20, 40)
    slope = 0.1 * x  # 0.9 px over any 9 px: no edge
    step = torch.where(x < 20, 10.0, 30.0)
    valid = torch.ones_like(step)
    assert float(depth_edges(slope, valid).sum()) == 0
    edges = depth_edges(step, valid)
    assert torch.equal(edges[0, 0, 0].nonzero().flatten(), torch.arange(16, 24))
    valid[..., 20:] = 0  # the far side unknown: nothing to jump to
    assert float(depth_edges(step, valid).sum()) == 0
    pred, gt = step + edges * 2, step  # wrong by 2 px on the 8 edge columns of 40
    ones = torch.ones_like(gt)
    assert float(sequence_loss([pred], gt, ones)) == pytest.approx(0.4)
    weighted = sequence_loss([pred], gt, ones, weight=1 + 3 * edges)
    assert float(weighted) == pytest.approx(8 * 4 * 2 / (8 * 4 + 32 * 1))  # a weighted mean


def test_split_strategies_partition_the_points():
    valid = (torch.rand(1, 1, 40, 40, generator=torch.Generator().manual_seed(2)) < 0.3).float()
    inp, sup = split_sparse(valid, "half2", torch.Generator().manual_seed(0))
    assert float((inp * sup).sum()) == 0 and torch.equal(inp + sup, valid)
    assert 0.3 < float(inp.sum() / valid.sum()) < 0.7
    inp1, sup1 = split_sparse(valid, "half1", torch.Generator().manual_seed(0))
    assert torch.equal(sup1, valid) and float(inp1.sum()) < float(valid.sum())
    assert all(torch.equal(t, valid) for t in split_sparse(valid, "all"))


def test_a_few_steps_on_one_batch_reduce_the_loss():
    torch.manual_seed(0)
    from edge_depth.model.data import sample_to_arrays, to_tensors
    from edge_depth.sim import RigConfig, make_sample

    rig = RigConfig(width=128, height=64, focal_px=90.0, max_disparity_px=20.0)
    arrays = sample_to_arrays(make_sample(1, rig))
    batch = {k: v[None] for k, v in to_tensors(arrays, None, np.random.default_rng(0),
                                                False).items()}
    net = SparseStereoNet(ModelConfig(gru_iters=3))
    opt = torch.optim.AdamW(net.parameters(), 2e-3)
    losses = []
    for _ in range(12):
        preds = net(batch["left"], batch["right"], batch["sparse"], batch["valid"], 3)
        loss = sequence_loss(preds, batch["gt"], torch.ones_like(batch["gt"]))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    assert np.mean(losses[-3:]) < 0.8 * np.mean(losses[:3])
