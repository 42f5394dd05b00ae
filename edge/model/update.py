"""The update operator: motion encoder, ConvGRU and the heads for Δd and the upsampling mask."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from edge_depth.model.params import param


class ConvGRU(nn.Module):
    def __init__(self, hidden_dim: int, input_dim: int) -> None:
        super().__init__()
        self.convzr = nn.Conv2d(hidden_dim + input_dim, 2 * hidden_dim, 3, 1, 1)
        self.convq = nn.Conv2d(hidden_dim + input_dim, hidden_dim, 3, 1, 1)

    def forward(self, h: torch.Tensor, x: torch.Tensor,
                fixed: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """`fixed`: `fixed_terms(c)` of the input's last channels c, which then stay out of
        `x` — the same result (convolutions are linear in their input channels)."""
        if fixed is None:
            hx = torch.cat([h, x], 1)
            z, r = torch.sigmoid(self.convzr(hx)).chunk(2, 1)
            q = torch.tanh(self.convq(torch.cat([r * h, x], 1)))
        else:
            # channel counts are the graph's constants (int(): never traced from the input's
            # shape, which an export with dynamic height and width would keep as a Slice of
            # the weights on every step, unquantizable)
            n = int(h.shape[1]) + int(x.shape[1])
            zr = F.conv2d(torch.cat([h, x], 1), self.convzr.weight[:, :n], padding=1)
            z, r = torch.sigmoid(zr + fixed[0]).chunk(2, 1)
            q = torch.tanh(F.conv2d(torch.cat([r * h, x], 1), self.convq.weight[:, :n],
                                    padding=1) + fixed[1])
        return (1 - z) * h + z * q

    def fixed_terms(self, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The gates' share from input channels that stay the same over the iterations (the
        context: the last `c.shape[1]` input channels), biases included: computed once per
        frame instead of once per iteration (the step graph's convolutions lose a quarter of
        their input channels)."""
        k = int(c.shape[1])  # a constant of the graph, as `n` in forward
        return (F.conv2d(c, self.convzr.weight[:, -k:], self.convzr.bias, padding=1),
                F.conv2d(c, self.convq.weight[:, -k:], self.convq.bias, padding=1))


class MotionEncoder(nn.Module):
    def __init__(self, corr_channels: int, out_dim: int) -> None:
        super().__init__()
        self.corr = nn.Conv2d(corr_channels, out_dim, 1)
        self.disp = nn.Conv2d(1, 16, 7, 1, 3)
        self.out = nn.Conv2d(out_dim + 16, out_dim - 1, 3, 1, 1)

    def forward(self, corr: torch.Tensor, disparity: torch.Tensor) -> torch.Tensor:
        c = F.relu(self.corr(corr))
        d = F.relu(self.disp(disparity))
        return torch.cat([F.relu(self.out(torch.cat([c, d], 1))), disparity], 1)


class UpdateBlock(nn.Module):
    """One GRU step: (hidden, context, correlation features, disparity) -> hidden, Δd, mask.

    gru_levels 2 adds a GRU at half resolution whose state feeds the full one.
    """

    def __init__(self, hidden_dim: int, context_dim: int, corr_channels: int, factor: int,
                 gru_levels: int = 1, motion_dim: int = 64, head_dim: int = 64) -> None:
        super().__init__()
        self.motion = MotionEncoder(corr_channels, motion_dim)
        self.gru_levels = gru_levels
        extra = hidden_dim if gru_levels == 2 else 0
        self.gru = ConvGRU(hidden_dim, motion_dim + context_dim + extra)
        if gru_levels == 2:
            self.gru_low = ConvGRU(hidden_dim, motion_dim + context_dim)
        self.delta = nn.Sequential(nn.Conv2d(hidden_dim, head_dim, 3, 1, 1), nn.ReLU(),
                                   nn.Conv2d(head_dim, 1, 3, 1, 1))
        self.mask = nn.Sequential(nn.Conv2d(hidden_dim, head_dim, 3, 1, 1), nn.ReLU(),
                                  nn.Conv2d(head_dim, 9 * factor * factor, 1))

    def context_terms(self, context: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The GRU's fixed terms from the context (`ConvGRU.fixed_terms`), for `forward`'s
        `context_terms`; gru_levels 1 only (the half-resolution GRU sees the context too)."""
        if self.gru_levels != 1:
            raise ValueError("the context's fixed terms need gru_levels 1")
        return self.gru.fixed_terms(context)

    def forward(self, hidden, hidden_low, context, corr, disparity, context_terms=None):
        """`context_terms`: `self.context_terms(context)`, computed once per frame; then
        `context` is not read (None is fine)."""
        motion = self.motion(corr, disparity)
        if context_terms is not None:
            hidden = self.gru(hidden, motion, context_terms)
        else:
            x = torch.cat([motion, context], 1)
            if self.gru_levels == 2:
                hidden_low = self.gru_low(hidden_low, F.avg_pool2d(x, 2))
                up = F.interpolate(hidden_low, size=hidden.shape[-2:], mode="bilinear",
                                   align_corners=False)
                x = torch.cat([x, up], 1)
            hidden = self.gru(hidden, x)
        return hidden, hidden_low, self.delta(hidden), self.upsampling_mask(hidden)

    def upsampling_mask(self, hidden: torch.Tensor) -> torch.Tensor:
        """The convex upsampling's mask logits (B, 9 f², h, w). The last 1×1 convolution is
        written as a MatMul (the same weights): its 9 f² channels come out channels-first,
        ready for the upsampling's 5-D view, where OpenVINO ran the convolution channels-last
        and then reordered its output (~2.8 ms of the upsampling graph at 640x400)."""
        x = self.mask[1](self.mask[0](hidden))
        last = self.mask[2]
        b, c, h, w = x.shape
        logits = torch.matmul(param(last).view(-1, c), x.reshape(b, c, h * w))
        return 0.25 * (logits + param(last, "bias").view(-1, 1)).view(b, -1, h, w)
