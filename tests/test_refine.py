"""The refinement stages (`edge/model/refine.py`): each version starts as the one it
extends, its new inputs reach the choice, and it learns; the confidence head and its loss."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from edge_depth.errors import ConfigError
from edge_depth.model.config import ModelConfig
from edge_depth.model.network import SparseStereoNet, convex_upsample


def test_refinement_starts_as_the_identity_and_only_the_last_step_is_refined():
    torch.manual_seed(0)
    net = SparseStereoNet(ModelConfig(gru_iters=2, refine=1)).eval()
    left = torch.rand(1, 1, 64, 96) * 255
    right = torch.rand(1, 1, 64, 96) * 255
    zeros = torch.zeros(1, 1, 64, 96)
    with torch.no_grad():
        outs, logit = net(left, right, zeros, zeros, 2, with_confidence=True)
        state = net.encode(left, right, zeros, zeros)
        d, h, hl = state["disparity"], state["hidden"], state["hidden_low"]
        d, h, hl, _ = net.step(state, d, h, hl)
        d, h, hl, mask = net.step(state, d, h, hl)
        plain = convex_upsample(d, mask, 8)
    assert logit.shape == (1, 1, 64, 96) and float(logit.abs().max()) == 0.0
    torch.testing.assert_close(outs[-1], plain)   # zero-initialised head: no residual yet
    with torch.no_grad():
        net.refine.out.bias.copy_(torch.tensor([0.5, 2.0]))
        outs, logit = net(left, right, zeros, zeros, 2, with_confidence=True)
    torch.testing.assert_close(outs[-1], plain + 1.0)  # residual 0.5 half-res px = 1 px
    assert torch.allclose(logit, torch.full_like(logit, 2.0))


def test_refinement_v2_starts_near_the_identity_sees_the_lidar_and_learns():
    """Version 2: separate heads; the residual's small non-zero start gives its features a
    gradient from the first step (version 1's zeroed shared layer gave them none), and the
    LiDAR reaches the stage."""
    from edge_depth.model.refine import Refinement

    torch.manual_seed(0)
    assert ModelConfig.from_dict({"refine": True}).refine == 1  # configs before versions
    with pytest.raises(ConfigError):
        ModelConfig(refine=11)
    stage = Refinement(2)
    left = torch.rand(1, 1, 32, 48) * 255
    right = torch.roll(left, -3, dims=3)
    disparity = torch.full((1, 1, 32, 48), 3.0)
    sparse = torch.zeros(1, 1, 32, 48)
    valid = torch.zeros(1, 1, 32, 48)
    sparse[..., ::8, ::2], valid[..., ::8, ::2] = 7.0, 1.0
    refined, logit = stage(left, right, disparity, sparse, valid)
    assert float((refined.detach() - disparity).abs().max()) < 0.05  # ~the identity
    assert logit.shape == disparity.shape
    loss = (refined - 3.5).abs().mean()
    loss.backward()
    assert float(stage.inp.weight.grad.abs().sum()) > 0  # the features learn too
    with torch.no_grad():
        without = stage(left, right, disparity)[0]
    assert float((refined.detach() - without).abs().max()) > 0  # the LiDAR changes the output


def test_confidence_loss_is_the_cross_entropy_of_being_within_a_pixel():
    from edge_depth.model.losses import confidence_loss

    gt = torch.tensor([[[[10.0, 10.0, 10.0]]]])
    disparity = torch.tensor([[[[10.5, 12.0, 3.0]]]])   # within 1 px, off, off
    logit = torch.tensor([[[[2.0, -1.0, 0.0]]]])
    valid = torch.tensor([[[[1.0, 1.0, 0.0]]]])          # the last pixel has no GT
    expected = (np.log1p(np.exp(-2.0)) + np.log1p(np.exp(-1.0))) / 2
    assert float(confidence_loss(logit, disparity, gt, valid)) == pytest.approx(expected, 1e-5)


def test_refinement_v2_trunk_gets_a_tenth_of_the_confidence_gradient(monkeypatch):
    import edge_depth.model.refine as refine

    torch.manual_seed(1)
    stage = refine.Refinement(2)
    torch.nn.init.normal_(stage.confidence.weight, std=0.1)
    left = torch.rand(1, 1, 32, 48) * 255
    args = (left, torch.roll(left, -2, dims=3), torch.full((1, 1, 32, 48), 2.0))

    def trunk_grad(share: float) -> torch.Tensor:
        monkeypatch.setattr(refine, "CONFIDENCE_TRUNK_GRAD", share)
        stage.zero_grad()
        stage(*args)[1].sum().backward()
        return stage.inp.weight.grad.clone()

    torch.testing.assert_close(trunk_grad(0.1), 0.1 * trunk_grad(1.0))
    assert float(trunk_grad(0.0).abs().max()) == 0.0


def test_matching_cost_reads_the_right_features_at_each_candidate():
    from edge_depth.model.refine import matching_cost

    torch.manual_seed(2)
    f_left, f_right = torch.randn(2, 3, 4, 10), torch.randn(2, 3, 4, 10)
    candidates = torch.rand(2, 2, 4, 10) * 6
    expected = torch.zeros(2, 2, 4, 10)
    for n in range(2):  # the second image's rows must not read the first's
        for k in range(2):
            for y in range(4):
                for x in range(10):
                    j = min(max(round(x - float(candidates[n, k, y, x])), 0), 9)
                    expected[n, k, y, x] = (f_left[n, :, y, x] - f_right[n, :, y, j]).abs().mean()
    torch.testing.assert_close(matching_cost(f_left, f_right, candidates), expected)


@pytest.mark.parametrize("factor,scale", [(8, 4), (8, 2), (4, 2)])
def test_expand_to_cells_is_nearest_upsampling_in_the_convex_layout(factor, scale):
    from edge_depth.model.refine import expand_to_cells

    torch.manual_seed(3)
    values = torch.randn(2, 3, 24 // scale, 40 // scale)
    full = F.interpolate(values, scale_factor=scale, mode="nearest")  # (2, 3, 24, 40)
    expected = F.pixel_unshuffle(full, factor).view(2, 3, factor * factor, 24 // factor,
                                                   40 // factor)
    assert torch.equal(expand_to_cells(values, factor, scale), expected)


def _two_plane_cell_edge():
    """A left image whose right half (x ≥ 44, inside the 1/8 cell 40..47) is at 10 px and
    the rest at 2 px, its right view made by shifting each part, and the 1/8 disparity
    that says 2 up to cell 5 and 10 from cell 5 on (the edge cell is wrong on its left)."""
    g = torch.Generator().manual_seed(3)
    texture = torch.rand(1, 1, 32, 112, generator=g) * 255
    left = texture[..., 16:96].clone()
    right = texture[..., 18:98].clone()  # the 2 px plane's right view everywhere
    gt = torch.full_like(left, 2.0)
    gt[..., 44:] = 10.0
    for x in range(80):
        d = int(gt[0, 0, 0, x])
        # the right view sees left pixel x at x - d: fill it from the texture by disparity
        right[..., max(x - d, 0)] = left[..., x]
    low = torch.full((1, 1, 4, 10), 2.0 / 8)
    low[..., 5:] = 10.0 / 8
    return left, right, gt, low


def test_guided_selection_starts_as_the_convex_upsampling_and_learns_the_edge():
    """Version 3 is the convex upsampling when its score is zero, is moved by the LiDAR, and
    with a few steps of training picks each pixel's candidate by how it matches."""
    from edge_depth.model.refine import GuidedSelection

    torch.manual_seed(0)
    stage = GuidedSelection(8)
    left, right, gt, low = _two_plane_cell_edge()
    mask = torch.zeros(1, 9 * 64, 4, 10)  # uniform convex weights: blurred edges
    with torch.no_grad():
        torch.nn.init.zeros_(stage.score[-1].weight)
        refined, logit = stage(left, right, low, mask)
    torch.testing.assert_close(refined, convex_upsample(low, mask, 8))
    assert logit.shape == left.shape and float(logit.abs().max()) == 0.0
    sparse = torch.zeros_like(left)
    valid = torch.zeros_like(left)
    sparse[..., ::4, ::2], valid[..., ::4, ::2] = gt[..., ::4, ::2], 1.0
    torch.nn.init.normal_(stage.score[-1].weight, std=0.5)
    with torch.no_grad():
        seen = stage(left, right, low, mask, sparse, valid)[0]
        blind = stage(left, right, low, mask)[0]
    assert float((seen - blind).abs().max()) > 0  # the LiDAR reaches the choice
    opt = torch.optim.Adam(stage.parameters(), lr=1e-2)
    inner = (slice(None), slice(None), slice(4, 28), slice(12, 76))  # away from borders
    errors = []
    for _ in range(60):
        refined = stage(left, right, low, mask)[0]
        loss = (refined - gt)[inner].abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        errors.append(float(loss.detach()))
    convex_error = float((convex_upsample(low, mask, 8) - gt)[inner].abs().mean())
    assert errors[-1] < 0.5 * convex_error  # the images decide the edge, not the 1/8 grid


def test_guided_selection_v5_starts_as_version_3_and_its_quarter_features_reach_the_choice():
    """Version 5 carried over from version 3's weights gives version 3's output exactly (the
    new inputs' weights are zero); once they are not, the 1/4 features move the choice;
    without them it says what it needs. The network hands it the backbone's 1/4 features."""
    from edge_depth.model.config import ModelConfig
    from edge_depth.model.network import SparseStereoNet
    from edge_depth.model.refine import GuidedSelection, widen_from_version3

    torch.manual_seed(0)
    v3, v5 = GuidedSelection(8), GuidedSelection(8, quarter=4)
    for p in v3.parameters():
        torch.nn.init.normal_(p, std=0.3)
    result = v5.load_state_dict(widen_from_version3(v3.state_dict(), v5, prefix=""),
                                strict=False)
    assert sorted(result.missing_keys) == ["project.bias", "project.weight"]
    left, right, gt, low = _two_plane_cell_edge()
    mask = torch.zeros(1, 9 * 64, 4, 10)
    quarter = (torch.rand(1, 4, 8, 20), torch.rand(1, 4, 8, 20))
    with torch.no_grad():
        out3, logit3 = v3(left, right, low, mask)
        out5, logit5 = v5(left, right, low, mask, quarter=quarter)
        torch.testing.assert_close(out5, out3, rtol=0, atol=0)
        torch.testing.assert_close(logit5, logit3, rtol=0, atol=0)
        torch.nn.init.normal_(v5.score[0].weight[:, 6:], std=3.0)
        moved = v5(left, right, low, mask, quarter=quarter)[0]
    assert float((moved - out3).abs().max()) > 0.1
    with pytest.raises(ValueError, match="1/4 features"):
        v5(left, right, low, mask)
    net = SparseStereoNet(ModelConfig(refine=5, half_res_block=False))
    state = net.encode(left, right, torch.zeros_like(left), torch.zeros_like(left))
    assert state["quarter_left"].shape == (1, net.config.widths[1], 8, 20)


def test_guided_selection_v6_starts_as_version_5_and_its_context_spans_neighbours():
    """Version 6 with version 5's weights gives version 5's output exactly (its context
    scorer's output layer starts at zero); once trained, a change of the image at one 1/4
    pixel moves the choice 7 1/4-pixels away, beyond version 5's reach (its features' two
    3x3 layers and its 7x7 cost average: 5), within version 6's (3 more)."""
    from edge_depth.model.config import ModelConfig
    from edge_depth.model.network import SparseStereoNet
    from edge_depth.model.refine import GuidedSelection

    torch.manual_seed(0)
    v5, v6 = GuidedSelection(8, quarter=4), GuidedSelection(8, quarter=4, context=8)
    for p in v5.parameters():
        torch.nn.init.normal_(p, std=0.3)
    result = v6.load_state_dict(v5.state_dict(), strict=False)
    assert sorted(result.missing_keys) == sorted(
        f"context.{i}.{k}" for i in (0, 2, 4) for k in ("weight", "bias"))
    left, right, gt, low = _two_plane_cell_edge()
    mask = torch.zeros(1, 9 * 64, 4, 10)
    quarter = (torch.rand(1, 4, 8, 20), torch.rand(1, 4, 8, 20))
    poked = left.clone()
    poked[..., 12:16] += 60.0  # the 1/4 column 3
    with torch.no_grad():
        out5, logit5 = v5(left, right, low, mask, quarter=quarter)
        out6, logit6 = v6(left, right, low, mask, quarter=quarter)
        torch.testing.assert_close(out6, out5, rtol=0, atol=0)
        torch.testing.assert_close(logit6, logit5, rtol=0, atol=0)
        torch.nn.init.normal_(v6.context[-1].weight, std=3.0)
        moved = {name: (module(left, right, low, mask, quarter=quarter)[0]
                        - module(poked, right, low, mask, quarter=quarter)[0]).abs()
                 for name, module in (("v5", v5), ("v6", v6))}
    # the candidates differ only near the edge cell (x 32..55): the choice matters there
    assert float(moved["v5"][..., 32:36].max()) > 1e-3  # the 1/4 column 8: within reach
    assert float(moved["v5"][..., 40:].max()) == 0.0  # from the 1/4 column 10 on
    assert float(moved["v6"][..., 40:44].max()) > 1e-3
    net = SparseStereoNet(ModelConfig(refine=6, half_res_block=False))
    assert net.refine.context is not None
    state = net.encode(left, right, torch.zeros_like(left), torch.zeros_like(left))
    assert state["quarter_left"].shape == (1, net.config.widths[1], 8, 20)


def test_guided_selection_v7_starts_as_version_5_and_places_an_edge_inside_a_quarter_pixel():
    """Version 7 with version 5's weights gives version 5's output exactly (its gain starts
    at zero); its affinity is, per pixel and candidate, the pixel's 1/2-resolution features
    dotted with the mean features of the candidate's 1/8 cell; with the gain on, pixels on
    either side of an image edge that runs inside a 4x4 block (where versions 5 and 6 apply
    one correction) move apart."""
    import torch.nn.functional as F

    from edge_depth.model.refine import GuidedSelection

    torch.manual_seed(0)
    v5, v7 = GuidedSelection(8, quarter=4), GuidedSelection(8, quarter=4, pixel=4)
    for p in v5.parameters():
        torch.nn.init.normal_(p, std=0.3)
    result = v7.load_state_dict(v5.state_dict(), strict=False)
    assert sorted(result.missing_keys) == ["pixel.0.bias", "pixel.0.weight", "pixel.2.bias",
                                           "pixel.2.weight", "pixel_gain"]
    left, right, gt, low = _two_plane_cell_edge()
    mask = torch.zeros(1, 9 * 64, 4, 10)
    quarter = (torch.rand(1, 4, 8, 20), torch.rand(1, 4, 8, 20))
    with torch.no_grad():
        out5, logit5 = v5(left, right, low, mask, quarter=quarter)
        out7, logit7 = v7(left, right, low, mask, quarter=quarter)
        torch.testing.assert_close(out7, out5, rtol=0, atol=0)
        torch.testing.assert_close(logit7, logit5, rtol=0, atol=0)
        affinity = v7.cell_affinity(left)  # (1, 9, 64, 4, 10)
        feats = v7.pixel(F.avg_pool2d(left, 2) / 127.5 - 1.0)
        cells = F.avg_pool2d(feats, 4)
        for y, x, k in ((13, 45, 4), (13, 45, 3), (0, 0, 0), (31, 79, 8), (6, 33, 5)):
            cy = min(max(y // 8 + k // 3 - 1, 0), 3)
            cx = min(max(x // 8 + k % 3 - 1, 0), 9)
            expected = float((feats[0, :, y // 2, x // 2] * cells[0, :, cy, cx]).sum())
            assert float(affinity[0, k, (y % 8) * 8 + x % 8, y // 8, x // 8]) == \
                pytest.approx(expected, abs=1e-5)
        v7.pixel_gain.fill_(5.0)
        edge = left.clone()
        edge[..., 42:] = 250.0  # a bright region from x = 42: inside the 1/4 block 40..43
        edge[..., :42] = 5.0
        before = v5(edge, right, low, mask, quarter=quarter)[0]
        after = v7(edge, right, low, mask, quarter=quarter)[0]
    step5 = float((before[..., 41] - before[..., 42]).abs().max())
    step7 = float((after[..., 41] - after[..., 42]).abs().max())
    assert step5 == pytest.approx(0.0, abs=1e-4)  # one correction per 4x4 block
    assert step7 > 0.05


def test_guided_selection_v8_starts_as_version_5_and_its_query_learns_from_the_first_step():
    """Version 7's features get no gradient at the start (its gain is zero): it never
    started. Version 8 starts as exactly version 5 too, but its query's weights get a
    gradient at once, and a few steps on the cell-edge scene lower the loss."""
    from edge_depth.model.refine import GuidedSelection

    torch.manual_seed(0)
    v5 = GuidedSelection(8, quarter=4)
    v7 = GuidedSelection(8, quarter=4, pixel=8)
    v8 = GuidedSelection(8, quarter=4, pixel=8, query=True)
    for p in v5.parameters():
        torch.nn.init.normal_(p, std=0.3)
    for module in (v7, v8):
        module.load_state_dict(v5.state_dict(), strict=False)
    left, right, gt, low = _two_plane_cell_edge()
    mask = torch.zeros(1, 9 * 64, 4, 10)
    quarter = (torch.rand(1, 4, 8, 20), torch.rand(1, 4, 8, 20))
    with torch.no_grad():
        out5 = v5(left, right, low, mask, quarter=quarter)[0]
    for module in (v7, v8):
        out = module(left, right, low, mask, quarter=quarter)[0]
        torch.testing.assert_close(out, out5, rtol=0, atol=0)
        (out - gt).abs().mean().backward()
    assert float(v7.pixel[0].weight.grad.abs().max()) == 0.0
    assert float(v8.query.weight.grad.abs().max()) > 0.0
    opt = torch.optim.Adam([v8.query.weight, v8.query.bias, *v8.pixel.parameters()], lr=0.05)
    losses = []
    for _ in range(30):
        opt.zero_grad()
        loss = (v8(left, right, low, mask, quarter=quarter)[0] - gt).abs().mean()
        loss.backward()
        opt.step()
        losses.append(float(loss))
    assert losses[-1] < 0.8 * losses[0]


def test_guided_selection_at_half_resolution_scores_inside_a_quarter_block():
    """`scale=2` takes the 1/4 scorer's weights as they are (the same tensors), still reads
    the backbone's 1/4 features at 1/4, and its correction can differ between the two 1/2
    pixels of a 4x4 block, where the 1/4 scorer applies one; scales other than 1/2 and 1/4
    are refused."""
    from edge_depth.errors import ConfigError
    from edge_depth.model.config import ModelConfig
    from edge_depth.model.refine import GuidedSelection

    torch.manual_seed(0)
    quarter4 = GuidedSelection(8, quarter=4)
    half = GuidedSelection(8, quarter=4, scale=2)
    for p in quarter4.parameters():
        torch.nn.init.normal_(p, std=0.3)
    half.load_state_dict(quarter4.state_dict())  # strict: the same tensors
    left, right, gt, low = _two_plane_cell_edge()
    mask = torch.zeros(1, 9 * 64, 4, 10)
    quarter = (torch.rand(1, 4, 8, 20), torch.rand(1, 4, 8, 20))
    edge = left.clone()
    edge[..., 42:] = 250.0  # an image edge at x = 42: inside the 1/4 block 40..43
    edge[..., :42] = 5.0
    with torch.no_grad():
        out4, logit4 = quarter4(edge, right, low, mask, quarter=quarter)
        out2, logit2 = half(edge, right, low, mask, quarter=quarter)
    assert out2.shape == out4.shape == left.shape and logit2.shape == left.shape
    assert float((out4[..., 41] - out4[..., 42]).abs().max()) == pytest.approx(0.0, abs=1e-4)
    assert float((out2[..., 41] - out2[..., 42]).abs().max()) > 0.05
    with pytest.raises(ValueError, match="1/2 or 1/4"):
        GuidedSelection(8, scale=8)
    with pytest.raises(ConfigError):
        ModelConfig(refine=8, refine_scale=3)
    assert ModelConfig(refine=8, refine_scale=2).refine_scale == 2


def test_guided_selection_v9_starts_as_version_8_and_its_wide_query_learns():
    """Version 9 with version 8's weights gives version 8's output exactly (its second pixel
    side's query starts at zero); that query gets a gradient at once, and a few steps on the
    cell-edge scene with only the new branch training lower the loss."""
    from edge_depth.model.refine import GuidedSelection

    torch.manual_seed(0)
    v8 = GuidedSelection(8, quarter=4, pixel=8, query=True)
    v9 = GuidedSelection(8, quarter=4, pixel=8, query=True, wide_pixel=8)
    for p in v8.parameters():
        torch.nn.init.normal_(p, std=0.3)
    result = v9.load_state_dict(v8.state_dict(), strict=False)
    assert sorted(result.missing_keys) == sorted(
        [f"wide_pixel.{i}.{p}" for i in (0, 2, 4) for p in ("weight", "bias")]
        + ["wide_query.weight", "wide_query.bias"])
    left, right, gt, low = _two_plane_cell_edge()
    mask = torch.zeros(1, 9 * 64, 4, 10)
    quarter = (torch.rand(1, 4, 8, 20), torch.rand(1, 4, 8, 20))
    with torch.no_grad():
        out8, logit8 = v8(left, right, low, mask, quarter=quarter)
    out9, logit9 = v9(left, right, low, mask, quarter=quarter)
    torch.testing.assert_close(out9, out8, rtol=0, atol=0)
    torch.testing.assert_close(logit9, logit8, rtol=0, atol=0)
    (out9 - gt).abs().mean().backward()
    assert float(v9.wide_query.weight.grad.abs().max()) > 0.0
    opt = torch.optim.Adam([*v9.wide_query.parameters(), *v9.wide_pixel.parameters()], lr=0.01)
    losses = []  # (at 0.05 its ReLUs die and the loss stalls above the start)
    for _ in range(60):
        opt.zero_grad()
        loss = (v9(left, right, low, mask, quarter=quarter)[0] - gt).abs().mean()
        loss.backward()
        opt.step()
        losses.append(float(loss))
    assert losses[-1] < 0.5 * losses[0]


def test_version_10_keeps_the_convex_disparity_and_upsamples_its_confidence_the_same_way():
    """Version 10 has no image-guided stage: the disparity is the trunk's convex upsampling,
    bit for bit, and the 1/8 confidence logit reaches full resolution through the same convex
    weights — a constant logit stays constant, an edge in it follows the weights."""
    torch.manual_seed(0)
    net = SparseStereoNet(ModelConfig(gru_iters=2, refine=10)).eval()
    left = torch.rand(1, 1, 64, 96) * 255
    zeros = torch.zeros(1, 1, 64, 96)
    with torch.no_grad():
        outs, logit = net(left, torch.roll(left, -3, dims=3), zeros, zeros, 2,
                          with_confidence=True)
        state = net.encode(left, torch.roll(left, -3, dims=3), zeros, zeros)
        d, h, hl = state["disparity"], state["hidden"], state["hidden_low"]
        for _ in range(2):
            d, h, hl, mask = net.step(state, d, h, hl)
        low = net.refine(h, d)
        head = net.refine.head[2]
    torch.testing.assert_close(outs[-1], convex_upsample(d, mask, 8), rtol=0, atol=0)
    assert low.shape == (1, 1, 8, 12) and logit.shape == (1, 1, 64, 96)
    _, expected = convex_upsample(d, mask, 8, low)
    torch.testing.assert_close(logit, expected)
    with torch.no_grad():   # a constant logit comes out constant: the weights sum to one
        head.weight.zero_()
        head.bias.fill_(1.5)
        _, logit = net(left, torch.roll(left, -3, dims=3), zeros, zeros, 2,
                       with_confidence=True)
    torch.testing.assert_close(logit, torch.full_like(logit, 1.5))
    # an edge in the 1/8 logit: full-resolution values stay between its two sides
    edge = torch.zeros(1, 1, 8, 12)
    edge[..., 6:] = 4.0
    _, up = convex_upsample(d, mask, 8, edge)
    assert float(up[..., :, :40].max()) < 1e-4 and float(up[..., :, 56:].min()) > 4 - 1e-4
    assert 0 < float(up[..., :, 40:56].mean()) < 4


def test_version_10_head_sees_the_hidden_state_and_the_disparitys_spread(monkeypatch):
    import edge_depth.model.refine as refine

    torch.manual_seed(2)
    head = refine.ConvexConfidence(hidden_dim=8, channels=4)
    hidden = torch.rand(1, 8, 6, 6, requires_grad=True)
    flat = torch.full((1, 1, 6, 6), 5.0)
    step = flat.clone()
    step[..., 3:] = 9.0
    with torch.no_grad():
        assert float((head(hidden, step) - head(hidden, flat)).abs().max()) > 0
    monkeypatch.setattr(refine, "CONFIDENCE_TRUNK_GRAD", 0.1)
    head(hidden, flat).sum().backward()
    tenth = hidden.grad.clone()
    hidden.grad = None
    monkeypatch.setattr(refine, "CONFIDENCE_TRUNK_GRAD", 1.0)
    head(hidden, flat).sum().backward()
    torch.testing.assert_close(tenth, 0.1 * hidden.grad)
