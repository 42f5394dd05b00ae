"""Feature, context and affinity extraction: a shared residual backbone with separate heads.

The paper uses two encoders of the same architecture with separate weights. At this project's
budget (a 2-core CPU, see DESIGN.md) the backbone is shared and only the heads differ: the
feature head (run on both images) feeds the correlation, the context head (left only) gives the
GRU's initial state and context, and an extra residual block on the context predicts the
8-neighbour CSPN affinity, as the paper adds.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


class ResidualBlock(nn.Module):
    def __init__(self, c_in: int, c_out: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride, 1)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, 1, 1)
        self.norm1 = nn.BatchNorm2d(c_out)
        self.norm2 = nn.BatchNorm2d(c_out)
        self.skip = None
        if stride != 1 or c_in != c_out:
            self.skip = nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride), nn.BatchNorm2d(c_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        y = self.norm2(self.conv2(y))
        return F.relu(y + (x if self.skip is None else self.skip(x)))


class Backbone(nn.Module):
    """Grey image (B, 1, H, W) in [0, 255] -> features at 1/4, (B, widths[1], H/4, W/4), and
    at 1/downsample, (B, widths[-1], h, w)."""

    def __init__(self, widths: tuple[int, int, int], downsample: int,
                 half_res_block: bool = True) -> None:
        super().__init__()
        w1, w2, w3 = widths
        self.stem = nn.Sequential(nn.Conv2d(1, w1, 5, 2, 2), nn.BatchNorm2d(w1), nn.ReLU())
        self.layer1 = ResidualBlock(w1, w1) if half_res_block else nn.Identity()
        self.layer2 = ResidualBlock(w1, w2, stride=2)
        self.layer3 = ResidualBlock(w2, w3, stride=2 if downsample == 8 else 1)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = image / 127.5 - 1.0
        quarter = self.layer2(self.layer1(self.stem(x)))
        return quarter, self.layer3(quarter)


class Encoders(nn.Module):
    """Shared backbone + feature, context and affinity heads. Also returns the backbone's 1/4
    features of both images (2B, widths[1], H/4, W/4), for the 1/4 stage (`edge.model.quarter`).
    """

    def __init__(self, widths, downsample: int, feature_dim: int, hidden_dim: int,
                 context_dim: int, half_res_block: bool = True) -> None:
        super().__init__()
        c = widths[-1]
        self.backbone = Backbone(widths, downsample, half_res_block)
        self.feature_head = nn.Conv2d(c, feature_dim, 1)
        self.context_head = nn.Conv2d(c, hidden_dim + context_dim, 3, 1, 1)
        self.affinity_block = ResidualBlock(c, c)
        self.affinity_head = nn.Conv2d(c, 8, 3, 1, 1)
        self.hidden_dim = hidden_dim

    def forward(self, left: torch.Tensor, right: torch.Tensor):
        quarter, both = self.backbone(torch.cat([left, right], 0))
        f_left, f_right = self.feature_head(both).chunk(2, 0)
        trunk = both[: left.shape[0]]
        ctx = self.context_head(trunk)
        hidden = torch.tanh(ctx[:, : self.hidden_dim])
        context = F.relu(ctx[:, self.hidden_dim:])
        affinity = self.affinity_head(self.affinity_block(trunk))
        return f_left, f_right, hidden, context, affinity, quarter
