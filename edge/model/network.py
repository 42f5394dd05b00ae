"""The sparse-LiDAR-assisted RAFT-Stereo network (Zhao et al.), split for deployment.

`encode` runs once per frame (features, correlation pyramid, context, affinity, sparse input at
the GRU's resolution, and the first CSPN that seeds the disparity from the LiDAR); `step` is
one update (lookup, GRU, d + Δd, CSPN with re-injection, upsampling mask); `upsample` is the
convex upsampling to full resolution. `forward` chains them for training.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from edge_depth.model.config import ModelConfig
from edge_depth.model.corr import (
    correlation_pyramid,
    correlation_volume,
    flatten_pyramid,
    lookup_flat,
)
from edge_depth.model.cspn import cspn, normalise_affinity, patches_3x3
from edge_depth.model.extractor import Encoders
from edge_depth.model.refine import ConvexConfidence
from edge_depth.model.update import UpdateBlock


def downsample_sparse(sparse: torch.Tensor, valid: torch.Tensor, factor: int
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Full-resolution sparse disparity (B, 1, H, W) px -> mean of the valid points in each
    factor x factor cell, in low-resolution pixels, and the cell's validity (0/1 float)."""
    total = F.avg_pool2d(sparse * valid, factor) * factor * factor
    count = F.avg_pool2d(valid, factor) * factor * factor
    low_valid = (count > 0.5).to(sparse.dtype)
    return total / count.clamp(min=1.0) / factor * low_valid, low_valid


def convex_upsample(disparity: torch.Tensor, mask: torch.Tensor, factor: int,
                    logit: torch.Tensor | None = None):
    """(B, 1, h, w) low-res disparity and (B, 9 f², h, w) mask logits -> (B, 1, f h, f w) in
    full-resolution pixels: a softmax over the 9 neighbours' weights, then depth-to-space.
    With `logit` (B, 1, h, w), also that map upsampled by the same weights (not scaled):
    (disparity, logit).

    Written for ONNX Runtime, where a 7-D softmax is slow: at most 5-D; logits clipped to
    ±30 instead of subtracting their maximum (the same softmax unless a logit leaves that
    range, and exp(30) · 9 is far from overflow); normalised after the weighted sum, so the
    division runs on f² channels rather than 9 f²."""
    b, _, h, w = disparity.shape
    weights = torch.exp(mask.view(b, 9, factor * factor, h, w).clamp(-30.0, 30.0))
    patches = patches_3x3(disparity * factor).view(b, 9, 1, h, w)
    total = weights.sum(1)
    up = (weights * patches).sum(1) / total  # (B, f², h, w)
    if logit is None:
        return F.pixel_shuffle(up, factor)
    logits = (weights * patches_3x3(logit).view(b, 9, 1, h, w)).sum(1) / total
    return F.pixel_shuffle(up, factor), F.pixel_shuffle(logits, factor)


class SparseStereoNet(nn.Module):
    def __init__(self, config: ModelConfig | None = None) -> None:
        super().__init__()
        self.config = cfg = config or ModelConfig()
        self.encoders = Encoders(cfg.widths, cfg.downsample, cfg.feature_dim, cfg.hidden_dim,
                                 cfg.context_dim, cfg.half_res_block)
        corr_channels = cfg.corr_levels * (2 * cfg.corr_radius + 1)
        self.update = UpdateBlock(cfg.hidden_dim, cfg.context_dim, corr_channels,
                                  cfg.downsample, cfg.gru_levels, cfg.motion_dim, cfg.head_dim)
        # the confidence head (`refine` 10), for the engine's selections and matching
        self.refine = ConvexConfidence(cfg.hidden_dim) if cfg.refine == 10 else None

    def encode(self, left: torch.Tensor, right: torch.Tensor, sparse: torch.Tensor,
               valid: torch.Tensor) -> dict[str, Any]:
        """Images (B, 1, H, W) grey 0-255; sparse (B, 1, H, W) px, valid (B, 1, H, W) 0/1."""
        cfg = self.config
        f_l, f_r, hidden, context, affinity, _ = self.encoders(left, right)
        corr = flatten_pyramid(correlation_pyramid(correlation_volume(f_l, f_r),
                                                   cfg.corr_levels))
        weights, centre = normalise_affinity(affinity)
        sparse_low, valid_low = downsample_sparse(sparse, valid, cfg.downsample)
        disparity = torch.zeros_like(sparse_low)
        disparity = self._propagate(disparity, weights, centre, sparse_low, valid_low)
        hidden_low = F.avg_pool2d(hidden, 2) if cfg.gru_levels == 2 else hidden[:, :0]
        state = dict(corr=corr, hidden=hidden, hidden_low=hidden_low, context=context,
                     weights=weights, centre=centre, sparse=sparse_low, valid=valid_low,
                     disparity=disparity)
        return state

    def _propagate(self, d, weights, centre, sparse, valid):
        cfg = self.config
        if not cfg.use_sparse:
            sparse = valid = None
        if cfg.use_cspn:
            return cspn(d, weights, centre, cfg.cspn_steps, sparse, valid)
        if sparse is not None:
            return (1 - valid) * d + valid * sparse
        return d

    def step(self, state: dict, disparity: torch.Tensor, hidden: torch.Tensor,
             hidden_low: torch.Tensor):
        """One GRU iteration; returns (disparity, hidden, hidden_low, upsampling mask)."""
        cfg = self.config
        corr = lookup_flat(state["corr"], disparity, cfg.corr_radius, cfg.corr_levels)
        terms = (state["context_zr"], state["context_q"]) if "context_zr" in state else None
        hidden, hidden_low, delta, mask = self.update(hidden, hidden_low, state.get("context"),
                                                      corr, disparity, terms)
        disparity = self._propagate(disparity + delta, state["weights"], state["centre"],
                                    state["sparse"], state["valid"])
        return disparity, hidden, hidden_low, mask

    def upsample(self, disparity: torch.Tensor, mask: torch.Tensor,
                 hidden: torch.Tensor | None = None
                 ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Convex upsampling to full resolution: (disparity (B, 1, H, W) px, confidence logits
        or None without the head). The head reads the last step's `hidden` and its logit is
        upsampled by the same convex weights as the disparity."""
        factor = self.config.downsample
        if self.refine is None:
            return convex_upsample(disparity, mask, factor), None
        assert hidden is not None, "the confidence head reads the last step's hidden state"
        return convex_upsample(disparity, mask, factor, self.refine(hidden, disparity))

    def forward(self, left, right, sparse, valid, iters: int | None = None,
                with_confidence: bool = False):
        """Full-resolution disparity (B, 1, H, W) px after each of `iters` GRU steps; with
        `with_confidence`, also the confidence logits of the last one (None without the
        head). Only the last step's are computed, as the engine runs it once, after its last
        step."""
        iters = self.config.gru_iters if iters is None else iters
        state = self.encode(left, right, sparse, valid)
        d, h, hl = state["disparity"], state["hidden"], state["hidden_low"]
        outputs, logit = [], None
        for i in range(iters):
            d, h, hl, mask = self.step(state, d, h, hl)
            if i < iters - 1:
                outputs.append(convex_upsample(d, mask, self.config.downsample))
            else:
                full, logit = self.upsample(d, mask, h)
                outputs.append(full)
        return (outputs, logit) if with_confidence else outputs
