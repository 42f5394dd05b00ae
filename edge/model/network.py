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

from edge_depth.errors import ConfigError
from edge_depth.model.config import ModelConfig
from edge_depth.model.corr import (
    correlation_pyramid,
    correlation_volume,
    flatten_pyramid,
    lookup_flat,
)
from edge_depth.model.cspn import cspn, normalise_affinity, patches_3x3
from edge_depth.model.extractor import Encoders
from edge_depth.model.quarter import QuarterStage
from edge_depth.model.refine import (
    GUIDED_VERSIONS,
    ConvexConfidence,
    GuidedSelection,
    Refinement,
)
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
        self.refine: Any = None  # the refinement stage of `cfg.refine`'s version
        if cfg.refine == 4:
            if cfg.downsample != 8:
                raise ConfigError("refine", "4 only with downsample 8", cfg.refine)
            self.refine = QuarterStage(cfg.widths[1])
        elif cfg.refine in GUIDED_VERSIONS:
            self.refine = GuidedSelection(cfg.downsample,
                                          quarter=cfg.widths[1] if cfg.refine >= 5 else 0,
                                          context=16 if cfg.refine == 6 else 0,
                                          pixel=8 if cfg.refine in (7, 8, 9) else 0,
                                          query=cfg.refine in (8, 9),
                                          wide_pixel=8 if cfg.refine == 9 else 0,
                                          scale=cfg.refine_scale)
        elif cfg.refine == 10:
            self.refine = ConvexConfidence(cfg.hidden_dim)
        elif cfg.refine:
            self.refine = Refinement(cfg.refine)
        # training only: the 1/4 stage's matching as an auxiliary loss on the backbone
        self.aux_offsets: Any = QuarterStage(cfg.widths[1]) if cfg.aux_offsets else None

    def encode(self, left: torch.Tensor, right: torch.Tensor, sparse: torch.Tensor,
               valid: torch.Tensor) -> dict[str, Any]:
        """Images (B, 1, H, W) grey 0-255; sparse (B, 1, H, W) px, valid (B, 1, H, W) 0/1."""
        cfg = self.config
        f_l, f_r, hidden, context, affinity, quarter = self.encoders(left, right)
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
        if cfg.refine == 4:
            state["quarter_left"], state["quarter_right"] = \
                self.refine.head(quarter).chunk(2, 0)
        elif cfg.refine >= 5:  # the guided selection also matches on the backbone's 1/4
            state["quarter_left"], state["quarter_right"] = quarter.chunk(2, 0)
        if self.aux_offsets is not None and self.training:
            state["aux_left"], state["aux_right"] = self.aux_offsets.head(quarter).chunk(2, 0)
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

    def quarter_features(self, state: dict) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The encoder's 1/4 features (left, right) for `upsample`; None but for versions 4
        (its own head's), 5 to 8 (the backbone's)."""
        if self.config.refine < 4:
            return None
        return state["quarter_left"], state["quarter_right"]

    def upsample(self, left, right, disparity, mask, sparse=None, valid=None,
                 quarter: tuple[torch.Tensor, torch.Tensor] | None = None,
                 aux: dict | None = None, hidden: torch.Tensor | None = None):
        """Convex upsampling, then (if configured) the refinement: full-resolution disparity
        (B, 1, H, W) px and confidence logits (None without the refinement). `sparse` and
        `valid` (full resolution) reach the refinement only if the model uses the LiDAR;
        `quarter` is the encoder's (quarter_left, quarter_right), for version 4, which also
        puts what its losses need into `aux` if given (`offset_loss`, `gate_loss`); `hidden`
        is the last step's state, for version 10's confidence head."""
        if not self.config.use_sparse:
            sparse = valid = None
        if self.config.refine == 4:  # gated towards an estimate found by matching at 1/4
            full = convex_upsample(disparity, mask, self.config.downsample)
            assert quarter is not None, "version 4 matches on the encoder's 1/4 features"
            refined, logit, extras = self.refine(*quarter, full, sparse, valid, left)
            if aux is not None:
                aux.update(extras, convex=full)
            logit = F.interpolate(logit, size=full.shape[-2:], mode="bilinear",
                                  align_corners=False)
            return refined, logit
        if self.config.refine in GUIDED_VERSIONS:  # chooses among the convex candidates
            return self.refine(left, right, disparity, mask, sparse, valid, quarter)
        if self.config.refine == 10:  # the confidence only, upsampled as the disparity is
            return convex_upsample(disparity, mask, self.config.downsample,
                                   self.refine(hidden, disparity))
        full = convex_upsample(disparity, mask, self.config.downsample)
        if self.refine is None:
            return full, None
        return self.refine(left, right, full, sparse, valid)

    def forward(self, left, right, sparse, valid, iters: int | None = None,
                with_confidence: bool = False, aux: dict | None = None):
        """Full-resolution disparity (B, 1, H, W) px after each of `iters` GRU steps; with
        `with_confidence`, also the confidence logits of the last one (None without the
        refinement stage). Only the last step goes through the refinement (as the engine
        runs it, once, after its last step); the earlier ones are convex-upsampled only,
        which keeps training ~35 % cheaper at 6 steps."""
        iters = self.config.gru_iters if iters is None else iters
        state = self.encode(left, right, sparse, valid)
        d, h, hl = state["disparity"], state["hidden"], state["hidden_low"]
        outputs, logit = [], None
        for i in range(iters):
            d, h, hl, mask = self.step(state, d, h, hl)
            if i < iters - 1:
                outputs.append(convex_upsample(d, mask, self.config.downsample))
            else:
                full, logit = self.upsample(left, right, d, mask, sparse, valid,
                                            self.quarter_features(state), aux, h)
                outputs.append(full)
                if aux is not None and "aux_left" in state:  # the auxiliary matching's loss
                    convex = convex_upsample(d, mask, self.config.downsample).detach()
                    extras = self.aux_offsets(state["aux_left"], state["aux_right"], convex,
                                              sparse, valid, left)[2]
                    aux.update(offsets=extras["offsets"], centre=extras["centre"])
        return (outputs, logit) if with_confidence else outputs
