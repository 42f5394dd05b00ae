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

from edge_depth.model.cspn import patches_3x3
from edge_depth.model.losses import warp_horizontal
from edge_depth.model.params import param

GUIDED_VERSIONS = (3, 5, 6, 7, 8, 9)  # the refinement versions that are a `GuidedSelection`
RESIDUAL_INIT_STD = 1e-2  # version 2: ~the identity at the start (residuals of ~0.1 px), not zero
CONFIDENCE_TRUNK_GRAD = 0.1  # how much of the confidence's gradient reaches the shared trunk


class ResidualDilated(nn.Module):
    def __init__(self, channels: int, dilation: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, 1, dilation, dilation)
        self.conv2 = nn.Conv2d(channels, channels, 3, 1, dilation, dilation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.conv2(F.relu(self.conv1(x))))


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


def sparse_at_half(sparse: torch.Tensor, valid: torch.Tensor, disparity2: torch.Tensor):
    """(LiDAR − disparity) / 8 where a 2×2 cell has LiDAR (mean of its points, in half-res px),
    0 elsewhere, and the cell's 0/1 mask."""
    count = F.avg_pool2d(valid, 2)
    mean = F.avg_pool2d(sparse * valid, 2) / count.clamp(min=0.25) / 2.0
    has = (count > 0).to(sparse.dtype)
    return has * (mean - disparity2) / 8.0, has


def lidar_at(sparse: torch.Tensor, valid: torch.Tensor, scale: int
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Full-resolution sparse disparity (px) and validity → the mean of each scale × scale
    cell's points in 1/scale px (0 where none) and the cell's 0/1 mask."""
    count = F.avg_pool2d(valid, scale)
    mean = F.avg_pool2d(sparse * valid, scale) / count.clamp(min=1.0 / (scale * scale)) / scale
    return mean, (count > 0).to(sparse.dtype)


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
            nn.init.normal_(param(self.residual), std=RESIDUAL_INIT_STD)
            nn.init.zeros_(param(self.residual, "bias"))
            nn.init.zeros_(param(self.confidence))  # says 0.5 until trained
            nn.init.zeros_(param(self.confidence, "bias"))
        else:
            self.out = nn.Conv2d(channels, 2, 3, 1, 1)
            nn.init.zeros_(param(self.out))  # starts as the identity: no residual, logit 0
            nn.init.zeros_(param(self.out, "bias"))

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


def read_right_rows(f_right: torch.Tensor, column: torch.Tensor) -> torch.Tensor:
    """f_right (B, C, h, w), integer-valued columns (B, h, w, K) within 0..w − 1 → (B·h·w, K, C):
    each pixel's right row read at its K columns. Written for the runtimes: the features as
    (B·h·w, C) rows read with one 1-D Gather instead of a GatherElements over (B, C, h, w·K),
    whose index must be expanded over the channels — ~2× faster in ONNX Runtime for the 1/4
    stage's correlation (equal there for `matching_cost`), and a JIT kernel in OpenVINO, where
    GatherElements is a reference one (upsampling graph 28.4 → 26.2 ms)."""
    b, c, h, w = f_right.shape
    k = column.shape[-1]
    row = (torch.arange(b * h, dtype=column.dtype, device=column.device) * w).view(b, h, 1, 1)
    rows = f_right.permute(0, 2, 3, 1).reshape(b * h * w, c)
    return rows.index_select(0, (row + column).long().reshape(-1)).view(b * h * w, k, c)


def matching_cost(f_left: torch.Tensor, f_right: torch.Tensor, candidates: torch.Tensor
                  ) -> torch.Tensor:
    """Mean |f_left(x) − f_right(x − d_k)| over channels for each of K candidate disparities:
    features (B, C, h, w), candidates (B, K, h, w) px → (B, K, h, w). The right features are
    read at the nearest pixel (border clamped) by `read_right_rows` (grid_sample of 9 warps
    ran ~70 ms at 320x200 in ONNX Runtime). Scores need no sub-pixel precision, and no
    gradient flows to the candidates through them."""
    b, c, h, w = f_left.shape
    k = candidates.shape[1]
    x = torch.arange(w, dtype=candidates.dtype, device=candidates.device).view(1, 1, w, 1)
    column = torch.round(x - candidates.permute(0, 2, 3, 1)).clamp(0, w - 1)  # (B, h, w, K)
    read = read_right_rows(f_right, column)
    cost = (read - f_left.permute(0, 2, 3, 1).reshape(b * h * w, 1, c)).abs().mean(2)
    return cost.view(b, h, w, k).permute(0, 3, 1, 2)


def expand_to_cells(values: torch.Tensor, factor: int, scale: int) -> torch.Tensor:
    """(B, K, H/scale, W/scale) → (B, K, factor², H/factor, W/factor): each full-resolution
    pixel's value from the 1/scale pixel that holds it, in the convex upsampling's layout
    (sub-position i·factor + j of each 1/factor cell), without a full-resolution tensor
    (pixel_unshuffle, then one gather with a constant index)."""
    b, k = values.shape[:2]
    per = factor // scale
    cells = F.pixel_unshuffle(values, per)  # (B, K·per², h, w)
    h, w = cells.shape[-2:]
    return cells.view(b, k, per * per, h, w).index_select(
        2, sub_position_index(factor, scale, values.device))


def cell_candidates(disparity: torch.Tensor, factor: int, scale: int) -> torch.Tensor:
    """(B, 1, H/factor, W/factor) disparity in 1/factor px → (B, 9, H/scale, W/scale): at
    every 1/scale pixel the nine values of its 1/factor cell's 3×3 neighbourhood, in 1/scale
    px (the convex upsampling's candidates)."""
    return F.interpolate(patches_3x3(disparity * (factor / scale)), scale_factor=factor // scale,
                         mode="nearest")


def sub_position_index(factor: int, scale: int, device) -> torch.Tensor:
    """For each of a 1/factor cell's factor² full-resolution sub-positions, the index of the
    1/scale pixel that holds it among the cell's (factor/scale)²."""
    per = factor // scale
    return torch.tensor([(i // scale) * per + j // scale for i in range(factor)
                         for j in range(factor)], device=device)


class GuidedSelection(nn.Module):
    """Version 3: (left, right (B, 1, H, W) grey 0-255, low-resolution disparity (B, 1, h, w)
    in low-res px, convex mask logits (B, 9 f², h, w)[, sparse px, valid 0/1 (B, 1, H, W)])
    → full-resolution disparity (B, 1, H, W) px and confidence logits.

    Each full-resolution pixel's output is a weighted mean of its cell's nine candidates, as
    in the convex upsampling, with logits = the convex ones + a correction. The correction
    is computed at 1/4 resolution for every candidate by one small per-pixel network shared
    by all nine, from that candidate's matching cost (learned features of the left image
    against the right read at the candidate's disparity; raw, 3×3- and 7×7-averaged), its
    distance to the LiDAR in the 4×4 cell and its offset from the cell's own value. Edges
    inside a 1/8 cell are then placed by the images at 1/4 (where the exact GT's own
    nearest-neighbour ceiling on Aloe is bad-3 4.9 % against 10.3 % at 1/8) instead of by
    the 1/8 hidden state alone. The confidence comes from a few convolutions at 1/4 on what
    the choice saw. ~0.1 GFLOP at 640x400 beyond the convex upsampling.

    Version 5 (`quarter` = the backbone's 1/4 channel count) also scores each candidate by
    the backbone's own 1/4 features (the ones the correlation's features come from, trained
    to match), projected to `QUARTER_FEATURES` channels: their matching cost, raw and 3×3
    averaged, two more inputs of the scorer. Its weights for them start at zero, so a version
    3 checkpoint carried over (`widen_from_version3`) starts as exactly version 3.

    Version 6 (`context` = its width) adds a correction with spatial context: the 1×1 scorer
    judges each candidate at each 1/4 pixel alone, and 86 % of the shipped model's bad-3
    pixels on Aloe lie within 4 px of a depth edge, where an oracle among the same nine
    candidates scores bad-3 1.8 %. Two 3×3 convolutions (the second dilated) see all nine
    candidates' costs, LiDAR distances and offsets, the 1×1 scorer's corrections and the
    image at once over ~20 full-resolution px, so the choice can follow an edge across
    pixels and compare candidates. Its output layer starts at zero: a version 5 checkpoint
    starts as exactly version 5.

    Version 7 (`pixel` = its feature count) adds what neither scorer has: the image at full
    resolution. Both corrections are constant over each 4×4 block, and the exact GT itself,
    chosen per 1/4 pixel, scores bad-3 4.9 % on Aloe (nearest) — no better than the SGBM +
    LiDAR fusion — while the nine candidates chosen per full-resolution pixel score 1.8 %.
    So each 1/2-resolution pixel also scores each candidate by how its own learned features
    (one 3×3 and one 1×1 convolution on the left image) resemble the mean features of the
    1/8 cell the candidate comes from: a learned joint-bilateral upsampling. The term's gain
    starts at zero: a version 5 checkpoint starts as exactly version 5. It never started (run
    stage16): the term is a gain times a product of two small learned factors, and with the
    gain at zero the features get no gradient, nor the gain a steady one (after 400 steps it
    was −0.006 and the term moved the logits by ~3e-5) — version 1's lesson again.

    Version 8 (`query=True`) is version 7 written so that it can start: the pixel side goes
    through a 1×1 `query` convolution that starts at zero (so again a version 5 checkpoint
    starts as exactly version 5) while the cells' side keeps its features, so the query's
    weights get a gradient from the first step; no gain.

    Version 9 (`wide_pixel` = its feature count) adds a second pixel side beside version 8's,
    with a wider view: three layers (16 channels, the middle one dilated: 14×14 full-
    resolution px against version 8's 6×6), its own query starting at zero, so a version 8
    checkpoint starts as exactly version 8. Version 8's term stopped growing after 3 000
    steps (run stage27v8b): whether the affinity's features, not the scorer, are its limit."""

    SCALE = 4  # the default resolution the candidates are scored at (`scale`)
    QUARTER_FEATURES = 8  # 16 cost ~3 ms more in OpenVINO (GatherElements: a reference kernel)
    PIXEL_SCALE = 2  # versions 7-9: the resolution of the pixel side's features

    def __init__(self, factor: int = 8, features: int = 2, hidden: int = 16,
                 quarter: int = 0, context: int = 0, pixel: int = 0,
                 query: bool = False, scale: int = SCALE, wide_pixel: int = 0) -> None:
        super().__init__()
        if scale not in (2, 4):
            raise ValueError(f"the candidates are scored at 1/2 or 1/4, not 1/{scale}")
        self.factor = factor
        self.scale = scale
        self.features = nn.Sequential(nn.Conv2d(1, 8, 3, 1, 1), nn.ReLU(),
                                      nn.Conv2d(8, features, 3, 1, 1))
        inputs = 6
        self.project = None
        if quarter:
            self.project = nn.Conv2d(quarter, self.QUARTER_FEATURES, 1)
            inputs += 2
        self.score = nn.Sequential(nn.Conv2d(inputs, hidden, 1), nn.ReLU(),
                                   nn.Conv2d(hidden, 1, 1))
        self.confidence = nn.Sequential(nn.Conv2d(6, hidden, 3, 1, 1), nn.ReLU(),
                                        nn.Conv2d(hidden, hidden, 3, 1, 1), nn.ReLU(),
                                        nn.Conv2d(hidden, 1, 3, 1, 1))
        # ~the convex upsampling at the start; small rather than zero so that the first
        # layer gets a gradient at once (version 1's zero output layer never started)
        nn.init.normal_(param(self.score[-1]), std=RESIDUAL_INIT_STD)
        nn.init.zeros_(param(self.score[-1], "bias"))
        nn.init.zeros_(param(self.confidence[-1]))  # says 0.5 until trained
        nn.init.zeros_(param(self.confidence[-1], "bias"))
        if quarter:
            with torch.no_grad():
                param(self.score[0])[:, 6:] = 0.0
        self.context = None
        if context:  # per candidate: cost, 1/4 cost, LiDAR distance, offset, correction
            per = 5 if quarter else 4
            self.context = nn.Sequential(nn.Conv2d(9 * per + 1, context, 3, 1, 1), nn.ReLU(),
                                         nn.Conv2d(context, context, 3, 1, 2, dilation=2),
                                         nn.ReLU(), nn.Conv2d(context, 9, 1))
            nn.init.zeros_(param(self.context[-1]))  # starts as the version it extends
            nn.init.zeros_(param(self.context[-1], "bias"))
        self.pixel = None
        if pixel:
            self.pixel = nn.Sequential(nn.Conv2d(1, pixel, 3, 1, 1), nn.ReLU(),
                                       nn.Conv2d(pixel, pixel, 1))
        self.query = None
        if pixel and query:  # version 8: the pixel side's projection starts at zero
            self.query = nn.Conv2d(pixel, pixel, 1)
            nn.init.zeros_(param(self.query))
            nn.init.zeros_(param(self.query, "bias"))
        elif pixel:  # version 7: a gain at zero (never started: see above)
            self.pixel_gain = nn.Parameter(torch.zeros(()))
        self.wide_pixel = self.wide_query = None
        if wide_pixel:  # version 9
            self.wide_pixel = nn.Sequential(nn.Conv2d(1, 16, 3, 1, 1), nn.ReLU(),
                                            nn.Conv2d(16, 16, 3, 1, 2, dilation=2), nn.ReLU(),
                                            nn.Conv2d(16, wide_pixel, 1))
            self.wide_query = nn.Conv2d(wide_pixel, wide_pixel, 1)
            nn.init.zeros_(param(self.wide_query))
            nn.init.zeros_(param(self.wide_query, "bias"))
        # False: the confidence logit stays at 1/scale (the export: the engine resizes the
        # confidence to full resolution, cheaper than in OpenVINO's graph)
        self.confidence_full_resolution = True

    def forward(self, left, right, disparity, mask, sparse=None, valid=None, quarter=None):
        f, s = self.factor, self.scale
        b, _, h, w = disparity.shape
        left_s = F.avg_pool2d(left, s) / 127.5 - 1.0
        right_s = F.avg_pool2d(right, s) / 127.5 - 1.0
        hs, ws = left_s.shape[-2:]
        # the nine candidates in 1/s px at every 1/s pixel (those of the 1/8 cell it is in)
        candidates = cell_candidates(disparity, f, s)  # (B, 9, hs, ws)
        feats = self.features(torch.cat([left_s, right_s], 0))
        cost = matching_cost(torch.cat([left_s, feats[:b]], 1),
                             torch.cat([right_s, feats[b:]], 1), candidates)
        if sparse is None or valid is None:
            sparse = valid = torch.zeros_like(left)
        lidar, has = lidar_at(sparse, valid, s)
        to_lidar = has * ((lidar - candidates) / 4.0).clamp(-2.0, 2.0)
        offset = ((candidates - candidates[:, 4:5]) / 4.0).clamp(-2.0, 2.0)
        per_candidate = [cost, F.avg_pool2d(cost, 3, 1, 1, count_include_pad=False),
                         F.avg_pool2d(cost, 7, 1, 3, count_include_pad=False),
                         to_lidar, to_lidar.abs(), offset]
        if self.project is not None:
            if quarter is None:
                raise ValueError("refinement version 5 needs the encoder's 1/4 features")
            q_left, q_right = self.project(torch.cat(quarter, 0)).chunk(2, 0)
            # the backbone's features are at 1/4 whatever the scorer's scale
            q_candidates = candidates if s == 4 else cell_candidates(disparity, f, 4)
            q_cost = matching_cost(q_left, q_right, q_candidates)
            q_pair = [q_cost, F.avg_pool2d(q_cost, 3, 1, 1, count_include_pad=False)]
            if s != 4:
                q_pair = [F.interpolate(t, scale_factor=4 // s, mode="nearest") for t in q_pair]
            per_candidate += q_pair
        x = torch.stack(per_candidate, 2).view(b * 9, len(per_candidate), hs, ws)
        correction = self.score(x).view(b, 9, hs, ws)
        if self.context is not None:
            seen_all = [cost, to_lidar, offset, correction, left_s]
            if self.project is not None:
                seen_all.insert(1, per_candidate[6])
            correction = correction + self.context(torch.cat(seen_all, 1))
        correction = correction.clamp(-30.0, 30.0)
        # what the evidence alone prefers (exp and sum: a softmax over axis 1 is ~20x
        # slower in ONNX Runtime), summarised for the confidence
        chosen = torch.exp(correction)
        chosen = chosen / chosen.sum(1, keepdim=True)
        seen = torch.cat([(chosen * cost).sum(1, keepdim=True),
                          (chosen * per_candidate[2]).sum(1, keepdim=True),
                          chosen.amax(1, keepdim=True),
                          (chosen * to_lidar.abs()).sum(1, keepdim=True), has, left_s], 1)
        if self.pixel is None:
            logits = mask.view(b, 9, f * f, h, w) + expand_to_cells(correction, f, s)
        else:  # both terms summed at the pixel side's resolution, then expanded once
            affinity = self.half_resolution_affinity(left)
            if self.query is None:
                affinity = self.pixel_gain * affinity
            if self.wide_pixel is not None:
                affinity = affinity + self.half_resolution_affinity(
                    left, self.wide_pixel, self.wide_query)
            half = expand_to_cells(correction, f // self.PIXEL_SCALE,
                                   s // self.PIXEL_SCALE) + affinity
            logits = mask.view(b, 9, f * f, h, w) + half.index_select(
                2, sub_position_index(f, self.PIXEL_SCALE, left.device))
        weights = torch.exp(logits.clamp(-30.0, 30.0))
        patches = patches_3x3(disparity * f).view(b, 9, 1, h, w)
        up = (weights * patches).sum(1) / weights.sum(1)  # (B, f², h, w)
        logit = self.confidence(seen)
        if self.confidence_full_resolution:
            logit = F.interpolate(logit, size=left.shape[-2:], mode="bilinear",
                                  align_corners=False)
        return F.pixel_shuffle(up, f), logit

    def cell_affinity(self, left: torch.Tensor) -> torch.Tensor:
        """`half_resolution_affinity` in the convex upsampling's layout (B, 9, f², H/f, W/f):
        each full-resolution pixel takes its 1/2 pixel's."""
        return self.half_resolution_affinity(left).index_select(
            2, sub_position_index(self.factor, self.PIXEL_SCALE, left.device))

    def half_resolution_affinity(self, left: torch.Tensor, pixel: nn.Module | None = None,
                                 query: nn.Module | None = None) -> torch.Tensor:
        """Versions 7-9: (B, 1, H, W) grey 0-255 → (B, 9, (f/2)², H/f, W/f), the dot
        product of each 1/2-resolution pixel's features (versions 8, 9: their query) with the mean
        features of each of the nine 1/8 cells its candidates come from, per 1/2-resolution
        sub-position of each 1/8 cell (`pixel_unshuffle`'s order). Computed per
        1/8 cell, one channel at a time: at full resolution, as one batched product per cell,
        or with the cell means resized to 1/2, the graph ran 30–60 % slower in OpenVINO.
        `pixel` and `query`: another pixel side's (version 9's); default version 7's or 8's."""
        f, s = self.factor, self.PIXEL_SCALE
        per = f // s
        if pixel is None:
            pixel, query = self.pixel, self.query
        assert pixel is not None, "the pixel side of versions 7-9"
        feats = pixel(F.avg_pool2d(left, s) / 127.5 - 1.0)  # (B, C, H/s, W/s)
        b, c = feats.shape[:2]
        cells = F.avg_pool2d(feats, per)
        h, w = cells.shape[-2:]
        means = patches_3x3(cells.reshape(b * c, 1, h, w)).view(b, c, 9, 1, h, w)
        if query is not None:  # versions 8 and 9
            feats = query(feats)
        pixels = F.pixel_unshuffle(feats, per).view(b, c, 1, per * per, h, w)
        affinity = means[:, 0] * pixels[:, 0]
        for i in range(1, c):
            affinity = affinity + means[:, i] * pixels[:, i]
        return affinity


def widen_from_version3(weights: dict, module: GuidedSelection, prefix: str = "refine."
                        ) -> dict:
    """A version 3 state dict made loadable into version 5 (`module`): the scorer's first
    layer gets zero weights for the new inputs; `project` is left for a fresh start."""
    key = prefix + "score.0.weight"
    old = weights.get(key)
    new = param(module.score[0])
    if old is None or old.shape == new.shape:
        return weights
    wide = torch.zeros_like(new)
    wide[:, :old.shape[1]] = old
    return {**weights, key: wide}
