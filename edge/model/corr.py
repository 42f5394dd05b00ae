"""The 1-D all-pairs correlation pyramid and its radius-r lookup.

C(i, j, k) = Σ_h f_l(i, j, h) f_r(i, k, h) / √C (the paper's correlation, RAFT-Stereo's
scaling), average-pooled by 2 along k into `levels` levels. The lookup samples each level at
x - d (scaled to the level) plus integer offsets -r..r by linear interpolation, with zeros
outside the row, using gathers (GatherElements in ONNX) rather than grid_sample.
"""

from __future__ import annotations

from typing import Any

import torch
from torch.nn import functional as F


def correlation_volume(f_left: torch.Tensor, f_right: torch.Tensor) -> torch.Tensor:
    """(B, C, H, W) x2 -> (B, H, W, W): left pixel j against right pixel k on row i."""
    b, c, h, w = f_left.shape
    left = f_left.permute(0, 2, 3, 1).reshape(b * h, w, c)
    right = f_right.permute(0, 2, 1, 3).reshape(b * h, c, w)
    return torch.matmul(left, right).reshape(b, h, w, w) / c**0.5


def correlation_pyramid(volume: torch.Tensor, levels: int) -> list[torch.Tensor]:
    """Level l has (B, H, W, W / 2**l), pooled by 2 along the last axis."""
    b, h, w, w2 = volume.shape
    pyramid = [volume]
    flat = volume.reshape(b * h * w, 1, w2)
    for _ in range(levels - 1):
        flat = F.avg_pool1d(flat, 2, 2)
        pyramid.append(flat.reshape(b, h, w, flat.shape[-1]))
    return pyramid


def lookup(pyramid: list[torch.Tensor], disparity: torch.Tensor, radius: int) -> torch.Tensor:
    """Correlation around x - d: (B, levels * (2r + 1), H, W). disparity: (B, 1, H, W)."""
    b, _, h, w = disparity.shape
    x = torch.arange(w, dtype=disparity.dtype, device=disparity.device).view(1, 1, w)
    target = x - disparity[:, 0]  # (B, H, W) position in the right row
    offsets = torch.arange(-radius, radius + 1, dtype=disparity.dtype,
                           device=disparity.device)
    out = []
    for level, corr in enumerate(pyramid):
        width = corr.shape[-1]
        pos = target.unsqueeze(-1) / 2**level + offsets  # (B, H, W, 2r+1)
        i0 = torch.floor(pos)
        frac = pos - i0
        i0 = i0.long()
        sampled: Any = 0  # a tensor after the first term
        for idx, weight in ((i0, 1 - frac), (i0 + 1, frac)):
            valid = (idx >= 0) & (idx < width)
            values = torch.gather(corr, 3, idx.clamp(0, width - 1))
            sampled = sampled + values * weight * valid.to(values.dtype)
        out.append(sampled)
    return torch.cat(out, -1).permute(0, 3, 1, 2)


def flatten_pyramid(pyramid: list[torch.Tensor]) -> torch.Tensor:
    """Levels zero-padded (one column left, two right) and concatenated along the last axis:
    (B, H, W, Σ (W_l + 3)). `lookup_flat` samples it with one gather (one GatherElements in
    ONNX, several times faster in ONNX Runtime than a gather per level or grid_sample)."""
    return torch.cat([F.pad(level, (1, 2)) for level in pyramid], -1)


def lookup_flat(flat: torch.Tensor, disparity: torch.Tensor, radius: int, levels: int
                ) -> torch.Tensor:
    """The same values as `lookup` on the pyramid `flat` was made from.

    Positions are clamped to [-1, W_l], where the padding is zero and the interpolation weight
    of the in-row neighbour is zero, so no validity mask is needed."""
    b, _, h, w = disparity.shape
    x = torch.arange(w, dtype=disparity.dtype, device=disparity.device).view(1, 1, w)
    target = (x - disparity[:, 0]).unsqueeze(-1)  # (B, H, W, 1)
    offsets = torch.arange(-radius, radius + 1, dtype=disparity.dtype, device=disparity.device)
    # the level widths and where each level starts, as tensors computed from `x` rather than
    # Python numbers: an exported graph then reads them from its input's width and runs a
    # camera of any size (a float would be traced as the export size's constant)
    width = x[..., -1:].unsqueeze(-1) + 1  # (1, 1, 1, 1): W
    start = torch.zeros_like(width)
    positions, starts = [], []
    for level in range(levels):
        pos = torch.minimum(torch.clamp(target / 2**level + offsets, min=-1.0), width)
        positions.append(pos)
        starts.append(start + 1.0 + 0 * offsets)  # +1: the left pad column
        start = start + width + 3
        width = torch.floor(width / 2)
    pos = torch.cat(positions, -1)
    base = torch.cat(starts, -1)
    i0 = torch.floor(pos)
    frac = pos - i0
    idx = (i0 + base).long()
    values = torch.gather(flat, 3, torch.cat([idx, idx + 1], -1))
    v0, v1 = values.chunk(2, -1)
    return (v0 * (1 - frac) + v1 * frac).permute(0, 3, 1, 2)
