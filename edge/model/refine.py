"""The confidence head (`ModelConfig.refine` 10): the probability that the disparity is
within 1 px of the truth, for the engine's LiDAR selection and its band refinement.

At 1/8 the convex upsampling has to invent every edge; rather than a learned image-guided
stage at 1/2 (the earlier versions 1-9, removed; the tag model-versions-archive holds them),
the network says where it is unsure and the engine's band refinement
(`edge.runtime.band_sgm`) does the edges' work there.
"""

from __future__ import annotations

import torch
from torch import nn

from edge_depth.model.cspn import patches_3x3

CONFIDENCE_TRUNK_GRAD = 0.1  # how much of the confidence's gradient reaches the shared trunk


class ConvexConfidence(nn.Module):
    """Version 10: no image-guided stage, only a confidence head at 1/8 — two 3×3
    convolutions on the last step's hidden state and the 3×3 range of its disparity (where an
    edge crosses the cell). Its logit (B, 1, h, w) is upsampled by the convex weights, as the
    disparity is (`network.convex_upsample`); ~0.1 GFLOP at 640x400."""

    def __init__(self, hidden_dim: int = 64, channels: int = 32) -> None:
        super().__init__()
        self.head = nn.Sequential(nn.Conv2d(hidden_dim + 1, channels, 3, 1, 1), nn.ReLU(),
                                  nn.Conv2d(channels, 1, 3, 1, 1))

    def forward(self, hidden: torch.Tensor, disparity: torch.Tensor) -> torch.Tensor:
        patches = patches_3x3(disparity)
        spread = patches.amax(1, keepdim=True) - patches.amin(1, keepdim=True)
        # as in the other versions: the trunk feels a tenth of the confidence's gradient
        x = torch.cat([hidden, spread], 1)
        return self.head(x.detach() + CONFIDENCE_TRUNK_GRAD * (x - x.detach()))
