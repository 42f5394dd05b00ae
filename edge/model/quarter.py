"""The 1/4-resolution stage (refinement version 4): matching at the backbone's 1/4 features
around the 1/8 estimate, supervised as a distribution over offsets, and a residual for every
full-resolution pixel, with the confidence.

Why: at 1/8 every edge inside a cell is invented by the upsampling mask. On Aloe the exact
GT brought to 1/8 and back scores bad-3 10.6 % at best (nearest), at 1/4 4.9 %; every bad-3
pixel of stage 8 lies within 16 px of a depth edge. Version 3 (`edge.model.refine`) only
re-weights the 1/8 cell's nine candidates and gained ~0.01 px for ~13 ms. This stage matches
again at 1/4 with the backbone's own 1/4 features (computed by the encoder anyway; the
stage's 1×1 `head`, run in the encoder, makes them 16 channels), so it can put an edge where
the images put it.

Inputs at 1/4: the left features (context), the correlation f_l(x)·f_r(x − k)/√C at the
2r + 1 integer disparities k around round(d4), d4 − round(d4), and the LiDAR's disagreement
with d4 where a 4×4 cell has a point. d4 is the 8× convex upsampling of the last GRU step,
read at one pixel of each 4×4 block.

The output, for each full-resolution pixel: the convex estimate moved towards the 1/4 estimate
(centre + the offsets' expected value, constant over its 4×4 block) by a gate, + the residual.
The gate is trained by its own target, "the 1/4 estimate is closer to the GT than the convex
one here" (`edge.model.losses.gate_loss`): a residual trained by L1 alone never learned to copy
the 1/4 estimate (run stage10q), because in smooth regions that estimate is the noisier one and
nothing said where to trust it.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from edge_depth.model.params import param
from edge_depth.model.refine import (
    CONFIDENCE_TRUNK_GRAD,
    RESIDUAL_INIT_STD,
    ResidualDilated,
    lidar_at,
    read_right_rows,
)

SCALE = 4
RADIUS = 4  # ±4 px at 1/4 = ±16 px at full resolution: two 1/8 cells either side
GATE_START = -4.0  # the gate's bias at the start: sigmoid(−4) ≈ 0.02, ~the convex estimate
SAMPLE = 1  # d4 is the convex estimate at this pixel of each 4×4 block: an average would mix
#             the two sides of an edge into a value neither has


def local_correlation(f_left: torch.Tensor, f_right: torch.Tensor, centre: torch.Tensor,
                      radius: int) -> torch.Tensor:
    """f_l(x) · f_r(x − centre − k) / √C for k = −r..r: features (B, C, h, w), integer-valued
    centre (B, 1, h, w) px → (B, 2r + 1, h, w), the right row read at clamped columns.

    The right row is read by `read_right_rows` (one 1-D Gather) and the products summed by a
    batched MatMul."""
    b, c, h, w = f_left.shape
    k = 2 * radius + 1
    offsets = torch.arange(-radius, radius + 1, dtype=centre.dtype,
                           device=centre.device).view(1, 1, 1, k)
    x = torch.arange(w, dtype=centre.dtype, device=centre.device).view(1, 1, w, 1)
    column = (x - centre.permute(0, 2, 3, 1) - offsets).clamp(0, w - 1)  # (B, h, w, K)
    read = read_right_rows(f_right, column)
    dots = torch.matmul(read, f_left.permute(0, 2, 3, 1).reshape(b * h * w, c, 1))
    return dots.view(b, h, w, k).permute(0, 3, 1, 2) / c**0.5


def offset_distribution(logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor,
                                                       torch.Tensor]:
    """(B, 2r + 1, h, w) logits over the offsets −r..r → the expected offset, its variance and
    the largest probability, each (B, 1, h, w). exp / sum rather than a softmax over axis 1
    (~20× slower in ONNX Runtime); logits clipped to ±30 as in the convex upsampling."""
    k = logits.shape[1]
    radius = (k - 1) // 2
    offsets = torch.arange(-radius, radius + 1, dtype=logits.dtype,
                           device=logits.device).view(1, k, 1, 1)
    weights = torch.exp(logits.clamp(-30.0, 30.0))
    p = weights / weights.sum(1, keepdim=True)
    mean = (p * offsets).sum(1, keepdim=True)
    variance = (p * (offsets - mean) ** 2).sum(1, keepdim=True)
    return mean, variance, p.amax(1, keepdim=True)


class QuarterStage(nn.Module):
    """(1/4 features left and right (B, C, H/4, W/4), the 8× convex-upsampled disparity
    (B, 1, H, W) px[, sparse px, valid 0/1, the left image grey 0–255, each (B, 1, H, W)]) →
    the refined disparity (B, 1, H, W) px, the confidence logits at 1/4, and for the losses a
    dict: `offsets` (B, 2r + 1, H/4, W/4) logits and the integer `centre` they are relative
    to (B, 1, H/4, W/4), 1/4 px (`offset_loss`); `gate` logits and the 1/4 estimate
    `quarter` px, both (B, 1, H, W) (`gate_loss`).

    The trunk (24 channels, two residual blocks) sees the local correlation, the left
    features, d4 − centre and the LiDAR; an offsets head turns it into a distribution over
    the 2r + 1 disparities around the centre, trained by cross-entropy against the GT's
    offset (`edge.model.losses.offset_loss`). Its expected value minus d4 is a direct
    estimate of the correction at 1/4; the residual head reads it (with the distribution's
    spread and peak) beside the trunk and writes one residual per full-resolution pixel of
    the 4×4 block. Trained by the disparity's L1 alone the stage did not learn (run stage9q,
    `docs/experiments.md`): the loss's ±1 per pixel cancels across an edge. The gate head sees
    the trunk, the distribution's summary, each pixel's convex value relative to the 1/4
    estimate and the left image's pixels of the block (where inside the block the edge is)."""

    def __init__(self, backbone: int = 32, features: int = 16, channels: int = 24) -> None:
        super().__init__()
        k = 2 * RADIUS + 1
        self.head = nn.Conv2d(backbone, features, 1)  # run by the encoder, on both images
        self.inp = nn.Conv2d(k + features + 3, channels, 3, 1, 1)
        self.blocks = nn.Sequential(ResidualDilated(channels, 1), ResidualDilated(channels, 2))
        self.offsets = nn.Conv2d(channels, k, 3, 1, 1)
        self.residual = nn.Conv2d(channels + 3, SCALE * SCALE, 3, 1, 1)
        self.confidence = nn.Conv2d(channels + 3, 1, 3, 1, 1)
        self.gate = nn.Conv2d(channels + 3 + 2 * SCALE * SCALE, SCALE * SCALE, 3, 1, 1)
        # starts as the 8× convex estimate: small rather than zero residual weights so the
        # trunk gets a gradient at once (refinement version 1); the confidence says 0.5
        nn.init.normal_(param(self.residual), std=RESIDUAL_INIT_STD)
        nn.init.zeros_(param(self.residual, "bias"))
        nn.init.zeros_(param(self.confidence))
        nn.init.zeros_(param(self.confidence, "bias"))
        nn.init.normal_(param(self.gate), std=RESIDUAL_INIT_STD)
        nn.init.constant_(param(self.gate, "bias"), GATE_START)

    def forward(self, f_left, f_right, full, sparse=None, valid=None, image=None):
        d4 = full[..., SAMPLE::SCALE, SAMPLE::SCALE] / SCALE
        centre = torch.round(d4).detach()
        corr = local_correlation(f_left, f_right, centre, RADIUS)
        if sparse is None or valid is None:
            sparse = valid = torch.zeros_like(full)
        lidar, has = lidar_at(sparse, valid, SCALE)
        to_lidar = has * ((lidar - d4) / 4.0).clamp(-2.0, 2.0)
        x = torch.cat([corr, f_left, d4 - centre, to_lidar, has], 1)
        x = self.blocks(F.relu(self.inp(x)))
        logits = self.offsets(x)
        mean, variance, peak = offset_distribution(logits)
        # in full-resolution px: the residual head copies it with weight 1
        estimate = SCALE * (centre + mean - d4)
        seen = torch.cat([estimate.clamp(-4 * SCALE, 4 * SCALE), variance, peak], 1)
        # the confidence's larger, steadier gradient would otherwise decide what the trunk
        # learns (refinement version 2's lesson)
        to_confidence = x.detach() + CONFIDENCE_TRUNK_GRAD * (x - x.detach())
        residual = self.residual(torch.cat([x, seen], 1))
        logit = self.confidence(torch.cat([to_confidence, seen.detach()], 1))
        # the 1/4 estimate, full-res px, and the block's pixels: convex values and image
        quarter = SCALE * (centre + mean)
        blocks = F.pixel_unshuffle(full, SCALE)
        apart = ((blocks - quarter) / SCALE).clamp(-4.0, 4.0)
        grey = (F.pixel_unshuffle(image, SCALE) / 127.5 - 1.0 if image is not None
                else torch.zeros_like(blocks))
        gate = self.gate(torch.cat([x, seen, apart, grey], 1))
        moved = blocks + torch.sigmoid(gate) * (quarter - blocks) + residual
        extras = dict(offsets=logits, centre=centre, gate=F.pixel_shuffle(gate, SCALE),
                      quarter=F.interpolate(quarter, scale_factor=SCALE, mode="nearest"))
        return F.pixel_shuffle(moved, SCALE), logit, extras
