"""Image-guided refinement and confidence at half resolution (after StereoNet / HITNet).

At 1/8 the convex upsampling has to invent every edge; this stage sees, at 1/2 resolution,
the left and right images, the photometric error of the right image warped by the upsampled
disparity, the disparity itself and (version 2) the LiDAR's disagreement with it, and
predicts (a) a residual that snaps the disparity to image edges and to the LiDAR and (b) the
logit of the confidence that the refined disparity is within 1 px of the truth (trained with
that target, as Isaac ROS ESS's confidence is). Both are brought to full resolution
bilinearly. Cost at 640x400: ~1.9 GFLOP (one GRU step is 3.7).

Versions (`ModelConfig.refine`): 1 shares one zero-initialised output convolution between
residual and logit (stage 4; its residual never learned: with the layer at zero the features
get no gradient and the L1 signal alone was too weak to start them); 2 has a head each, the
residual's initialised small but not zero (the confidence's at zero: 0.5), and takes the
LiDAR as two more inputs.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from edge.model.losses import warp_horizontal

RESIDUAL_INIT_STD = 1e-2  # version 2: ~the identity at the start (residuals of ~0.1 px), not zero
CONFIDENCE_TRUNK_GRAD = 0.1  # how much of the confidence's gradient reaches the shared trunk


class ResidualDilated(nn.Module):
    def __init__(self, channels: int, dilation: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, 1, dilation, dilation)
        self.conv2 = nn.Conv2d(channels, channels, 3, 1, dilation, dilation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.conv2(F.relu(self.conv1(x))))


def sparse_at_half(sparse: torch.Tensor, valid: torch.Tensor, disparity2: torch.Tensor):
    """(LiDAR − disparity) / 8 where a 2×2 cell has LiDAR (mean of its points, in half-res px),
    0 elsewhere, and the cell's 0/1 mask."""
    count = F.avg_pool2d(valid, 2)
    mean = F.avg_pool2d(sparse * valid, 2) / count.clamp(min=0.25) / 2.0
    has = (count > 0).to(sparse.dtype)
    return has * (mean - disparity2) / 8.0, has


class Refinement(nn.Module):
    """(left, right (B, 1, H, W) grey 0-255, disparity (B, 1, H, W) px[, sparse px, valid 0/1
    (B, 1, H, W), version 2]) → refined disparity (B, 1, H, W) px and confidence logits."""

    def __init__(self, version: int = 2, channels: int = 16,
                 dilations: tuple[int, ...] = (1, 2, 4)) -> None:
        super().__init__()
        self.version = version
        self.inp = nn.Conv2d(6 if version >= 2 else 4, channels, 3, 1, 1)
        self.blocks = nn.Sequential(*[ResidualDilated(channels, d) for d in dilations])
        if version >= 2:
            self.residual = nn.Conv2d(channels, 1, 3, 1, 1)
            self.confidence = nn.Conv2d(channels, 1, 3, 1, 1)
            nn.init.normal_(self.residual.weight, std=RESIDUAL_INIT_STD)
            nn.init.zeros_(self.residual.bias)
            nn.init.zeros_(self.confidence.weight)  # says 0.5 until trained
            nn.init.zeros_(self.confidence.bias)
        else:
            self.out = nn.Conv2d(channels, 2, 3, 1, 1)
            nn.init.zeros_(self.out.weight)  # starts as the identity: no residual, logit 0
            nn.init.zeros_(self.out.bias)

    def forward(self, left, right, disparity, sparse=None, valid=None):
        left2 = F.avg_pool2d(left, 2) / 255.0
        right2 = F.avg_pool2d(right, 2) / 255.0
        disp2 = F.avg_pool2d(disparity, 2) / 2.0
        error = (left2 - warp_horizontal(right2, disp2)).abs()
        inputs = [left2 - 0.5, right2 - 0.5, error, disp2 / 32.0]
        if self.version >= 2:
            if sparse is None or valid is None:
                sparse = valid = torch.zeros_like(disparity)
            inputs.extend(sparse_at_half(sparse, valid, disp2))
        x = self.blocks(F.relu(self.inp(torch.cat(inputs, 1))))
        if self.version >= 2:
            # the trunk learns mostly for the residual: the confidence's larger, steadier
            # gradient would otherwise decide what its features become (run stage5's
            # first try: the residual's weights stayed at their initial 1e-3 for 600 steps)
            to_confidence = x.detach() + CONFIDENCE_TRUNK_GRAD * (x - x.detach())
            residual, logit = self.residual(x), self.confidence(to_confidence)
        else:
            residual, logit = self.out(x).chunk(2, 1)
        size = disparity.shape[-2:]
        up = lambda t: F.interpolate(t, size=size, mode="bilinear",  # noqa: E731
                                     align_corners=False)
        refined = disparity + 2.0 * up(residual)
        return refined, up(logit)
